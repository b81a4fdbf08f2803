"""The `ros2` camera backend (hal/camera/ros2.py, issue 33): sensor_msgs Image and
CompressedImage as rmw_zenoh carries them, decoded to the daemon's frames; over a real
zenoh session on loopback, as a ROS 2 camera driver would publish them."""

from __future__ import annotations

import time
from typing import Any

import cv2
import numpy as np
import pytest
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore

from daemon.config import load
from hal.camera.ros2 import COMPRESSED, IMAGE, Ros2Camera, decode_image
from hal.camera.settings import CameraSettings, Ros2CameraSettings
from hal.registry import HalContext, create_camera
from kernel.errors import ConfigError, DeviceTimeoutError
from tests.daemon_harness import free_port, listening_session

TS = get_typestore(Stores.ROS2_JAZZY)
READ_TIMEOUT_S = CameraSettings().read_timeout_s


def _header(stamp_ns: int) -> Any:
    t = TS.types
    return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000), frame_id="camera")


def image_cdr(image: np.ndarray, encoding: str, stamp_ns: int, pad: int = 0) -> bytes:
    h, w = image.shape[:2]
    channels = 1 if image.ndim == 2 else 3
    rows = image.reshape(h, w * channels)
    data = np.concatenate([rows, np.zeros((h, pad), np.uint8)], axis=1) if pad else rows
    msg = TS.types[IMAGE](header=_header(stamp_ns), height=h, width=w, encoding=encoding,
                          is_bigendian=0, step=w * channels + pad,
                          data=np.ascontiguousarray(data).ravel())
    return bytes(TS.serialize_cdr(msg, IMAGE))


def compressed_cdr(image: np.ndarray, fmt: str, stamp_ns: int) -> bytes:
    ok, data = cv2.imencode("." + fmt, image)
    assert ok
    msg = TS.types[COMPRESSED](header=_header(stamp_ns), format=fmt,
                               data=np.asarray(data, np.uint8).ravel())
    return bytes(TS.serialize_cdr(msg, COMPRESSED))


def _picture(seed: int, channels: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (48, 64, 3) if channels == 3 else (48, 64)
    return rng.integers(0, 256, shape, dtype=np.uint8)


def test_raw_images_of_each_encoding_become_bgr_or_grey_frames() -> None:
    bgr = _picture(1)
    image, stamp = decode_image(IMAGE, image_cdr(bgr, "bgr8", 1_764_000_000_123_456_789))
    assert stamp == 1_764_000_000_123_456_789 and np.array_equal(image, bgr)
    rgb = bgr[:, :, ::-1].copy()
    image, _ = decode_image(IMAGE, image_cdr(rgb, "rgb8", 5, pad=8))  # rows padded (step)
    assert np.array_equal(image, bgr)
    grey = _picture(2, channels=1)
    image, _ = decode_image(IMAGE, image_cdr(grey, "mono8", 5))
    assert image.shape == (48, 64) and np.array_equal(image, grey)


def test_compressed_images_decode_and_bad_ones_are_named() -> None:
    bgr = _picture(3)
    image, _ = decode_image(COMPRESSED, compressed_cdr(bgr, "png", 7))
    assert np.array_equal(image, bgr)  # png is lossless
    image, _ = decode_image(COMPRESSED, compressed_cdr(bgr, "jpg", 7))
    assert image.shape == bgr.shape
    with pytest.raises(ValueError, match="encoding '16UC1'"):
        decode_image(IMAGE, image_cdr(_picture(4, 1).astype(np.uint8), "16UC1", 1))
    with pytest.raises(ValueError, match="not a sensor_msgs/msg/Image"):
        decode_image(IMAGE, b"\x00\x01\x00\x00garbage")
    broken = TS.types[COMPRESSED](header=_header(1), format="jpeg",
                                  data=np.frombuffer(b"not a jpeg", np.uint8))
    with pytest.raises(ValueError, match="cannot decode"):
        decode_image(COMPRESSED, bytes(TS.serialize_cdr(broken, COMPRESSED)))
    short = TS.types[IMAGE](header=_header(1), height=48, width=64, encoding="bgr8",
                            is_bigendian=0, step=192, data=np.zeros(100, np.uint8))
    with pytest.raises(ValueError, match="100 bytes"):
        decode_image(IMAGE, bytes(TS.serialize_cdr(short, IMAGE)))


def test_a_topic_that_is_not_a_ros2_name_is_refused(tmp_path: Any) -> None:
    path = tmp_path / "bad.toml"
    path.write_text('[camera]\nbackend = "ros2"\n[camera.ros2]\ntopic = "camera image"\n')
    with pytest.raises(ConfigError, match="camera.ros2.topic"):
        load(path)


def _key(topic: str, msg_type: str) -> str:
    package, kind, name = msg_type.split("/")
    return f"0/{topic.strip('/')}/{package}::{kind}::dds_::{name}_/{TS.hash_rihs01(msg_type)}"


def _first_frame(camera: Ros2Camera, publish: Any) -> Any:
    """Publish until the camera's subscription has reached the publisher (zenoh drops
    samples published before it has), then the frame."""
    deadline = time.monotonic() + 60 * READ_TIMEOUT_S
    while time.monotonic() < deadline:
        publish()
        try:
            return camera.read(READ_TIMEOUT_S)
        except DeviceTimeoutError:
            continue
    raise AssertionError("no frame from the ROS 2 topic")


def test_frames_arrive_over_rmw_zenoh_keys_stamped_on_the_monotonic_clock() -> None:
    port = free_port()
    driver = listening_session(port)  # the camera driver's side (a ROS 2 node)
    settings = Ros2CameraSettings(topic="/robot/camera/image_raw",
                                  connect=[f"tcp/127.0.0.1:{port}"])
    camera = create_camera(CameraSettings(backend="ros2", ros2=settings),
                           HalContext(load(None)))
    assert isinstance(camera, Ros2Camera)
    camera.open()
    try:
        raw = driver.declare_publisher(_key(settings.topic, IMAGE))
        packed = driver.declare_publisher(_key(settings.topic, COMPRESSED))
        bgr = _picture(5)
        attachment = zenoh.ext.z_serialize((zenoh.ext.Int64(1), zenoh.ext.Int64(0),
                                            bytes(16))).to_bytes()
        age_ns = 30_000_000  # captured 30 ms before it is sent

        def send() -> None:
            raw.put(image_cdr(bgr, "bgr8", time.time_ns() - age_ns), attachment=attachment)

        sent_mono = time.monotonic_ns()
        frame = _first_frame(camera, send)
        assert np.array_equal(frame.image, bgr)
        # ROS time carried onto the monotonic clock (not left on the UNIX clock).
        assert abs(frame.stamp_ns - (time.monotonic_ns() - age_ns)) \
            < time.monotonic_ns() - sent_mono + 50_000_000
        # A message that is no image is counted and dropped; the camera goes on (the
        # next frame, compressed, may come after late ones of the first kind).
        raw.put(b"garbage", attachment=attachment)
        other = _picture(6)

        def send_other() -> None:
            packed.put(compressed_cdr(other, "png", time.time_ns()), attachment=attachment)

        send_other()
        for _ in range(100):
            try:
                frame = camera.read(READ_TIMEOUT_S)
            except DeviceTimeoutError:  # a loaded machine: sent again, as _first_frame does
                send_other()
                continue
            if not np.array_equal(frame.image, bgr):
                break
        assert np.array_equal(frame.image, other)
        assert camera.stats()["bad_messages"] == 1
        assert camera.info.width == 64 and camera.info.height == 48
    finally:
        camera.close()
        driver.close()
    with pytest.raises(DeviceTimeoutError, match="no image on ROS 2 topic"):
        camera.read(0.01)


def test_a_stamp_conversion_preempted_between_clock_reads_is_not_skewed(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """ROS stamps go onto the monotonic clock by the offset of the two clocks; a thread
    pre-empted between reading them (50 ms here) would shift a frame's stamp by that
    much against its odometry: such a reading is passed over."""
    from hal import ros2_wire
    offset = ros2_wire._ClockOffset()
    monotonic, unix = [1_000_000_000], 5_000_000_000_000

    def mono() -> int:
        monotonic[0] += 1000
        return monotonic[0]

    monkeypatch.setattr(ros2_wire.time, "monotonic_ns", mono)
    monkeypatch.setattr(ros2_wire.time, "time_ns", lambda: unix + monotonic[0])
    clean = offset.now()
    assert abs(clean - unix) <= 1000

    def preempted() -> int:  # every read: 50 ms passed since the one before
        monotonic[0] += 50_000_000
        return monotonic[0]

    monkeypatch.setattr(ros2_wire.time, "monotonic_ns", preempted)
    assert offset.now() == clean
