"""The pose for ROS 2 nodes, exactly as rmw_zenoh carries it (design §11).

A ROS 2 system running rmw_zenoh (Humble, Jazzy) sees placecell as a node ``placecell``
with one publisher of ``geometry_msgs/msg/PoseWithCovarianceStamped`` on ``[ros2] topic``:
``ros2 topic echo /placecell/pose`` needs no bridge and no ROS install on our side.

What rmw_zenoh expects, and what this module makes:

- the topic key ``<domain>/<topic without leading slash>/<mangled type>/<type hash>``;
- the payload in CDR (XCDR1, little endian), written by ``rosbags`` (a well-kept
  serialiser; the message definitions are Jazzy's, whose hash equals Humble's here);
- a 33-byte attachment on every sample: the sequence number and the source timestamp
  (int64, ns since the UNIX epoch), then the publisher's 16-byte GID, in zenoh-ext's
  serialisation (a length byte before the GID) — subscribers drop samples without it;
- liveliness tokens for the node (``NN``) and the publisher (``MP``) under
  ``@ros2_lv/<domain>/...``, which is how the ROS graph (``ros2 node list``, ``ros2 topic
  list``) discovers them. The GID is XXH3-128 of the publisher's token, as rmw_zenoh
  computes it.

The pose is in the ``map`` frame (design §6); the 6x6 covariance is the 3x3 of (x, y, yaw)
placed at rows/columns (0, 1, 5), the others 0 as nav2's AMCL publishes them.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import xxhash
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore

from daemon.config import Ros2Settings
from kernel.se2 import SE2

MSG_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
# rmw_zenoh's name for it: <package>::msg::dds_::<Type>_
MANGLED_TYPE = "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"
# REP-2011 type hash (RIHS01) of the message definition; Humble and Jazzy alike.
TYPE_HASH = "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e"
NODE_NAME = "placecell"
# QoS as rmw_zenoh writes it in a token, fields equal to its defaults left empty:
# reliable, volatile, keep-last 10 (rclcpp's default depth; rmw_zenoh's own is 42).
QOS_KEYEXPR = "::,10:,:,:,,"
GID_LENGTH = 16

_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def mangle(name: str) -> str:
    """rmw_zenoh's mangling of names inside key expressions: '/' becomes '%'; an empty
    namespace or enclave ('/' or '') is '%'."""
    return name.replace("/", "%") if name else "%"


def topic_key(domain_id: int, topic: str) -> str:
    return f"{domain_id}/{topic.strip('/')}/{MANGLED_TYPE}/{TYPE_HASH}"


def node_token(domain_id: int, zid: str, node_id: int) -> str:
    return (f"@ros2_lv/{domain_id}/{zid}/{node_id}/{node_id}/NN/{mangle('/')}/"
            f"{mangle('/')}/{NODE_NAME}")


def publisher_token(domain_id: int, zid: str, node_id: int, entity_id: int,
                    topic: str) -> str:
    topic = topic if topic.startswith("/") else "/" + topic
    return (f"@ros2_lv/{domain_id}/{zid}/{node_id}/{entity_id}/MP/{mangle('/')}/"
            f"{mangle('/')}/{NODE_NAME}/{mangle(topic)}/{MANGLED_TYPE}/{TYPE_HASH}/"
            f"{QOS_KEYEXPR}")


def gid(token: str) -> bytes:
    """The entity's GID as rmw_zenoh derives it: XXH3-128 of its liveliness key, the low
    64 bits first, each little endian."""
    return xxhash.xxh3_128(token.encode()).intdigest().to_bytes(GID_LENGTH, "little")


def attachment(sequence: int, stamp_ns: int, publisher_gid: bytes) -> bytes:
    """The per-sample attachment: int64 sequence number, int64 source timestamp, the GID
    (zenoh-ext serialisation, as rmw_zenoh's AttachmentData writes it)."""
    out: bytes = zenoh.ext.z_serialize((zenoh.ext.Int64(sequence), zenoh.ext.Int64(stamp_ns),
                                        publisher_gid)).to_bytes()
    return out


def pose_cdr(pose: SE2, covariance: np.ndarray, stamp_ns: int, frame_id: str) -> bytes:
    """PoseWithCovarianceStamped in CDR: ``pose`` (map frame) with its 3x3 covariance of
    (x, y, yaw) spread into ROS's 6x6 (x, y, z, roll, pitch, yaw)."""
    t = _TYPESTORE.types
    full = np.zeros((6, 6))
    idx = np.array([0, 1, 5])
    full[np.ix_(idx, idx)] = np.asarray(covariance, float).reshape(3, 3)
    msg = t[MSG_TYPE](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                   nanosec=stamp_ns % 1_000_000_000),
            frame_id=frame_id),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=pose.x, y=pose.y, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(pose.yaw / 2.0), w=math.cos(pose.yaw / 2.0))),
            covariance=full.reshape(36)))
    return bytes(_TYPESTORE.serialize_cdr(msg, MSG_TYPE))


class Ros2PosePublisher:
    """One ROS 2 node with one publisher on the daemon's zenoh session."""

    def __init__(self, session: zenoh.Session, settings: Ros2Settings) -> None:
        self.settings = settings
        zid = str(session.zid())
        node_id, entity_id = 0, 1  # the first entities of the session's ROS context
        self.key = topic_key(settings.domain_id, settings.topic)
        self.node_token_key = node_token(settings.domain_id, zid, node_id)
        self.publisher_token_key = publisher_token(settings.domain_id, zid, node_id,
                                                   entity_id, settings.topic)
        self.gid = gid(self.publisher_token_key)
        self._sequence = 0
        self._tokens: list[Any] = [session.liveliness().declare_token(self.node_token_key)]
        self._publisher = session.declare_publisher(self.key)
        self._tokens.append(session.liveliness().declare_token(self.publisher_token_key))

    def publish(self, pose: SE2, covariance: np.ndarray, stamp_ns: int) -> None:
        """``stamp_ns``: the frame's time since the UNIX epoch (ROS time)."""
        self._sequence += 1
        self._publisher.put(pose_cdr(pose, covariance, stamp_ns, self.settings.frame_id),
                            attachment=attachment(self._sequence, time.time_ns(), self.gid))

    def close(self) -> None:
        for token in self._tokens:
            token.undeclare()
        self._publisher.undeclare()
