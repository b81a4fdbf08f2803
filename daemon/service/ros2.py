"""The pose for ROS 2 nodes, exactly as rmw_zenoh carries it (design §11).

A ROS 2 system running rmw_zenoh (Humble, Jazzy) sees placecell as a node ``placecell``
with one publisher of ``geometry_msgs/msg/PoseWithCovarianceStamped`` on ``[ros2] topic``:
``ros2 topic echo /placecell/pose`` needs no bridge and no ROS install on our side.

The keys, CDR payloads, attachments and liveliness tokens are rmw_zenoh's, made by
hal/ros2_wire.py (shared with the ROS 2 camera and base backends).

The pose is in the ``map`` frame (design §6); the 6x6 covariance is the 3x3 of (x, y, yaw)
placed at rows/columns (0, 1, 5), the others 0 as nav2's AMCL publishes them.

With ``[ros2] tf`` the node also publishes ``tf2_msgs/msg/TFMessage`` on ``/tf`` as nav2's
AMCL does (``amcl_node.cpp``): ``map -> odom`` = (map -> base) ∘ (odom -> base)⁻¹ from the
pose and the base's odometry at the frame's stamp, post-dated by
``transform_tolerance_s`` and re-sent every ``tf_period_s`` while tracking, nothing
before the first tracked pose; and with ``odom_tf`` the odometry itself as ``odom ->
base_link`` (for a base no ROS driver publishes). It subscribes to ``[ros2]
initial_pose_topic`` (rviz's 2D Pose Estimate): the caller sets the pose from it. The
filter's particles go out as a ``geometry_msgs/msg/PoseArray`` on ``particle_cloud_topic``
each tracked frame (at most ``particle_cloud_size``, evenly drawn; nav2's own
``nav2_msgs/ParticleCloud`` is not in rosbags' type store, and rviz shows a PoseArray).
It serves AMCL's two services as rmw_zenoh serves them (a complete queryable on the
service key, the request's attachment echoed with a new time):
``/reinitialize_global_localization`` (std_srvs/Empty: a global search) and
``/set_initial_pose`` (nav2_msgs/SetInitialPose: as /initialpose), with ``SS`` tokens.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh
import zenoh.ext

from daemon.config import Ros2Settings
from hal import ros2_wire as wire
from kernel.se2 import SE2, turned_covariance

MSG_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF_TYPE = "tf2_msgs/msg/TFMessage"
CLOUD_TYPE = "geometry_msgs/msg/PoseArray"
# nav2_amcl's services (their definitions; rosbags has no srv types, hal/ros2_wire.py
# registers them and computes their hashes as rosidl does).
EMPTY_SRV, SET_POSE_SRV = "std_srvs/srv/Empty", "nav2_msgs/srv/SetInitialPose"
EMPTY_SRV_HASH = wire.register_service(EMPTY_SRV, "", "")
SET_POSE_SRV_HASH = wire.register_service(
    SET_POSE_SRV, "geometry_msgs/PoseWithCovarianceStamped pose\n", "")
RELOCALISE_SERVICE, SET_POSE_SERVICE = "/reinitialize_global_localization", "/set_initial_pose"
TF_TOPIC = "/tf"
# rmw_zenoh's name for it: <package>::msg::dds_::<Type>_
MANGLED_TYPE = "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"
# REP-2011 type hash (RIHS01) of the message definition; Humble and Jazzy alike.
TYPE_HASH = "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e"
NODE_NAME = "placecell"
QOS_KEYEXPR = wire.QOS_KEYEXPR
TF_QOS_KEYEXPR = "::,100:,:,:,,"  # tf2's publisher depth
GID_LENGTH = wire.GID_LENGTH

_TYPESTORE = wire.TYPESTORE
log = logging.getLogger(__name__)

# The rmw_zenoh names and wire helpers (hal/ros2_wire.py), with this node's defaults.
mangle, mangled_type, gid, attachment, type_hash = wire.mangle, wire.mangled_type, \
    wire.gid, wire.attachment, wire.type_hash


def topic_key(domain_id: int, topic: str, msg_type: str = MSG_TYPE) -> str:
    return wire.topic_key(domain_id, topic, msg_type)


def node_token(domain_id: int, zid: str, node_id: int) -> str:
    return wire.node_token(domain_id, zid, node_id, NODE_NAME)


def publisher_token(domain_id: int, zid: str, node_id: int, entity_id: int,
                    topic: str, msg_type: str = MSG_TYPE, qos: str = QOS_KEYEXPR) -> str:
    return wire.entity_token("MP", domain_id, zid, node_id, entity_id, NODE_NAME, topic,
                             msg_type, qos)


def subscription_token(domain_id: int, zid: str, node_id: int, entity_id: int,
                       topic: str, msg_type: str = MSG_TYPE, qos: str = QOS_KEYEXPR) -> str:
    return wire.entity_token("MS", domain_id, zid, node_id, entity_id, NODE_NAME, topic,
                             msg_type, qos)


def decode_pose(payload: bytes) -> tuple[SE2, np.ndarray, str]:
    """A PoseWithCovarianceStamped from CDR: the pose in the plane, the 3x3 covariance of
    (x, y, yaw) taken from rows/columns (0, 1, 5), and ``header.frame_id``. ValueError for
    a payload that is not one."""
    try:
        msg: Any = _TYPESTORE.deserialize_cdr(payload, MSG_TYPE)
    except Exception as e:  # noqa: BLE001 - rosbags raises several kinds on bad bytes
        raise ValueError(f"not a {MSG_TYPE}: {e}") from e
    return pose_of(msg)


def pose_of(msg: Any) -> tuple[SE2, np.ndarray, str]:
    """decode_pose's values of a decoded PoseWithCovarianceStamped."""
    p = msg.pose.pose.position
    yaw = wire.yaw_of(msg.pose.pose.orientation)
    full = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(6, 6)
    idx = np.array([0, 1, 5])
    values = (p.x, p.y, yaw, *full[np.ix_(idx, idx)].ravel())
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"a {MSG_TYPE} with values that are not finite")
    return SE2(float(p.x), float(p.y), yaw), full[np.ix_(idx, idx)].copy(), \
        str(msg.header.frame_id)


_time, _quaternion = wire.ros_time, wire.quaternion


def pose_cdr(pose: SE2, covariance: np.ndarray, stamp_ns: int, frame_id: str) -> bytes:
    """PoseWithCovarianceStamped in CDR: ``pose`` (map frame) with its 3x3 covariance of
    (x, y, yaw) spread into ROS's 6x6 (x, y, z, roll, pitch, yaw)."""
    t = _TYPESTORE.types
    full = np.zeros((6, 6))
    idx = np.array([0, 1, 5])
    full[np.ix_(idx, idx)] = np.asarray(covariance, float).reshape(3, 3)
    msg = t[MSG_TYPE](
        header=t["std_msgs/msg/Header"](stamp=_time(stamp_ns), frame_id=frame_id),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=pose.x, y=pose.y, z=0.0),
                orientation=_quaternion(pose.yaw)),
            covariance=full.reshape(36)))
    return bytes(_TYPESTORE.serialize_cdr(msg, MSG_TYPE))




def tf_cdr(transforms: list[tuple[str, str, SE2, int]]) -> bytes:
    """TFMessage in CDR: one TransformStamped per (parent, child, T_parent_child, stamp
    since the UNIX epoch in ns), in the plane (z 0, yaw about z)."""
    t = _TYPESTORE.types
    stamped = [t["geometry_msgs/msg/TransformStamped"](
        header=t["std_msgs/msg/Header"](stamp=_time(stamp_ns), frame_id=parent),
        child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=T.x, y=T.y, z=0.0),
            rotation=_quaternion(T.yaw)))
        for parent, child, T, stamp_ns in transforms]
    return bytes(_TYPESTORE.serialize_cdr(t[TF_TYPE](transforms=stamped), TF_TYPE))


class Ros2PosePublisher:
    """One ROS 2 node on the daemon's zenoh session: the pose publisher and, with
    ``[ros2] tf``, a publisher on /tf (map -> odom, and odom -> base_link with
    ``odom_tf``)."""

    def __init__(self, session: zenoh.Session, settings: Ros2Settings) -> None:
        self.settings = settings
        zid = str(session.zid())
        node_id = 0  # the first entities of the session's ROS context
        self.node_token_key = node_token(settings.domain_id, zid, node_id)
        self._node_token = session.liveliness().declare_token(self.node_token_key)
        self._pose = wire.Publisher(
            session, settings.domain_id, node_id, 1, NODE_NAME, settings.topic, MSG_TYPE,
            wire.transient_local_qos(1) if settings.transient_local else QOS_KEYEXPR,
            transient_local=1 if settings.transient_local else 0)
        self.key, self.publisher_token_key = self._pose.key, self._pose.token_key
        self.gid = self._pose.gid
        self._tf = wire.Publisher(session, settings.domain_id, node_id, 2, NODE_NAME,
                                  TF_TOPIC, TF_TYPE, TF_QOS_KEYEXPR) if settings.tf else None
        self._cloud = wire.Publisher(session, settings.domain_id, node_id, 4, NODE_NAME,
                                     settings.particle_cloud_topic, CLOUD_TYPE) \
            if settings.particle_cloud_size > 0 else None
        self._session, self._zid, self._node_id = session, zid, node_id
        self._subscribers: list[Any] = []
        self.map_odom: SE2 | None = None  # the last map -> odom published

    def publish_tracked(self, in_map: SE2, place: SE2, covariance_in_place: np.ndarray,
                        stamp_ns: int, odometry: SE2 | None) -> None:
        """A tracked pose (design §11): ``in_map`` with its covariance turned by the
        place's heading in the map (``place``: the place's reference in the map frame);
        ``stamp_ns`` the frame's time on the UNIX clock; ``odometry`` (odom -> base at that
        time) gives map -> odom = (map -> base) ∘ (odom -> base)⁻¹, as AMCL publishes it."""
        self.publish(in_map, turned_covariance(covariance_in_place, place.yaw), stamp_ns)
        if odometry is not None:
            self.map_odom = in_map.compose(odometry.inverse())
            self.publish_tf(self.map_odom, stamp_ns,
                            odometry if self.settings.odom_tf else None)

    def publish_particles(self, particles_in_place: np.ndarray, place: SE2,
                          stamp_ns: int) -> None:
        """The filter's particles (N x 3, x y yaw in the place frame) in the map frame as a
        PoseArray: at most ``particle_cloud_size`` of them, evenly drawn (every k-th)."""
        if self._cloud is None or len(particles_in_place) == 0:
            return
        step = max(1, -(-len(particles_in_place) // self.settings.particle_cloud_size))
        p = particles_in_place[::step]
        c, s = math.cos(place.yaw), math.sin(place.yaw)
        xs = place.x + c * p[:, 0] - s * p[:, 1]
        ys = place.y + s * p[:, 0] + c * p[:, 1]
        t = _TYPESTORE.types
        poses = [t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
            orientation=_quaternion(float(place.yaw + yaw)))
            for x, y, yaw in zip(xs, ys, p[:, 2], strict=True)]
        self._cloud.put_message(t[CLOUD_TYPE](
            header=t["std_msgs/msg/Header"](stamp=_time(stamp_ns),
                                            frame_id=self.settings.frame_id), poses=poses))

    def resend_map_odom(self) -> None:
        """map -> odom again, post-dated from now (between frames: a slow frame must not
        let nav2's transform go stale); nothing before the first tracked pose. The caller
        calls it while tracking only."""
        if self.map_odom is not None:
            self.publish_tf(self.map_odom, time.time_ns())

    def on_initial_pose(self, handle: Callable[[SE2, np.ndarray, str], None]) -> None:
        """Subscribe to ``[ros2] initial_pose_topic`` (any publisher's type hash) and hand
        each decoded pose to ``handle``; a sample that is not a pose is logged and dropped."""
        s = self.settings
        key = f"{s.domain_id}/{s.initial_pose_topic.strip('/')}/{MANGLED_TYPE}/*"

        def received(sample: zenoh.Sample) -> None:
            try:
                handle(*decode_pose(sample.payload.to_bytes()))
            except ValueError as e:
                log.warning("%s: %s; ignored", s.initial_pose_topic, e)

        self._subscribers.append(self._session.declare_subscriber(key, received))
        self._subscribers.append(self._session.liveliness().declare_token(subscription_token(
            s.domain_id, self._zid, self._node_id, 3, s.initial_pose_topic)))

    def serve(self, relocalise: Callable[[], None],
              set_pose: Callable[[SE2, np.ndarray, str, str], None]) -> None:
        """AMCL's services: ``/reinitialize_global_localization`` (std_srvs/Empty) calls
        ``relocalise``; ``/set_initial_pose`` (nav2_msgs/SetInitialPose) hands its pose to
        ``set_pose`` as /initialpose does. Both answer with their empty response."""
        s = self.settings

        def relocalise_now(_: Any) -> Any:
            relocalise()
            return _TYPESTORE.types[f"{EMPTY_SRV}_Response"]()

        def set_pose_now(request: Any) -> Any:
            set_pose(*pose_of(request.pose), SET_POSE_SERVICE)
            return _TYPESTORE.types[f"{SET_POSE_SRV}_Response"]()

        def refused(message: str) -> None:
            log.warning("%s; answered with an error", message)

        self._subscribers += [
            wire.ServiceServer(self._session, s.domain_id, self._node_id, 5, NODE_NAME,
                               RELOCALISE_SERVICE, EMPTY_SRV, EMPTY_SRV_HASH,
                               relocalise_now, refused),
            wire.ServiceServer(self._session, s.domain_id, self._node_id, 6, NODE_NAME,
                               SET_POSE_SERVICE, SET_POSE_SRV, SET_POSE_SRV_HASH,
                               set_pose_now, refused)]

    def publish(self, pose: SE2, covariance: np.ndarray, stamp_ns: int) -> None:
        """``stamp_ns``: the frame's time since the UNIX epoch (ROS time)."""
        self._pose.put(pose_cdr(pose, covariance, stamp_ns, self.settings.frame_id))

    def publish_tf(self, map_odom: SE2, stamp_ns: int, odom_base: SE2 | None = None) -> None:
        """map -> odom valid from ``stamp_ns`` (ROS time, ns since the UNIX epoch),
        stamped ``transform_tolerance_s`` later as AMCL post-dates it; and odom -> base at
        ``stamp_ns`` itself when given."""
        if self._tf is None:
            return
        s = self.settings
        ahead_ns = int(s.transform_tolerance_s * 1e9)
        transforms = [(s.frame_id, s.odom_frame, map_odom, stamp_ns + ahead_ns)]
        if odom_base is not None:
            transforms.append((s.odom_frame, s.base_frame, odom_base, stamp_ns))
        self._tf.put(tf_cdr(transforms))

    def close(self) -> None:
        for subscriber in self._subscribers:
            subscriber.undeclare()
        self._node_token.undeclare()
        self._pose.close()
        for publisher in (self._tf, self._cloud):
            if publisher is not None:
                publisher.close()
