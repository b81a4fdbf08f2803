"""The v4l2 camera backend as far as a machine without a camera allows: a missing device
names its path; the capture logic runs on a real video file and on a stalling source."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.config import load
from hal import registry
from hal.camera.settings import V4L2Settings
from hal.camera.v4l2 import V4L2Camera
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.errors import (
    BackendUnavailableError,
    DeviceInitError,
    DeviceIOError,
    DeviceTimeoutError,
)


def test_missing_device_names_the_path() -> None:
    cam = V4L2Camera(V4L2Settings(device="/dev/video-placecell-missing"), None)
    with pytest.raises(DeviceInitError, match="/dev/video-placecell-missing does not exist"):
        cam.open()


def test_libcamera_without_picamera2_says_what_to_install() -> None:
    try:
        import picamera2  # noqa: F401
    except ImportError:
        with pytest.raises(BackendUnavailableError, match="pip install picamera2"):
            registry.load_backend("camera", "libcamera")
    else:  # on a Raspberry Pi the backend loads
        assert registry.load_backend("camera", "libcamera")


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[np.ndarray]]:
    """A 20-frame MJPG video of rendered mirror images: what a camera would deliver."""
    path = tmp_path_factory.mktemp("v4l2") / "mirror.avi"
    c = load(None)
    renderer = Renderer(load_world("generate:office:1"), c.projection, c.panorama, (640, 480))
    frames = [renderer.donut((3.0 + 0.05 * i, 10.0, 0.0)) for i in range(20)]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 15.0, (640, 480))
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()
    return path, frames


def test_capture_logic_on_a_video_file(video: tuple[Path, list[np.ndarray]]) -> None:
    path, originals = video
    cam = V4L2Camera(V4L2Settings(), None, open_capture=lambda s: cv2.VideoCapture(str(path)))
    cam.open()
    got = []
    try:
        while True:
            got.append(cam.read(1.0))
    except DeviceIOError as e:  # the file ends like an unplugged camera
        assert "stopped delivering" in str(e)
    finally:
        cam.close()
    assert got, "no frames"
    # One-slot mailbox: the newest frame wins, so frames may be skipped, never reordered.
    seqs = [f.seq for f in got]
    assert seqs == sorted(seqs) and seqs[-1] == len(originals)
    stamps = [f.stamp_ns for f in got]
    assert all(b > a for a, b in zip(stamps, stamps[1:], strict=False))
    last = got[-1].image
    assert last.shape == (480, 640, 3)
    assert np.abs(last.astype(int) - originals[-1].astype(int)).mean() < 6  # JPEG-close


class _StallingCapture:
    """Delivers a few frames, then grab() blocks like a stalled USB camera."""

    def __init__(self) -> None:
        self.frames = 3
        self.release_event = threading.Event()

    def isOpened(self) -> bool:  # noqa: N802
        return True

    def grab(self) -> bool:
        if self.frames > 0:
            self.frames -= 1
            time.sleep(0.01)
            return True
        self.release_event.wait(5.0)
        return False

    def retrieve(self) -> tuple[bool, np.ndarray]:
        return True, np.zeros((4, 4, 3), np.uint8)

    def get(self, prop: int) -> float:
        return 0.0

    def release(self) -> None:
        self.release_event.set()


def test_a_stalled_device_is_noticed() -> None:
    fake = _StallingCapture()
    cam = V4L2Camera(V4L2Settings(), None, open_capture=lambda s: fake)
    cam.open()
    cam.read(1.0)
    with pytest.raises(DeviceTimeoutError, match="stalled"):
        for _ in range(5):
            cam.read(0.3)
    cam.close()
    assert cam.stats()["timeouts"] == 1
