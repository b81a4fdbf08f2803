"""The fleet's routers (docs/fleet.md, config/fleet/router.json5): two zenohd processes
with the storage manager plugin, each storing the fleet's key space and replicating it.
What one robot puts through one router is stored by both; a router killed and restarted
empty takes what was put while it was away from the other; with the first router then gone
too, nothing stored is lost."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from daemon.service.zenoh_link import make_config
from tests.daemon_harness import free_port, wait_for
from tools.fleet_router import client_session, fleet_routers, stored

KEYS = "placecell/fleet/test"
START_S = 60.0  # a router's start on a loaded machine
# The replicas compare digests every `interval` (1 s in the shipped configuration); a
# restarted router aligns within a few of them.
CAUGHT_UP_S = 60.0

pytestmark = pytest.mark.xdist_group("zenohd")


def _stored_by(session: zenoh.Session, zid: str) -> set[str]:
    """The keys router ``zid``'s storage answers with (every storage is asked)."""
    return set(stored(session, f"{KEYS}/**", timeout_s=5.0).get(zid, {}))


def test_a_restarted_router_takes_what_it_missed_from_the_other(tmp_path: Path) -> None:
    ports = [free_port(), free_port()]
    with fleet_routers(ports, tmp_path, START_S) as (a, b):
        robot = client_session(a.endpoint)
        watcher = client_session(b.endpoint)
        try:
            # A client sends a put only where it knows a subscriber (the storages'): once
            # the router has told it of them.
            probe = robot.declare_publisher(f"{KEYS}/place/0")
            assert wait_for(lambda: probe.matching_status.matching, START_S, 0.05)
            first = {f"{KEYS}/place/{k}" for k in range(10)}
            for key in sorted(first):
                robot.put(key, json.dumps({"key": key}))
            # Both routers store what one robot put through one of them.
            assert wait_for(lambda: _stored_by(watcher, b.zid) >= first, CAUGHT_UP_S, 0.2), \
                _stored_by(watcher, b.zid)
            assert wait_for(lambda: _stored_by(watcher, a.zid) >= first, CAUGHT_UP_S, 0.2)
            b.stop()
            second = {f"{KEYS}/place/{k}" for k in range(10, 20)}
            for key in sorted(second):
                robot.put(key, json.dumps({"key": key}))
            b.start(START_S)  # empty: its storage is in memory
            watcher.close()
            watcher = client_session(b.endpoint)
            assert wait_for(lambda: _stored_by(watcher, b.zid) == first | second,
                            CAUGHT_UP_S, 0.2), sorted(_stored_by(watcher, b.zid))
            a.stop()  # the router the robot put through is gone: nothing is lost
            got = {str(r.ok.key_expr): json.loads(r.ok.payload.to_string())
                   for r in watcher.get(f"{KEYS}/**", timeout=5.0) if r.ok is not None}
            assert set(got) == first | second
            assert all(value == {"key": key} for key, value in got.items())
        finally:
            robot.close()
            watcher.close()


def test_robots_connected_to_both_routers_hear_each_other_through_either(
        tmp_path: Path) -> None:
    """Robots are zenoh peers (the daemon's session, ``[zenoh] mode = "peer"``) connected
    to every fleet router; a place one puts reaches the other's subscription through the
    routers (zenoh's failover brokering, which needs the routers' gossip), and still does
    with either router gone."""
    ports = [free_port(), free_port()]
    with fleet_routers(ports, tmp_path, START_S) as routers:
        endpoints = [r.endpoint for r in routers]
        robots = [zenoh.open(make_config("peer", [f"tcp/127.0.0.1:{free_port()}"], order,
                                         False, timestamping=True))
                  for order in (endpoints, endpoints[::-1])]
        heard: list[str] = []
        try:
            robots[1].declare_subscriber(f"{KEYS}/**", lambda s: heard.append(str(s.key_expr)))
            probe = robots[0].declare_publisher(f"{KEYS}/robot-a/place/0")
            assert wait_for(lambda: probe.matching_status.matching, START_S, 0.05)
            for gone in (None, *routers):
                if gone is not None:
                    gone.stop()
                key = f"{KEYS}/robot-a/place/{len(heard)}"
                # a put is routed once the routers know the peer's subscription
                assert wait_for(lambda k=key: robots[0].put(k, b"place") or k in heard,
                                CAUGHT_UP_S, 0.2), (gone, heard)
                if gone is not None:
                    gone.start(START_S)
        finally:
            for r in robots:
                r.close()
