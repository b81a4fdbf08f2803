"""Operator-only commands (design §11, config/zenoh-acl.json5): the daemon with the
shipped access control, an operator whose commands are answered, a viewer whose cmd/*
queries reach nothing while it still receives the pose and cannot publish one, and a
client without credentials that gets nothing — each its own process, loopback only."""

from __future__ import annotations

import json
import subprocess
import tomllib
from pathlib import Path

from tests.daemon_harness import REPO, running_daemon, venv_bin, wait_for, write_config

ACL = REPO / "config" / "zenoh-acl.json5"
USERS = REPO / "config" / "zenoh-users.example"


# A viewer's process putting fake poses on the robot's key (argv: credentials, endpoint).
FORGE = """
import json, sys, time, zenoh
conf = zenoh.Config.from_file(sys.argv[1])
conf.insert_json5("mode", '"peer"')
conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[2]]))
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
publisher = session.declare_publisher("placecell/acl/pose")
end = time.monotonic() + 10.0  # until the route to a subscriber is up (or surely never)
while not publisher.matching_status.matching and time.monotonic() < end:
    time.sleep(0.01)
fake = json.dumps({"schema": "placecell.pose/1", "forged": True}).encode()
for _ in range(20):
    publisher.put(fake)
    time.sleep(0.05)
print("forged 20")
session.close()
"""


def _endpoint(config: Path) -> str:
    return str(tomllib.loads(config.read_text())["zenoh"]["listen"][0])


def _client_file(tmp: Path, user: str) -> Path:
    password = next(line.split(":", 1)[1] for line in USERS.read_text().splitlines()
                    if line.startswith(f"{user}:"))
    path = tmp / f"{user}.json5"
    path.write_text(json.dumps({"transport": {"auth": {"usrpwd": {
        "user": user, "password": password}}}}))
    return path


def _ctl(config: Path, client: Path | None, *args: str) -> subprocess.CompletedProcess[str]:
    who = ["--zenoh-config", str(client)] if client is not None else []
    return subprocess.run([venv_bin("placecellctl"), "--config", str(config), *who, *args],
                          cwd=REPO, capture_output=True, text=True, timeout=60)


def test_only_operators_command_viewers_watch_strangers_get_nothing(tmp_path: Path) -> None:
    acl = tmp_path / "zenoh-acl.json5"  # the shipped file, the users' file where the test has it
    acl.write_text(ACL.read_text().replace("/etc/placecell/zenoh-users.txt", str(USERS)))
    config, _ = write_config(tmp_path, {"robot": {"name": "acl"},
                                        "zenoh": {"config_file": str(acl)}})
    operator, viewer = _client_file(tmp_path, "operator"), _client_file(tmp_path, "viewer")
    with running_daemon(config):
        def up() -> bool:
            return _ctl(config, operator, "mode", "--json").returncode == 0

        assert wait_for(up, 60, 0.5), "the operator's commands were never answered"
        mode = _ctl(config, operator, "mode", "--json")
        assert json.loads(mode.stdout)["mode"] == "mapping"
        # relocalise on an empty map: answered, and refused with the reason.
        asked = _ctl(config, operator, "relocalise")
        assert asked.returncode == 4 and "no places" in asked.stderr, asked
        # The viewer: every command reaches nothing (3: not reachable)...
        for args in (("mode", "--json"), ("relocalise",), ("learn", "--json")):
            refused = _ctl(config, viewer, "--timeout", "2", *args)
            assert refused.returncode == 3, (args, refused.returncode, refused.stderr)
        # ...while the pose flows to it, and to the operator.
        for who in (viewer, operator):
            pose = _ctl(config, who, "pose", "--json")
            assert pose.returncode == 0, pose.stderr
            assert json.loads(pose.stdout.splitlines()[-1])["schema"] == "placecell.pose/1"
        # Only the robot publishes: a viewer's forged poses never reach the operator.
        follower = subprocess.Popen(
            [venv_bin("placecellctl"), "--config", str(config), "--zenoh-config",
             str(operator), "pose", "--follow", "--json", "--duration", "4"],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        forger = subprocess.run([venv_bin("python"), "-c", FORGE, str(viewer),
                                 _endpoint(config)], cwd=REPO, capture_output=True,
                                text=True, timeout=60)
        assert forger.returncode == 0 and "forged 20" in forger.stdout, forger.stderr
        seen = [json.loads(line) for line in follower.communicate(timeout=60)[0].splitlines()]
        assert len(seen) > 10 and not any(p.get("forged") for p in seen), seen[-1:]
        # No credentials: refused at the transport, nothing heard.
        stranger = _ctl(config, None, "--timeout", "2", "pose", "--json")
        assert stranger.returncode == 3, (stranger.returncode, stranger.stdout)
        assert _ctl(config, None, "--timeout", "2", "mode").returncode == 3
