"""Only robots write the fleet's key space, each under its own name
(config/fleet/router-secure.json5, docs/fleet.md): a real zenohd with the storage plugin,
mutual TLS with certificates from placecell-certs, and the router's access control. A
robot's forgery under another robot's name, a viewer's puts and a stranger's connection
store nothing. Robot sim1 runs its node with its own rules (config/zenoh/robot.json5, as
its daemon does): its place is stored and it takes sim2's, and sim2 takes its."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import zenoh

from daemon.config import FleetSettings
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.settings import AcquisitionSettings, OdometryNoiseSettings
from daemon.service.fleet import SHARED, FleetLink
from daemon.service.mapper import Mapper
from daemon.service.mapping_session import MappingSession
from daemon.store.fleet_wire import FleetPlace, PlaceName, encode_place, place_key
from daemon.store.sqlite_store import MapStore
from tests.daemon_harness import REPO, free_port, venv_bin, wait_for
from tests.map_fixtures import synthetic_place
from tools.fleet_router import FleetRouter

START_S = 60.0  # a router's start on a loaded machine
GEOMETRY = "fleet-geometry"
PREFIX = "placecell/fleet"

pytestmark = pytest.mark.xdist_group("zenohd")


def _certs(*args: str) -> None:
    done = subprocess.run([venv_bin("placecell-certs"), *args], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr


def _tls(tls: Path, who: str) -> dict[str, object]:
    return {"root_ca_certificate": str(tls / "ca.pem"),
            "connect_certificate": str(tls / f"{who}.pem"),
            "connect_private_key": str(tls / f"{who}.key"),
            "enable_mtls": True, "verify_name_on_connect": False}


def _session(config: zenoh.Config, endpoint: str) -> zenoh.Session:
    config.insert_json5("mode", json.dumps("client"))
    config.insert_json5("listen/endpoints", "[]")
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)


def _bare(tls: Path, who: str, endpoint: str) -> zenoh.Session:
    """A client with its certificate and no rules of its own."""
    config = zenoh.Config()
    config.insert_json5("transport/link/tls", json.dumps(_tls(tls, who)))
    return _session(config, endpoint)


def _stored(session: zenoh.Session) -> set[str]:
    return {str(r.ok.key_expr) for r in session.get(f"{PREFIX}/**", timeout=5.0)
            if r.ok is not None}


def _place(seed: int, robot: str, place_id: int) -> tuple[str, bytes]:
    shared = FleetPlace(PlaceName(robot, place_id), GEOMETRY,
                        synthetic_place(np.random.default_rng(seed)), [])
    return place_key(PREFIX, shared.name), encode_place(shared)


class _Robot:
    """A robot's map owner (one place of its own) and fleet link on ``session``."""

    def __init__(self, name: str, path: Path, session: zenoh.Session, seed: int) -> None:
        self.owner = MappingSession(Mapper(MapStore.open(path, GEOMETRY),
                                           OdometryNoiseSettings()),
                                    AcquisitionSettings(enabled=False),
                                    LocalisationSettings(max_lookalikes=0))
        self.owner.store_place(synthetic_place(np.random.default_rng(seed), name), [], [])
        self.link = FleetLink(self.owner, session, FleetSettings(
            enabled=True, fetch_timeout_s=START_S), name, GEOMETRY, lambda _: None)

    def close(self) -> None:
        self.link.close()
        self.owner.mapper.store.close()


def test_only_a_robot_writes_its_own_places_into_the_fleets_storage(tmp_path: Path) -> None:
    tls = tmp_path / "tls"
    _certs("ca", str(tls))
    _certs("issue", str(tls), "sim1", "sim2", "viewer", "fleet-router")
    _certs("ca", str(tmp_path / "elsewhere"))
    _certs("issue", str(tmp_path / "elsewhere"), "stranger")
    config = tmp_path / "router-secure.json5"
    config.write_text((REPO / "config" / "fleet" / "router-secure.json5").read_text()
                      .replace("/etc/placecell/tls", str(tls)))
    # Robot sim1 runs its node with its own access control, as its daemon would
    # ([zenoh] config_file = config/zenoh/robot.json5).
    robot_config = tmp_path / "robot.json5"
    robot_config.write_text((REPO / "config" / "zenoh" / "robot.json5").read_text()
                            .replace("/etc/placecell/tls", str(tls)))
    router = FleetRouter(free_port(), [], "f1ee7aa1", tmp_path / "router.log", config, "tls")
    router.start(START_S)
    sessions: list[zenoh.Session] = []
    robots: list[_Robot] = []
    try:
        forger, viewer = (_bare(tls, who, router.endpoint) for who in ("sim1", "viewer"))
        sessions += [forger, viewer]
        # A client sends a put only where it knows a subscriber (the storage's): both
        # writers wait until the router has told them of it, so what they put is sent
        # and judged by the router, not dropped on the way.
        for who, session in (("sim1", forger), ("viewer", viewer)):
            probe = session.declare_publisher(f"{PREFIX}/{who}/place/9")
            assert wait_for(lambda p=probe: p.matching_status.matching, START_S, 0.05), \
                (who, router.log_path.read_text()[-2000:])
        forger.put(*_place(2, "sim2", 1), congestion_control=SHARED)  # under sim2's name
        viewer.put(*_place(3, "sim1", 2), congestion_control=SHARED)
        viewer.put(*_place(4, "viewer", 1), congestion_control=SHARED)
        with pytest.raises(zenoh.ZError):  # another CA's certificate: no connection
            sessions.append(_bare(tmp_path / "elsewhere", "stranger", router.endpoint))

        # sim1, through its own rules and the router's, puts its place and nothing else.
        sim1_session = _session(zenoh.Config.from_file(str(robot_config)), router.endpoint)
        sessions.append(sim1_session)
        sim1 = _Robot("sim1", tmp_path / "sim1.db", sim1_session, 1)
        robots.append(sim1)
        assert sim1.link.start() == 0
        own = f"{PREFIX}/sim1/place/1"
        assert wait_for(lambda: own in _stored(viewer), START_S, 0.1), \
            router.log_path.read_text()[-2000:]
        # Each writer's own query comes after its puts on the same link: the router has
        # judged them by the time it answers.
        assert _stored(forger) == _stored(viewer) == {own}

        # sim2 (no rules of its own) takes sim1's place; sim1 takes sim2's as it is put.
        sim2_session = _bare(tls, "sim2", router.endpoint)
        sessions.append(sim2_session)
        sim2 = _Robot("sim2", tmp_path / "sim2.db", sim2_session, 5)
        robots.append(sim2)
        assert sim2.link.start() == 1 and sim2.owner.mapper.origins == {2: ("sim1", 1)}
        assert wait_for(lambda: sim1.owner.mapper.origins == {2: ("sim2", 1)}, START_S, 0.05)
        assert sim1.link.refused == sim2.link.refused == 0
        assert _stored(viewer) == {own, f"{PREFIX}/sim2/place/1"}
    finally:
        for robot in robots:
            robot.close()
        for session in sessions:
            session.close()
        router.stop()
