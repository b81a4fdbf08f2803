"""Only robots write the fleet's key space, each under its own name
(config/fleet/router-secure.json5, docs/fleet.md): a real zenohd with the storage plugin,
mutual TLS with certificates from placecell-certs, and the router's access control. A
robot's forgery under another robot's name, a viewer's put and a stranger's connection
store nothing; the robots' own places are stored and another robot's fleet link takes
them over TLS."""

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


def _session(tls: Path, who: str, endpoint: str) -> zenoh.Session:
    """A client with its certificate and no rules of its own."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("client"))
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/link/tls", json.dumps({
        "root_ca_certificate": str(tls / "ca.pem"),
        "connect_certificate": str(tls / f"{who}.pem"),
        "connect_private_key": str(tls / f"{who}.key"),
        "enable_mtls": True, "verify_name_on_connect": False}))
    return zenoh.open(config)


def _stored(session: zenoh.Session) -> set[str]:
    return {str(r.ok.key_expr) for r in session.get(f"{PREFIX}/**", timeout=5.0)
            if r.ok is not None}


def _place(seed: int, robot: str, place_id: int) -> tuple[str, bytes]:
    shared = FleetPlace(PlaceName(robot, place_id), GEOMETRY,
                        synthetic_place(np.random.default_rng(seed)), [])
    return place_key(PREFIX, shared.name), encode_place(shared)


def test_only_a_robot_writes_its_own_places_into_the_fleets_storage(tmp_path: Path) -> None:
    tls = tmp_path / "tls"
    _certs("ca", str(tls))
    _certs("issue", str(tls), "robot-a", "robot-b", "viewer", "fleet-router")
    _certs("ca", str(tmp_path / "elsewhere"))
    _certs("issue", str(tmp_path / "elsewhere"), "stranger")
    config = tmp_path / "router-secure.json5"
    config.write_text((REPO / "config" / "fleet" / "router-secure.json5").read_text()
                      .replace("/etc/placecell/tls", str(tls)))
    router = FleetRouter(free_port(), [], "f1ee7aa1", tmp_path / "router.log", config, "tls")
    router.start(START_S)
    sessions: list[zenoh.Session] = []
    try:
        a, viewer = (_session(tls, who, router.endpoint) for who in ("robot-a", "viewer"))
        sessions += [a, viewer]
        # A client sends a put only where it knows a subscriber (the storage's): both
        # writers wait until the router has told them of it, so what they put is sent
        # and judged by the router, not dropped on the way.
        for who, session in (("robot-a", a), ("viewer", viewer)):
            probe = session.declare_publisher(f"{PREFIX}/{who}/place/1")
            assert wait_for(lambda p=probe: p.matching_status.matching, START_S, 0.05), \
                (who, router.log_path.read_text()[-2000:])
        forged_b, forged_a = _place(2, "robot-b", 1), _place(3, "robot-a", 2)
        for key, payload in (forged_b, _place(1, "robot-a", 1)):  # a's own last
            a.put(key, payload, congestion_control=SHARED)
        viewer.put(*forged_a, congestion_control=SHARED)
        viewer.put(*_place(4, "viewer", 1), congestion_control=SHARED)
        # Each writer's own query comes after its puts on the same link: the router has
        # judged them by the time it answers.
        assert wait_for(lambda: f"{PREFIX}/robot-a/place/1" in _stored(a), START_S, 0.1)
        assert _stored(viewer) == {f"{PREFIX}/robot-a/place/1"}
        with pytest.raises(zenoh.ZError):  # another CA's certificate: no connection
            sessions.append(_session(tmp_path / "elsewhere", "stranger", router.endpoint))

        # Robot B's fleet link, over TLS, takes robot A's place and nothing else.
        b = _session(tls, "robot-b", router.endpoint)
        sessions.append(b)
        owner = MappingSession(Mapper(MapStore.open(tmp_path / "b.db", GEOMETRY),
                                      OdometryNoiseSettings()),
                               AcquisitionSettings(enabled=False),
                               LocalisationSettings(max_lookalikes=0))
        link = FleetLink(owner, b, FleetSettings(enabled=True, fetch_timeout_s=START_S),
                         "robot-b", GEOMETRY, lambda events: None)
        try:
            assert link.start() == 1
            assert owner.mapper.origins == {1: ("robot-a", 1)} and link.refused == 0
        finally:
            link.close()
            owner.mapper.store.close()
        assert _stored(a) == {f"{PREFIX}/robot-a/place/1"}  # nothing of B's to put
    finally:
        for session in sessions:
            session.close()
        router.stop()
