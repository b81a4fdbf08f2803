"""The `ros2` camera backend: images from a ROS 2 topic over rmw_zenoh, no ROS install.

A ROS 2 system running rmw_zenoh (Humble, Jazzy) publishes a topic on the zenoh key
``<domain>/<topic>/<package>::msg::dds_::<Type>_/<type hash>`` with the message in CDR
(docs/design.md §11). This backend opens its own zenoh session (a peer connecting to
``connect``: the ROS system's router, by default rmw_zenoh's ``tcp/127.0.0.1:7447``;
multicast scouting off) and subscribes to ``<domain>/<topic>/*/*``, taking
``sensor_msgs/msg/Image`` (``mono8``, ``rgb8``, ``bgr8``) and
``sensor_msgs/msg/CompressedImage`` (``jpeg``, ``png``) alike, told apart by the type in
the key; the CDR is read by ``rosbags``. Like the v4l2 backend it keeps only the newest
frame (a one-slot mailbox): a slow daemon skips frames, it never queues them.

Stamps: a frame is stamped with its message's ``header.stamp`` (the capture time, ROS
time since the UNIX epoch) carried onto the daemon's monotonic clock by the offset between
the two clocks when it arrives, so frames and odometry from the same robot keep their
spacing. (A ROS system on simulated time, ``use_sim_time``, is not supported: its stamps
are not the wall clock.) A message that is not an image of a supported encoding is
counted (``bad_messages``), logged once per kind, and dropped; the camera does not stop.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
import zenoh

from hal.camera.base import CameraInfo, Frame
from hal.camera.settings import Ros2CameraSettings
from hal.ros2_wire import TYPESTORE, mangled_type, monotonic_of, open_session, stamp_of
from kernel.errors import DeviceInitError, DeviceTimeoutError

log = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
_BY_MANGLED = {mangled_type(t): t for t in (IMAGE, COMPRESSED)}  # the type in the key


def subscription_key(domain_id: int, topic: str) -> str:
    """Every type published on ``topic`` in ``domain_id`` (any type hash)."""
    return f"{domain_id}/{topic.strip('/')}/*/*"


def decode_image(msg_type: str, payload: bytes) -> tuple[np.ndarray, int]:
    """A BGR (or grey, for mono8) image and its header stamp (ns since the UNIX epoch)
    from a CDR ``Image`` or ``CompressedImage``; ValueError naming what is wrong."""
    try:
        msg: Any = TYPESTORE.deserialize_cdr(payload, msg_type)
    except Exception as e:  # noqa: BLE001 - rosbags raises several kinds on bad bytes
        raise ValueError(f"not a {msg_type}: {e}") from e
    stamp_ns = stamp_of(msg.header.stamp)
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg_type == COMPRESSED:
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"a CompressedImage (format {msg.format!r}) that OpenCV cannot "
                             "decode (jpeg and png are supported)")
        if image.ndim == 3 and image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        return image, stamp_ns
    channels = {"mono8": 1, "rgb8": 3, "bgr8": 3}.get(msg.encoding)
    if channels is None:
        raise ValueError(f"an Image with encoding {msg.encoding!r} (mono8, rgb8 and bgr8 "
                         "are supported)")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h <= 0 or w <= 0 or step < w * channels or data.size < h * step:
        raise ValueError(f"an Image of {w}x{h} (step {step}) with {data.size} bytes of data")
    rows = data[:h * step].reshape(h, step)[:, :w * channels]
    image = rows.reshape(h, w) if channels == 1 else rows.reshape(h, w, 3)
    if msg.encoding == "rgb8":
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    return np.ascontiguousarray(image), stamp_ns


class Ros2Camera:
    """Frames from a ROS 2 image topic (module docstring)."""

    def __init__(self, settings: Ros2CameraSettings, context: Any) -> None:
        self._settings = settings
        self._session: zenoh.Session | None = None
        self._subscriber: Any = None
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._seq = 0
        self._shape: tuple[int, ...] = ()
        self._complained: set[str] = set()
        self._counts = {"frames": 0, "skipped": 0, "timeouts": 0, "bad_messages": 0}
        self._stamps: collections.deque[int] = collections.deque(maxlen=30)  # of messages

    def open(self) -> None:
        s = self._settings
        try:
            self._session = open_session(s.connect)
            self._subscriber = self._session.declare_subscriber(
                subscription_key(s.domain_id, s.topic), self._received)
        except Exception as e:  # noqa: BLE001 - zenoh's errors carry no common type
            self.close()
            raise DeviceInitError(f"ros2 camera: cannot open a zenoh session to "
                                  f"{list(s.connect)}: {e}") from e
        self._frame = None

    def close(self) -> None:
        if self._subscriber is not None:
            with contextlib.suppress(Exception):  # the session already closed
                self._subscriber.undeclare()
            self._subscriber = None
        if self._session is not None:
            self._session.close()
            self._session = None

    @property
    def info(self) -> CameraInfo:
        s = self._settings
        h, w = self._shape[:2] if self._shape else (0, 0)
        return CameraInfo("ros2", f"{s.topic} (domain {s.domain_id})", w, h, self.rate_hz(),
                          {"connect": ",".join(s.connect)})

    def rate_hz(self) -> float:
        """The topic's rate from its last messages' stamps; 0 before two came."""
        with self._cond:
            stamps = list(self._stamps)
        if len(stamps) < 2 or stamps[-1] <= stamps[0]:
            return 0.0
        return (len(stamps) - 1) * 1e9 / (stamps[-1] - stamps[0])

    def _received(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = key.split("/")
        msg_type = _BY_MANGLED.get(parts[-2]) if len(parts) >= 2 else None
        if msg_type is None:
            self._complain(parts[-2] if len(parts) >= 2 else key,
                           f"{key}: not an Image or a CompressedImage")
            return
        try:
            image, stamp_ns = decode_image(msg_type, sample.payload.to_bytes())
        except ValueError as e:
            self._complain(str(e)[:60], f"{self._settings.topic}: {e}; dropped")
            return
        stamp_ns = monotonic_of(stamp_ns)  # ROS time onto the daemon's clock
        with self._cond:
            self._seq += 1
            if self._frame is not None:
                self._counts["skipped"] += 1
            self._frame = Frame(image, stamp_ns, self._seq)
            self._stamps.append(stamp_ns)
            self._shape = image.shape
            self._counts["frames"] += 1
            self._cond.notify_all()

    def _complain(self, kind: str, message: str) -> None:
        self._counts["bad_messages"] += 1
        if kind not in self._complained:
            self._complained.add(kind)
            log.warning("%s (reported once; counted in bad_messages)", message)

    def read(self, timeout: float) -> Frame:
        with self._cond:
            if not self._cond.wait_for(lambda: self._frame is not None, timeout):
                self._counts["timeouts"] += 1
                raise DeviceTimeoutError(f"no image on ROS 2 topic {self._settings.topic} "
                                         f"within {timeout:.2f} s")
            frame, self._frame = self._frame, None
        assert frame is not None
        return frame

    def stats(self) -> Mapping[str, float]:
        return dict(self._counts)
