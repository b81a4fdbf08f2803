"""The other processes of the access-control test (tests/test_zenoh_acl.py), each a zenoh
node of its own driven by lines on stdin/stdout:

    python -m tests.acl_clients receive <zenoh.json5> <mode> <endpoint> <robot>
        subscribes to the robot's pose and events (and its ROS 2 pose) and to liveliness
        under placecell/** and @ros2_lv/**;
        prints "ready" once a real pose has arrived, then on "check" waits for five more
        real poses (so whatever was forged before has had its time), queries status,
        map/places and liveliness, and prints one JSON line of what it heard.
    python -m tests.acl_clients forge <zenoh.json5> <mode> <endpoint> <robot> <who> <n> [wait]
        on "go": puts n forged poses, ROS 2 poses and events (with ``wait``, once a
        subscriber of the pose is matched: the control case, a receiver without the
        rules), answers status
        and map/places with forged replies and holds forged liveliness tokens; prints
        "forged n"; holds them until its stdin closes. A client refused at the transport
        prints "refused: ..." instead.

Every forged payload carries ``"forged": <who>``; nothing here sleeps: readiness and the
ends of phases are lines exchanged with the test.
"""

from __future__ import annotations

import json
import sys
import threading
from typing import Any

import zenoh

from daemon.service import ros2, zenoh_link

# The pose for ROS 2 nodes ([ros2] enabled), on any domain.
ROS_POSE = "*/placecell/pose/**"


def _session(config_file: str, mode: str, endpoint: str) -> zenoh.Session:
    conf = zenoh.Config.from_file(config_file)
    conf.insert_json5("mode", json.dumps(mode))
    # A peer listens (so that others reach it directly, as peers do); a client does not.
    conf.insert_json5("listen/endpoints",
                      json.dumps(["tls/127.0.0.1:0"] if mode == "peer" else []))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def _forged_by(payload: bytes) -> str | None:
    try:
        body = json.loads(payload)
    except ValueError:
        return "unreadable"
    return body.get("forged") if isinstance(body, dict) else "unreadable"


def receive(config_file: str, mode: str, endpoint: str, robot: str) -> None:
    session = _session(config_file, mode, endpoint)
    lock = threading.Condition()
    heard: dict[str, Any] = {"real_poses": 0, "forged_poses": [], "forged_events": [],
                             "tokens": [], "real_ros_poses": 0, "ros_tokens": []}

    def on_pose(sample: zenoh.Sample) -> None:
        forger = _forged_by(sample.payload.to_bytes())
        with lock:
            if forger is None:
                heard["real_poses"] += 1
            else:
                heard["forged_poses"].append(forger)
            lock.notify_all()

    def on_event(sample: zenoh.Sample) -> None:
        forger = _forged_by(sample.payload.to_bytes())
        if forger is not None:
            with lock:
                heard["forged_events"].append(forger)

    def on_token(sample: zenoh.Sample) -> None:
        with lock:
            heard["tokens"].append(str(sample.key_expr))

    def on_ros_pose(sample: zenoh.Sample) -> None:  # CDR from the robot, JSON if forged
        payload = sample.payload.to_bytes()
        with lock:
            if payload.startswith(b"{"):
                heard["forged_poses"].append(_forged_by(payload))
            else:
                heard["real_ros_poses"] += 1

    def on_ros_token(sample: zenoh.Sample) -> None:
        with lock:
            heard["ros_tokens"].append(str(sample.key_expr))

    keep = [session.declare_subscriber(zenoh_link.key(robot, "pose"), on_pose),
            zenoh_link.declare_history_subscriber(session, zenoh_link.key(robot, "events"),
                                                  on_event),
            session.liveliness().declare_subscriber("placecell/**", on_token, history=True),
            session.declare_subscriber(ROS_POSE, on_ros_pose),
            session.liveliness().declare_subscriber("@ros2_lv/**", on_ros_token,
                                                    history=True)]

    def wait_poses(n: int) -> None:
        with lock:
            target = heard["real_poses"] + n
            if not lock.wait_for(lambda: heard["real_poses"] >= target, timeout=120):
                raise SystemExit(f"no real pose heard ({heard['real_poses']} so far)")

    wait_poses(1)
    print("ready", flush=True)
    for line in sys.stdin:
        if line.strip() == "check":
            break
    wait_poses(5)
    replies: dict[str, list[str | None]] = {}
    for leaf in ("status", "map/places"):
        got = session.get(zenoh_link.key(robot, leaf), timeout=5,
                          consolidation=zenoh.ConsolidationMode.NONE)
        replies[leaf] = [_forged_by(r.ok.payload.to_bytes()) for r in got if r.ok is not None]
    # The robot's own keys (what a watcher may ask for) and everyone's (which the robot's
    # rules do not answer in client mode: the robot's token need not be among them).
    alive = {pattern: [str(r.ok.key_expr) for r in
                       session.liveliness().get(pattern, timeout=5) if r.ok is not None]
             for pattern in (zenoh_link.key(robot, "**"), "placecell/**")}
    with lock:
        print(json.dumps({**heard, "replies": replies, "alive": alive}), flush=True)
    del keep
    session.close()


def forge(config_file: str, mode: str, endpoint: str, robot: str, who: str, n: int,
          wait_matching: bool) -> None:
    try:
        session = _session(config_file, mode, endpoint)
    except zenoh.ZError as e:  # a client whose certificate nobody accepts
        print(f"refused: {e}", flush=True)
        return
    publisher = session.declare_publisher(zenoh_link.key(robot, "pose"))
    matched = threading.Event()
    listener = publisher.declare_matching_listener(
        lambda status: matched.set() if status.matching else None)
    if publisher.matching_status.matching:
        matched.set()
    fake = json.dumps({"schema": "placecell.pose/1", "forged": who}).encode()
    held = [session.liveliness().declare_token(zenoh_link.key(robot, f"{who}/alive")),
            session.liveliness().declare_token(f"placecell/{who}/alive"),
            session.liveliness().declare_token(
                f"@ros2_lv/0/{session.info.zid()}/0/11/MP/%/%/placecell/%placecell%pose/"
                f"{ros2.MANGLED_TYPE}/{ros2.TYPE_HASH}/{ros2.QOS_KEYEXPR}")]
    for leaf in ("status", "map/places"):
        held.append(session.declare_queryable(
            zenoh_link.key(robot, leaf),
            lambda query: query.reply(query.key_expr, json.dumps(
                {"schema": "placecell.status/1", "forged": who, "id": 666,
                 "label": "FORGED"}).encode())))
    for line in sys.stdin:
        if line.strip() == "go":
            break
    if wait_matching and not matched.wait(120):
        raise SystemExit("the control receiver was never matched")
    for _ in range(n):
        publisher.put(fake)
        session.put(ros2.topic_key(0, "/placecell/pose"), fake)
        session.put(zenoh_link.key(robot, "events"), fake)
    print(f"forged {n}", flush=True)
    for _ in sys.stdin:  # hold the tokens and queryables until the test is done
        pass
    del held, listener
    session.close()


if __name__ == "__main__":
    role, config_file, mode, endpoint, robot, *rest = sys.argv[1:]
    if role == "receive":
        receive(config_file, mode, endpoint, robot)
    else:
        forge(config_file, mode, endpoint, robot, rest[0], int(rest[1]), rest[2:] == ["wait"])
