"""Backend registry: config name -> "module:Class", imported only when chosen.

A backend class is constructed as ``Cls(settings, context)`` where ``settings`` is its own
section of the configuration and ``context`` the :class:`HalContext` shared by all devices.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from typing import Any, TypeVar

from kernel.errors import BackendUnavailableError, UnknownBackendError

CAMERA_BACKENDS: dict[str, str] = {
    "sim": "hal.camera.sim:SimCamera",
    "replay": "hal.camera.replay:ReplayCamera",
    "v4l2": "hal.camera.v4l2:V4L2Camera",
    "libcamera": "hal.camera.libcamera:LibcameraCamera",
    "ros2": "hal.camera.ros2:Ros2Camera",
}

BASE_BACKENDS: dict[str, str] = {
    "sim": "hal.base.sim:SimBase",
    "replay": "hal.base.replay:ReplayBase",
    "xr4000-serial": "hal.base.xr4000_serial:Xr4000SerialBase",
    "xr4000-can": "hal.base.xr4000_can:Xr4000CanBase",
    "ros2": "hal.base.ros2:Ros2Base",
}

# Which pip package provides the import a backend needs, for the error message.
_PIP_NAMES = {"cv2": "opencv-python-headless", "can": "python-can", "serial": "pyserial",
              "mcap": "mcap", "picamera2": "picamera2"}

T = TypeVar("T")


class HalContext:
    """State shared by the devices of one daemon, e.g. the one simulated robot that both
    the `sim` camera and the `sim` base look at."""

    def __init__(self, config: Any) -> None:
        self.config = config
        self._shared: dict[str, Any] = {}
        # The camera and base components open their devices on their own threads at once:
        # without the lock both could build "the one" simulated robot.
        self._lock = threading.Lock()

    def shared(self, key: str, factory: Callable[[], T]) -> T:
        with self._lock:
            if key not in self._shared:
                self._shared[key] = factory()
            return self._shared[key]  # type: ignore[no-any-return]


def load_backend(kind: str, name: str, table: dict[str, str] | None = None) -> type:
    """Import and return the class registered as ``name`` for device ``kind``."""
    if table is None:
        table = {"camera": CAMERA_BACKENDS, "base": BASE_BACKENDS}[kind]
    target = table.get(name)
    if target is None:
        known = ", ".join(sorted(table))
        raise UnknownBackendError(f"unknown {kind} backend {name!r} (known: {known})")
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:
        missing = e.name or "?"
        if missing.startswith(("hal.", "daemon.")):
            raise  # our own bug, not a missing optional dependency
        package = _PIP_NAMES.get(missing.split(".")[0], missing)
        raise BackendUnavailableError(
            f"{kind} backend {name!r} needs the Python package {package!r}, which is not "
            f"installed: pip install {package}"
        ) from e
    cls: type = getattr(module, class_name)
    return cls


def _section_name(name: str) -> str:
    return name.replace("-", "_")


def create_camera(camera_settings: Any, context: HalContext) -> Any:
    """The camera backend named by ``camera_settings.backend``, not yet opened."""
    cls = load_backend("camera", camera_settings.backend)
    return cls(getattr(camera_settings, _section_name(camera_settings.backend)), context)


def create_base(base_settings: Any, context: HalContext) -> Any:
    """The base backend named by ``base_settings.backend``, not yet opened."""
    cls = load_backend("base", base_settings.backend)
    return cls(getattr(base_settings, _section_name(base_settings.backend)), context)
