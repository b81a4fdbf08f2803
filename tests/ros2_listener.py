"""A ROS 2 subscriber's view of the daemon, as rmw_zenoh would have it, in its own process:
``python -m tests.ros2_listener PORT ROBOT OUT SECONDS``.

It subscribes to every PoseWithCovarianceStamped-shaped key of domain 0 (the type and hash
segments left open, so the test checks what the daemon put there), to the liveliness
tokens of the domain (with the ones already declared), and to the daemon's own JSON
``pose``; each sample becomes one JSON line in OUT. The CDR is decoded by ``rosbags``,
nothing of the daemon's code is imported.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

import zenoh
from rosbags.typesys import Stores, get_typestore

from tests.daemon_harness import client_session

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
MSG_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"


def _decode(payload: bytes) -> dict[str, Any]:
    msg = TYPESTORE.deserialize_cdr(payload, MSG_TYPE)
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec,
            "frame_id": msg.header.frame_id, "position": [p.x, p.y, p.z],
            "orientation": [q.x, q.y, q.z, q.w], "covariance": msg.pose.covariance.tolist()}


def _decode_tf(payload: bytes) -> list[dict[str, Any]]:
    msg = TYPESTORE.deserialize_cdr(payload, "tf2_msgs/msg/TFMessage")
    return [{"sec": t.header.stamp.sec, "nanosec": t.header.stamp.nanosec,
             "parent": t.header.frame_id, "child": t.child_frame_id,
             "translation": [t.transform.translation.x, t.transform.translation.y,
                             t.transform.translation.z],
             "rotation": [t.transform.rotation.x, t.transform.rotation.y,
                          t.transform.rotation.z, t.transform.rotation.w]}
            for t in msg.transforms]


def main(argv: list[str]) -> int:
    port, robot, out_path, seconds = int(argv[0]), argv[1], argv[2], float(argv[3])
    lock = threading.Lock()
    out = open(out_path, "w")  # noqa: SIM115 - closed below, written from callbacks

    def write(record: dict[str, Any]) -> None:
        with lock:
            out.write(json.dumps(record) + "\n")
            out.flush()

    def on_ros(sample: zenoh.Sample) -> None:
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
        payload = sample.payload.to_bytes()
        write({"kind": "ros", "key": str(sample.key_expr), "attachment": attachment.hex(),
               "payload_len": len(payload), "payload": payload.hex(),
               "message": _decode(payload), "received_ns": time.time_ns()})

    def on_tf(sample: zenoh.Sample) -> None:
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
        write({"kind": "tf", "key": str(sample.key_expr), "attachment": attachment.hex(),
               "transforms": _decode_tf(sample.payload.to_bytes()),
               "received_ns": time.time_ns()})

    def on_cloud(sample: zenoh.Sample) -> None:
        msg = TYPESTORE.deserialize_cdr(sample.payload.to_bytes(), "geometry_msgs/msg/PoseArray")
        xy = [(p.position.x, p.position.y) for p in msg.poses]
        write({"kind": "cloud", "key": str(sample.key_expr), "frame_id": msg.header.frame_id,
               "n": len(xy), "mean": [sum(x for x, _ in xy) / max(len(xy), 1),
                                      sum(y for _, y in xy) / max(len(xy), 1)]})

    def on_token(sample: zenoh.Sample) -> None:
        write({"kind": "token", "key": str(sample.key_expr),
               "alive": sample.kind == zenoh.SampleKind.PUT})

    first_pose = threading.Event()

    def on_pose(sample: zenoh.Sample) -> None:
        write({"kind": "pose", "body": json.loads(sample.payload.to_bytes())})
        first_pose.set()

    session = client_session(port)
    try:
        # The JSON pose first: the daemon puts it before the ROS message of the same frame,
        # so once one has arrived every ROS sample heard has its JSON twin in OUT.
        subscribers = [session.declare_subscriber(f"placecell/{robot}/pose", on_pose)]
        started = time.monotonic()
        first_pose.wait(seconds)
        subscribers += [
            session.declare_subscriber("0/placecell/pose/*/*", on_ros),
            session.declare_subscriber("0/tf/*/*", on_tf),
            session.declare_subscriber("0/particle_cloud/*/*", on_cloud),
            session.liveliness().declare_subscriber("@ros2_lv/0/**", on_token, history=True),
        ]
        time.sleep(max(0.0, seconds - (time.monotonic() - started)))
        for s in subscribers:
            s.undeclare()
    finally:
        session.close()
        out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
