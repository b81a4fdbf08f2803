"""ROS 2 as rmw_zenoh puts it on the wire, for the ROS 2 backends (hal/camera/ros2.py,
hal/base/ros2.py) and the daemon's ROS 2 node (daemon/service/ros2.py); no ROS install.

What rmw_zenoh (Humble, Jazzy) expects (docs/design.md §11):

- a topic's data key ``<domain>/<topic without leading slash>/<mangled type>/<type hash>``,
  the mangled type ``<package>::msg::dds_::<Type>_``, the hash REP-2011's RIHS01 of the
  definition (``rosbags`` computes it; Jazzy's definitions, whose hashes equal Humble's
  for the messages used here);
- payloads in CDR (XCDR1, little endian), written and read by ``rosbags``;
- a 33-byte attachment on every sample: the sequence number and the source timestamp
  (int64, ns since the UNIX epoch), then the publisher's 16-byte GID, in zenoh-ext's
  serialisation — subscribers drop samples without it;
- liveliness tokens for a node (``NN``), its publishers (``MP``) and subscriptions
  (``MS``) under ``@ros2_lv/<domain>/...``, '/' inside a field written '%'; that is how
  the ROS graph (``ros2 node list``, ``ros2 topic info``) discovers them. The GID is
  XXH3-128 of the entity's token.
"""

from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

import xxhash
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
# QoS as rmw_zenoh writes it in a token, fields equal to its defaults left empty:
# reliable, volatile, keep-last 10 (rclcpp's default depth; rmw_zenoh's own is 42).
QOS_KEYEXPR = "::,10:,:,:,,"
GID_LENGTH = 16


def transient_local_qos(depth: int) -> str:
    """The token's QoS of a transient-local publisher keeping ``depth`` samples (durability
    1, RMW_QOS_POLICY_DURABILITY_TRANSIENT_LOCAL; the other fields rmw_zenoh's defaults)."""
    return f":1:,{depth}:,:,:,,"


def register_service(service_type: str, request: str, response: str) -> str:
    """Register ``<service_type>_Request`` and ``_Response`` (message definitions, as the
    two halves of a .srv) in TYPESTORE, and return the service's RIHS01 hash: REP-2011's
    hash of the type description with fields request_message, response_message and
    event_message (``_Event``: info, request[<=1], response[<=1]) — rosidl's. Computed in a
    store of its own whose service_msgs/ServiceEventInfo has ``uint8[16] client_gid`` as
    rosidl sees it (rosbags ships it as char[16], which hashes otherwise); checked against
    hashes a ROS build generated (tests/test_ros2.py)."""
    req = next(iter(get_types_from_msg(request, "placecell_srv/msg/Request").values()))
    resp = next(iter(get_types_from_msg(response, "placecell_srv/msg/Response").values()))
    halves = {f"{service_type}_Request": req, f"{service_type}_Response": resp}
    if f"{service_type}_Request" not in TYPESTORE.fielddefs:
        TYPESTORE.register(halves)
    store = get_typestore(Stores.ROS2_JAZZY)
    store.fielddefs.pop("service_msgs/msg/ServiceEventInfo", None)
    store.register({
        **get_types_from_msg("uint8 event_type\nbuiltin_interfaces/Time stamp\n"
                             "uint8[16] client_gid\nint64 sequence_number\n",
                             "service_msgs/msg/ServiceEventInfo"),
        **halves,
        f"{service_type}_Event": ([], [
            ("info", (Nodetype.NAME, "service_msgs/msg/ServiceEventInfo")),
            ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, f"{service_type}_Request"), 1))),
            ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, f"{service_type}_Response"),
                                              1)))])})
    store.register({service_type: ([], [
        ("request_message", (Nodetype.NAME, f"{service_type}_Request")),
        ("response_message", (Nodetype.NAME, f"{service_type}_Response")),
        ("event_message", (Nodetype.NAME, f"{service_type}_Event"))])})
    return str(store.hash_rihs01(service_type))


def open_session(connect: list[str] | tuple[str, ...] = (),
                 listen: list[str] | tuple[str, ...] = (), timestamping: bool = False
                 ) -> zenoh.Session:
    """A zenoh peer on exactly these endpoints (none but them: no default listener on every
    address), multicast scouting off; ``timestamping`` for transient-local publishers."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if timestamping:
        conf.insert_json5("timestamping/enabled", "true")
    return zenoh.open(conf)


def mangle(name: str) -> str:
    """rmw_zenoh's mangling of names inside key expressions: '/' becomes '%'; an empty
    namespace or enclave ('/' or '') is '%'."""
    return name.replace("/", "%") if name else "%"


def mangled_type(msg_type: str) -> str:
    """rmw_zenoh's name of a message type: <package>::msg::dds_::<Type>_."""
    package, kind, name = msg_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def type_hash(msg_type: str) -> str:
    """The REP-2011 type hash (RIHS01) of a message definition."""
    return str(TYPESTORE.hash_rihs01(msg_type))


def topic_key(domain_id: int, topic: str, msg_type: str) -> str:
    return f"{domain_id}/{topic.strip('/')}/{mangled_type(msg_type)}/{type_hash(msg_type)}"


def node_token(domain_id: int, zid: str, node_id: int, node_name: str) -> str:
    return (f"@ros2_lv/{domain_id}/{zid}/{node_id}/{node_id}/NN/{mangle('/')}/"
            f"{mangle('/')}/{node_name}")


def entity_token(kind: str, domain_id: int, zid: str, node_id: int, entity_id: int,
                 node_name: str, topic: str, msg_type: str, qos: str = QOS_KEYEXPR,
                 hash_: str | None = None) -> str:
    """A publisher's (``MP``), subscription's (``MS``) or service server's (``SS``)
    liveliness token; ``hash_`` for a service type (type_hash knows messages only)."""
    topic = topic if topic.startswith("/") else "/" + topic
    return (f"@ros2_lv/{domain_id}/{zid}/{node_id}/{entity_id}/{kind}/{mangle('/')}/"
            f"{mangle('/')}/{node_name}/{mangle(topic)}/{mangled_type(msg_type)}/"
            f"{hash_ or type_hash(msg_type)}/{qos}")


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


def ros_time(stamp_ns: int) -> Any:
    """builtin_interfaces/Time of ``stamp_ns`` (ns since the UNIX epoch)."""
    return TYPESTORE.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                         nanosec=stamp_ns % 1_000_000_000)


class _ClockOffset:
    """The UNIX clock minus the monotonic clock (ns), read between two monotonic reads
    so a thread pre-empted between the reads (a busy machine: tens of ms) never skews
    a stamp: such a reading is passed over and the last clean one kept."""

    CLEAN_NS = 200_000  # the two monotonic reads within 0.2 ms: the reading is clean

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._offset_ns: int | None = None

    def now(self) -> int:
        for _ in range(3):
            before = time.monotonic_ns()
            unix = time.time_ns()
            after = time.monotonic_ns()
            if after - before <= self.CLEAN_NS:
                offset = unix - (before + after) // 2
                with self._lock:
                    self._offset_ns = offset
                return offset
        with self._lock:
            if self._offset_ns is not None:
                return self._offset_ns
        return unix - (before + after) // 2  # never clean yet: the best there is


_CLOCK_OFFSET = _ClockOffset()


def monotonic_of(ros_stamp_ns: int) -> int:
    """A ROS stamp (ns since the UNIX epoch) on the monotonic clock the daemon stamps
    with, by the offset of the two clocks now: a robot's stamps keep their spacing."""
    return ros_stamp_ns - _CLOCK_OFFSET.now()


def stamp_of(ros_time_msg: Any) -> int:
    """ns since the UNIX epoch of a builtin_interfaces/Time."""
    return int(ros_time_msg.sec) * 1_000_000_000 + int(ros_time_msg.nanosec)


def quaternion(yaw: float) -> Any:
    """A rotation about z by ``yaw`` (rad)."""
    return TYPESTORE.types["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))


def yaw_of(q: Any) -> float:
    """The rotation about z of a quaternion (the plane's heading)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class Publisher:
    """One rmw_zenoh publisher: its key, liveliness token, GID and sequence. With
    ``transient_local`` (depth samples kept, as ``/tf_static`` or AMCL's ``amcl_pose``) it
    is zenoh-ext's AdvancedPublisher with a cache of ``transient_local`` samples and
    publisher detection, as rmw_zenoh makes one: a late AdvancedSubscriber with history
    gets the last samples at once."""

    def __init__(self, session: zenoh.Session, domain_id: int, node_id: int,
                 entity_id: int, node_name: str, topic: str, msg_type: str,
                 qos: str = QOS_KEYEXPR, transient_local: int = 0) -> None:
        self.msg_type = msg_type
        self.key = topic_key(domain_id, topic, msg_type)
        self.token_key = entity_token("MP", domain_id, str(session.zid()), node_id, entity_id,
                                      node_name, topic, msg_type, qos)
        self.gid = gid(self.token_key)
        self._sequence = 0
        self._publisher: Any = zenoh.ext.declare_advanced_publisher(
            session, self.key, cache=zenoh.ext.CacheConfig(transient_local),
            publisher_detection=True) if transient_local > 0 \
            else session.declare_publisher(self.key)
        self._token = session.liveliness().declare_token(self.token_key)

    def put(self, payload: bytes) -> None:
        self._sequence += 1
        self._publisher.put(payload,
                            attachment=attachment(self._sequence, time.time_ns(), self.gid))

    def put_message(self, msg: Any) -> None:
        self.put(bytes(TYPESTORE.serialize_cdr(msg, self.msg_type)))

    def close(self) -> None:
        self._token.undeclare()
        self._publisher.undeclare()


class ServiceServer:
    """One rmw_zenoh service server: a queryable (complete) on the service key and an
    ``SS`` liveliness token. Each request's attachment (sequence number, time, client GID)
    is echoed in the reply with a new time; ``handle(request) -> response`` works on the
    decoded messages; a request that does not decode gets an error reply naming what is
    wrong (and the caller's ``on_error``)."""

    def __init__(self, session: zenoh.Session, domain_id: int, node_id: int,
                 entity_id: int, node_name: str, service: str, service_type: str,
                 service_hash: str, handle: Any, on_error: Any) -> None:
        self.key = f"{domain_id}/{service.strip('/')}/{mangled_type(service_type)}/{service_hash}"
        self.token_key = entity_token("SS", domain_id, str(session.zid()), node_id, entity_id,
                                      node_name, service, service_type, hash_=service_hash)
        self._type, self._handle, self._on_error = service_type, handle, on_error
        self._queryable = session.declare_queryable(self.key, self._query, complete=True)
        self._token = session.liveliness().declare_token(self.token_key)

    def _query(self, query: zenoh.Query) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            request = TYPESTORE.deserialize_cdr(payload, f"{self._type}_Request")
            if query.attachment is None:
                raise ValueError("no attachment (sequence number, time, client GID)")
            sequence, _, client = zenoh.ext.z_deserialize(
                tuple[zenoh.ext.Int64, zenoh.ext.Int64, bytes], query.attachment)
        except Exception as e:  # noqa: BLE001 - a request from someone else's node
            why = f"{self.key}: a request that is not a {self._type}: {e}"
            self._on_error(why)
            query.reply_err(why)  # the client hears what is wrong, not a timeout
            return
        response = self._handle(request)
        query.reply(self.key, bytes(TYPESTORE.serialize_cdr(response, f"{self._type}_Response")),
                    attachment=attachment(int(sequence), time.time_ns(), bytes(client)))

    def undeclare(self) -> None:
        self._token.undeclare()
        self._queryable.undeclare()
