"""MCAP recordings: camera frames, odometry, base status, ground truth, beliefs (design §10).

Every channel carries JSON messages with a JSON schema, so standard MCAP tools (the
``mcap`` CLI, Foxglove) read them. Frames follow the ``foxglove.CompressedImage`` layout
(base64 ``data``, ``format`` png or jpeg) plus our ``stamp_ns`` and ``seq``. Log times are
the sensor stamps (the monotonic clock camera and odometry share).
"""

from __future__ import annotations

import base64
import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import cv2
import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import Writer

from hal.base.base import BaseStatus, Odometry
from hal.camera.base import Frame
from kernel.errors import DeviceInitError, DeviceIOError
from kernel.message_schemas import SCHEMAS

TOPIC_FRAMES = "/camera/image/compressed"
TOPIC_ODOMETRY = "/base/odometry"
TOPIC_STATUS = "/base/status"
TOPIC_GROUND_TRUTH = "/sim/ground_truth"

_TOPIC_SCHEMA = {TOPIC_FRAMES: "foxglove.CompressedImage", TOPIC_ODOMETRY: "placecell.Odometry",
                 TOPIC_STATUS: "placecell.BaseStatus",
                 TOPIC_GROUND_TRUTH: "placecell.Pose2D"}


class Recorder:
    """Writes one MCAP file; safe to call from several threads."""

    def __init__(self, path: str | Path, metadata: dict[str, str], *,
                 image_format: str = "png", jpeg_quality: int = 90) -> None:
        if image_format not in ("png", "jpeg"):
            raise ValueError(f"image_format must be png or jpeg, got {image_format!r}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file)
        self._writer.start(profile="", library="placecell")
        self._writer.add_metadata("placecell", {k: str(v) for k, v in metadata.items()})
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._topic_schema = dict(_TOPIC_SCHEMA)
        self._format = image_format
        self._jpeg_quality = jpeg_quality
        self._closed = False

    def _channel(self, topic: str) -> int:
        if topic not in self._channels:
            schema = self._topic_schema.get(topic, "placecell.Json")
            if schema not in self._schemas:
                self._schemas[schema] = self._writer.register_schema(
                    schema, "jsonschema", json.dumps(SCHEMAS[schema]).encode())
            self._channels[topic] = self._writer.register_channel(
                topic, "json", self._schemas[schema])
        return self._channels[topic]

    def _write(self, topic: str, stamp_ns: int, body: dict[str, Any]) -> None:
        data = json.dumps(body, separators=(",", ":")).encode()
        with self._lock:
            if self._closed:
                return
            channel = self._channel(topic)
            seq = self._sequence.get(topic, 0) + 1
            self._sequence[topic] = seq
            self._writer.add_message(channel, log_time=stamp_ns, data=data,
                                     publish_time=stamp_ns, sequence=seq)

    def write_frame(self, frame: Frame) -> None:
        if self._format == "png":
            ok, buf = cv2.imencode(".png", frame.image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        else:
            ok, buf = cv2.imencode(".jpg", frame.image,
                                   [cv2.IMWRITE_JPEG_QUALITY, self._jpeg_quality])
        if not ok:
            raise DeviceIOError(f"cannot encode frame {frame.seq} as {self._format}")
        self._write(TOPIC_FRAMES, frame.stamp_ns, {
            "timestamp": {"sec": frame.stamp_ns // 1_000_000_000,
                          "nsec": frame.stamp_ns % 1_000_000_000},
            "frame_id": "mirror_camera", "format": self._format,
            "data": base64.b64encode(buf.tobytes()).decode(), "stamp_ns": frame.stamp_ns,
            "seq": frame.seq})

    def write_odometry(self, odo: Odometry) -> None:
        self._write(TOPIC_ODOMETRY, odo.stamp_ns, {"stamp_ns": odo.stamp_ns, "seq": odo.seq,
                                                   "x": odo.x, "y": odo.y, "yaw": odo.yaw})

    def write_status(self, stamp_ns: int, status: BaseStatus) -> None:
        self._write(TOPIC_STATUS, stamp_ns, {"stamp_ns": stamp_ns, "flags": status.to_flags()})

    def write_ground_truth(self, stamp_ns: int, pose: tuple[float, float, float]) -> None:
        self._write(TOPIC_GROUND_TRUTH, stamp_ns, {"stamp_ns": stamp_ns, "x": pose[0],
                                                   "y": pose[1], "yaw": pose[2]})

    def write_message(self, topic: str, schema: str, stamp_ns: int,
                      body: dict[str, Any]) -> None:
        """``body`` on ``topic`` under one of :data:`SCHEMAS` (the live view's topics:
        a recording opens in the same Foxglove layout)."""
        if schema not in SCHEMAS:
            raise ValueError(f"unknown schema {schema!r} for {topic}")
        with self._lock:
            self._topic_schema.setdefault(topic, schema)
        self._write(topic, stamp_ns, body)

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.finish()
            self._file.close()


# ---------------------------------------------------------------------- reading
@dataclass(frozen=True)
class Message:
    topic: str
    log_time_ns: int
    body: dict[str, Any]


class RecordingReader:
    """Streams the messages of an MCAP recording in log-time order."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise DeviceInitError(f"recording {self.path} does not exist")
        with open(self.path, "rb") as f:
            if f.read(8) != b"\x89MCAP0\r\n":
                raise DeviceInitError(f"{self.path} is not an MCAP file (bad magic)")

    def metadata(self) -> dict[str, str]:
        with open(self.path, "rb") as f:
            try:
                for record in make_reader(f).iter_metadata():
                    if record.name == "placecell":
                        return dict(record.metadata)
            except McapError as e:
                raise DeviceIOError(f"{self.path}: corrupt MCAP metadata: {e}") from e
        return {}

    def messages(self, topics: list[str] | None = None) -> Iterator[Message]:
        with open(self.path, "rb") as f:
            try:
                for _, channel, msg in make_reader(f).iter_messages(topics=topics):
                    try:
                        body = json.loads(msg.data)
                    except ValueError as e:
                        raise DeviceIOError(f"{self.path}: message on {channel.topic} at "
                                            f"{msg.log_time} is not JSON") from e
                    yield Message(channel.topic, msg.log_time, body)
            except McapError as e:
                raise DeviceIOError(f"{self.path}: corrupt MCAP data: {e}") from e


def decode_frame(body: dict[str, Any]) -> Frame:
    """A recorded frame message back into a Frame (exact for PNG)."""
    try:
        buf = np.frombuffer(base64.b64decode(body["data"]), np.uint8)
        image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        stamp, seq = int(body["stamp_ns"]), int(body["seq"])
    except (KeyError, ValueError, TypeError) as e:
        raise DeviceIOError(f"malformed frame message: {e}") from e
    if image is None:
        raise DeviceIOError(f"frame {seq}: image data cannot be decoded")
    return Frame(image=image, stamp_ns=stamp, seq=seq)


def decode_odometry(body: dict[str, Any]) -> Odometry:
    try:
        return Odometry(float(body["x"]), float(body["y"]), float(body["yaw"]),
                        int(body["stamp_ns"]), int(body["seq"]))
    except (KeyError, ValueError, TypeError) as e:
        raise DeviceIOError(f"malformed odometry message: {e}") from e
