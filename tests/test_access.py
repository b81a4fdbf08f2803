"""The access-control helpers (daemon/service/access.py, docs/security.md): roles read
from the rules, endpoints that cannot carry a certificate refused up front, the robot's
zenoh id, and placecellctl's filter of replies from any node but the robot's."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import zenoh

from daemon.config import ZenohSettings
from daemon.service import access, zenoh_link
from kernel.errors import ConfigError
from tests.daemon_harness import REPO
from tools.ctl import from_robot

ROBOT = REPO / "config" / "zenoh" / "robot.json5"


def _acl() -> dict:
    conf = zenoh_link.make_config("peer", ["tls/127.0.0.1:0"], [], False,
                                  config_file=str(ROBOT))
    acl = access.acl_of(conf)
    assert acl is not None
    return acl


def test_roles_by_certificate_name_from_the_shipped_rules() -> None:
    roles = access.roles_by_name(_acl())
    assert roles == {"operator": {"operators", "watchers"}, "viewer": {"watchers"},
                     "router": {"routers"}, "fleet-router": {"fleet_routers"}}


def test_a_plain_tcp_endpoint_beside_certificate_rules_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"tcp/127.0.0.1:7447 carries none"):
        zenoh_link.make_config("peer", ["tcp/127.0.0.1:7447"], [], False,
                               config_file=str(ROBOT))
    with pytest.raises(ConfigError, match=r"tcp/10.0.0.2:7448"):
        zenoh_link.make_config("client", [], ["tcp/10.0.0.2:7448"], False,
                               config_file=str(ROBOT))
    # Without access control, tcp is as good as ever.
    assert access.acl_of(zenoh_link.make_config("peer", ["tcp/127.0.0.1:0"], [], False)) is None


def test_the_robot_zid_is_its_names_unless_configured() -> None:
    zid = zenoh_link.robot_zid("sim1")
    assert len(zid) == 32 and zid == zenoh_link.robot_zid("sim1") != zenoh_link.robot_zid("sim2")
    assert zenoh_link.robot_zid("sim1", "abc123") == "abc123"
    # robot12's hash begins with a 0, which zenoh refuses in an id: dropped.
    for name in ("sim1", "robot12"):
        conf = zenoh_link.make_config("peer", [], [], False, zid=zenoh_link.robot_zid(name))
        session = zenoh.open(conf)
        try:
            assert str(session.info.zid()) == zenoh_link.robot_zid(name)  # taken as it is
        finally:
            session.close()
    for bad in ("XYZ", "0abc"):
        with pytest.raises(ValueError, match="not 1-32 lowercase hex"):
            ZenohSettings(id=bad)


def _reply(zid: str | None, body: bytes) -> SimpleNamespace:
    sample = SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: body),
                             key_expr="placecell/sim1/status")
    replier = None if zid is None else SimpleNamespace(zid=zid)
    return SimpleNamespace(ok=sample, replier_id=replier)


def test_ctl_keeps_the_robots_replies_and_says_what_it_dropped(
        capsys: pytest.CaptureFixture[str]) -> None:
    robot = zenoh_link.robot_zid("sim1")
    replies = [_reply(robot, b"real"), _reply("666", b"forged"), _reply(None, b"who"),
               SimpleNamespace(ok=None, replier_id=None)]
    kept = [s.payload.to_bytes() for s in from_robot(replies, robot)]
    assert kept == [b"real"]
    said = capsys.readouterr().err
    assert "from 666, not the robot's node" in said and "an unknown node" in said
    # No robot named (placecellctl --robot unset, no config): every answer counts.
    assert len(list(from_robot(replies, None))) == 3
