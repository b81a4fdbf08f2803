"""A client process for the load test (tests/test_service_load.py): ``--sessions`` zenoh
sessions, each its own subscriber on ``pose`` and ``belief``, for ``--duration`` seconds;
``{"ready": true}`` once every session receives both; then, as JSON on stdout, the pose
stamps and the belief count each session received."""

from __future__ import annotations

import argparse
import json
import threading
import time
from typing import Any

from tests.daemon_harness import client_session


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--robot", required=True)
    p.add_argument("--sessions", type=int, default=10)
    p.add_argument("--duration", type=float, default=60.0)
    args = p.parse_args()
    lock = threading.Condition()
    received: list[dict[str, Any]] = []
    sessions = []
    for _ in range(args.sessions):
        got: dict[str, Any] = {"pose": [], "belief": 0}
        received.append(got)
        session = client_session(args.port)

        def on_pose(sample: Any, got: dict[str, Any] = got) -> None:
            stamp = json.loads(sample.payload.to_bytes())["stamp_ns"]
            with lock:
                got["pose"].append(stamp)
                lock.notify_all()

        def on_belief(sample: Any, got: dict[str, Any] = got) -> None:
            with lock:
                got["belief"] += 1
                lock.notify_all()

        session.declare_subscriber(f"placecell/{args.robot}/pose", on_pose)
        session.declare_subscriber(f"placecell/{args.robot}/belief", on_belief)
        sessions.append(session)
    # Ready once every subscription is routed: each session has a pose and a belief.
    with lock:
        routed = lock.wait_for(lambda: all(g["pose"] and g["belief"] for g in received),
                               args.duration)
    print(json.dumps({"ready": routed}), flush=True)
    time.sleep(args.duration)
    with lock:
        out = json.dumps({"sessions": received})
    for session in sessions:
        session.close()
    print(out, flush=True)


if __name__ == "__main__":
    main()
