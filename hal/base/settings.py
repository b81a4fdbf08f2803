"""Settings of the base section and of each base backend (STYLE.md rule 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from kernel.settings import ROS2_TOPIC, setting


@dataclass(frozen=True)
class SimBaseSettings:
    odometry_rate_hz: float = setting(50.0, gt=0.0, le=1000.0)
    max_speed_m_s: float = setting(0.6, gt=0.0, le=3.0)
    max_accel_m_s2: float = setting(1.0, gt=0.0, le=10.0)
    max_yaw_rate_rad_s: float = setting(1.5, gt=0.0, le=10.0)
    max_yaw_accel_rad_s2: float = setting(3.0, gt=0.0, le=50.0)
    # Drift (docs/design.md §10): odometry = truth distorted by these.
    scale_error: float = setting(0.005, ge=-0.2, le=0.2, doc="fractional error of distance")
    heading_bias_rad_per_m: float = setting(
        0.016, ge=-0.5, le=0.5,
        doc="heading error gained per metre travelled (0.016: about 0.5 m off after the "
            "thesis's 25 m, 4-lap loop)"
    )
    random_walk_m_per_sqrt_m: float = setting(
        0.01, ge=0.0, le=1.0, doc="position noise per sqrt(metre) travelled"
    )
    random_walk_rad_per_sqrt_m: float = setting(
        0.003, ge=0.0, le=1.0, doc="heading noise per sqrt(metre) travelled"
    )
    can_move: bool = setting(True, doc="whether motion commands are accepted")
    kinematics: Literal["holonomic", "differential"] = setting(
        "holonomic", doc="holonomic: moves in any direction; differential: along the "
        "heading or turning in place only (sideways motion is refused)")


@dataclass(frozen=True)
class ReplayBaseSettings:
    file: str = setting("", doc="MCAP recording; empty: the camera's replay file")
    speed: float = setting(1.0, ge=0.0, le=1000.0)


@dataclass(frozen=True)
class Xr4000SerialSettings:
    port: str = setting("/dev/ttyUSB0", doc="serial device of the XR4000 bridge")
    baud_rate: int = setting(115200, ge=1200, le=4_000_000)
    command_timeout_s: float = setting(0.5, gt=0.0, le=10.0, doc="wait for ACK/NAK")
    command_retries: int = setting(2, ge=0, le=10, doc="a command unanswered in time is sent "
                                   "again with its id this often (the controller answers a "
                                   "repeated id without executing it twice)")
    silence_timeout_s: float = setting(0.5, gt=0.0, le=10.0, doc="no odometry this long = fault")


@dataclass(frozen=True)
class Xr4000CanSettings:
    interface: str = setting("socketcan", doc="python-can interface: socketcan, slcan, virtual")
    channel: str = setting("can0", doc="python-can channel (slcan: the serial port)")
    bitrate: int = setting(500_000, ge=10_000, le=1_000_000)
    odometry_position_id: int = setting(0x181, ge=0, le=0x7FF)
    odometry_heading_id: int = setting(0x281, ge=0, le=0x7FF)
    answer_id: int = setting(0x182, ge=0, le=0x7FF, doc="the controller's command answers")
    move_id: int = setting(0x201, ge=0, le=0x7FF)
    velocity_id: int = setting(0x202, ge=0, le=0x7FF)
    stop_id: int = setting(0x200, ge=0, le=0x7FF)
    command_timeout_s: float = setting(0.5, gt=0.0, le=10.0)
    command_retries: int = setting(2, ge=0, le=10, doc="stop and velocity commands unanswered "
                                   "in time are sent again this often; a move is not (CAN "
                                   "frames carry no id to tell a repeat): it fails, the base "
                                   "stopped")
    silence_timeout_s: float = setting(0.5, gt=0.0, le=10.0)

    def __post_init__(self) -> None:
        if self.interface == "udp_multicast":
            raise ValueError("base.xr4000_can.interface 'udp_multicast' is not allowed: its "
                             "traffic leaves the machine")


@dataclass(frozen=True)
class Ros2BaseSettings:
    """A ROS 2 robot's base over rmw_zenoh (hal/base/ros2.py)."""

    odom_topic: str = setting("/odom", doc="nav_msgs/Odometry from the base driver")
    cmd_vel_topic: str = setting("/cmd_vel", doc="geometry_msgs/Twist to the base driver")
    domain_id: int = setting(0, ge=0, le=232, doc="ROS_DOMAIN_ID")
    connect: list[str] = setting(["tcp/127.0.0.1:7447"], doc="zenoh endpoints to connect to "
                                 "(the ROS system's zenoh router: rmw_zenoh's default)")
    kinematics: Literal["holonomic", "differential"] = setting(
        "differential", doc="differential: along the heading or turning in place only")
    can_move: bool = setting(True, doc="whether motion commands are sent")
    max_speed_m_s: float = setting(0.3, gt=0.0, le=3.0, doc="moves are driven at most this fast")
    max_yaw_rate_rad_s: float = setting(0.8, gt=0.0, le=10.0, doc="and turn at most this fast")
    slow_down_m: float = setting(0.15, gt=0.0, le=5.0, doc="slowing down over the last metres")
    slow_down_rad: float = setting(0.3, gt=0.0, le=3.2, doc="...and the last radians of a move")
    position_tolerance_m: float = setting(0.01, gt=0.0, le=1.0, doc="a move is done this near")
    yaw_tolerance_rad: float = setting(0.02, gt=0.0, le=1.0, doc="...and turned this near")
    control_rate_hz: float = setting(20.0, gt=0.0, le=200.0, doc="velocity commands per second "
                                     "while a move is under way")
    odometry_timeout_s: float = setting(0.5, gt=0.0, le=10.0, doc="watchdog: no odometry this "
                                        "long while moving stops the robot")
    command_timeout_s: float = setting(0.5, gt=0.0, le=10.0, doc="watchdog: a velocity not "
                                       "repeated within this stops the robot")
    at_rest_s: float = setting(0.2, gt=0.0, le=5.0, doc="after a stop or a move, the base "
                               "counts as moving until its odometry has stayed within 2 mm "
                               "and 0.005 rad for this long (the robot decelerates after the "
                               "last command; Turn Back and Look takes its reference at rest)")

    def __post_init__(self) -> None:
        for name in ("odom_topic", "cmd_vel_topic"):
            if not ROS2_TOPIC.match(getattr(self, name)):
                raise ValueError(f"base.ros2.{name} {getattr(self, name)!r} is not a ROS 2 "
                                 "topic name (letters, digits, '_' between slashes)")
        if not self.connect:
            raise ValueError("base.ros2.connect is empty: give the ROS system's zenoh "
                             "router, e.g. tcp/127.0.0.1:7447")


@dataclass(frozen=True)
class BaseSettings:
    backend: str = setting("sim", doc="sim | replay | xr4000-serial | xr4000-can | ros2")
    read_timeout_s: float = setting(0.5, gt=0.0, le=60.0)
    sim: SimBaseSettings = setting(default_factory=SimBaseSettings)
    replay: ReplayBaseSettings = setting(default_factory=ReplayBaseSettings)
    xr4000_serial: Xr4000SerialSettings = setting(default_factory=Xr4000SerialSettings)
    xr4000_can: Xr4000CanSettings = setting(default_factory=Xr4000CanSettings)
    ros2: Ros2BaseSettings = setting(default_factory=Ros2BaseSettings)
