"""Settings of the camera section and of each camera backend (STYLE.md rule 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from kernel.sensor_settings import (
    CameraModelName,
    DualFisheyeSettings,
    EquirectangularSettings,
    FisheyeSettings,
    OcamcalibSettings,
)
from kernel.settings import ROS2_TOPIC, setting


@dataclass(frozen=True)
class SimCameraSettings:
    rate_hz: float = setting(10.0, gt=0.0, le=120.0, doc="frame rate")
    image_width: int = setting(640, ge=64, le=4096, doc="raw image width")
    image_height: int = setting(480, ge=64, le=4096, doc="raw image height")
    noise_sigma: float = setting(2.0, ge=0.0, le=64.0, doc="Gaussian pixel noise, grey levels")
    blur_sigma_px: float = setting(0.0, ge=0.0, le=10.0, doc="Gaussian blur of the raw image")
    gain: float = setting(1.0, gt=0.0, le=4.0, doc="illumination gain")


@dataclass(frozen=True)
class V4L2Settings:
    device: str = setting("/dev/video0", doc="V4L2 device path")
    pixel_format: str = setting("MJPG", doc="FOURCC, e.g. MJPG or YUYV")
    width: int = setting(1280, ge=16, le=8192)
    height: int = setting(960, ge=16, le=8192)
    rate_hz: float = setting(15.0, gt=0.0, le=240.0)


@dataclass(frozen=True)
class LibcameraSettings:
    camera_index: int = setting(0, ge=0)
    width: int = setting(1280, ge=16, le=8192)
    height: int = setting(960, ge=16, le=8192)
    rate_hz: float = setting(15.0, gt=0.0, le=240.0)


@dataclass(frozen=True)
class ReplayCameraSettings:
    file: str = setting("", doc="MCAP recording to play back")
    speed: float = setting(1.0, ge=0.0, le=1000.0, doc="1 = recorded rate; 0 = as fast as read")
    loop: bool = setting(False, doc="start again at the end instead of reporting end of file")


@dataclass(frozen=True)
class Ros2CameraSettings:
    """Images from a ROS 2 topic over rmw_zenoh (hal/camera/ros2.py)."""

    topic: str = setting("/camera/image_raw", doc="sensor_msgs/Image or CompressedImage topic")
    domain_id: int = setting(0, ge=0, le=232, doc="ROS_DOMAIN_ID")
    connect: list[str] = setting(["tcp/127.0.0.1:7447"], doc="zenoh endpoints to connect to "
                                 "(the ROS system's zenoh router: rmw_zenoh's default)")

    def __post_init__(self) -> None:
        if not ROS2_TOPIC.match(self.topic):
            raise ValueError(f"camera.ros2.topic {self.topic!r} is not a ROS 2 topic name "
                             "(e.g. /camera/image_raw: letters, digits, '_' between slashes)")
        if not self.connect:
            raise ValueError("camera.ros2.connect is empty: give the ROS system's zenoh "
                             "router, e.g. tcp/127.0.0.1:7447")


@dataclass(frozen=True)
class CameraSettings:
    backend: str = setting("sim", doc="sim | replay | v4l2 | libcamera | ros2")
    read_timeout_s: float = setting(0.5, gt=0.0, le=60.0, doc="a read longer than this is a stall")
    sim: SimCameraSettings = setting(default_factory=SimCameraSettings)
    v4l2: V4L2Settings = setting(default_factory=V4L2Settings)
    libcamera: LibcameraSettings = setting(default_factory=LibcameraSettings)
    replay: ReplayCameraSettings = setting(default_factory=ReplayCameraSettings)
    ros2: Ros2CameraSettings = setting(default_factory=Ros2CameraSettings)
    encoding: Literal["bgr", "grey"] = setting("bgr", doc="colour layout handed to the daemon")
    # How the camera images the world (kernel/camera_models.py, design §2): the mirror of
    # [mirror], or one of the sections below.
    model: CameraModelName = setting(
        "mirror", doc="mirror | ocamcalib | fisheye | equirectangular | dual-fisheye")
    # Where the camera sits on the robot (kernel/mount.py): its viewpoint's position in the
    # robot's frame (x forward, y left, from the rotation centre) and its yaw.
    mount_x_m: float = setting(0.0, ge=-2.0, le=2.0, doc="camera ahead of the rotation "
                               "centre (m)")
    mount_y_m: float = setting(0.0, ge=-2.0, le=2.0, doc="camera left of the rotation "
                               "centre (m)")
    mount_yaw_rad: float = setting(0.0, ge=-3.141592653589793, le=3.141592653589793,
                                   doc="camera's forward axis turned from the robot's")
    ocamcalib: OcamcalibSettings = setting(default_factory=OcamcalibSettings)
    fisheye: FisheyeSettings = setting(default_factory=FisheyeSettings)
    equirectangular: EquirectangularSettings = setting(default_factory=EquirectangularSettings)
    dual_fisheye: DualFisheyeSettings = setting(default_factory=DualFisheyeSettings)
