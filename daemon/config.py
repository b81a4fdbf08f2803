"""The daemon's configuration: one TOML file, loaded strictly (docs/design.md §11).

``config/placecell.toml`` is the documented default. Unknown keys, wrong types and
out-of-range values raise :class:`ConfigError` naming ``section.key`` before any device
is opened.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.settings import MappingSettings, OdometryNoiseSettings, TblSettings
from hal.base.settings import BaseSettings
from hal.camera.settings import CameraSettings
from hal.registry import BASE_BACKENDS, CAMERA_BACKENDS
from hal.sim.settings import SimSettings
from kernel.camera_models import Projection, read_ocamcalib
from kernel.errors import ConfigError
from kernel.mount import Mount
from kernel.se2 import SE2
from kernel.sensor_settings import MirrorSettings, PanoramaSettings
from kernel.settings import ROS2_TOPIC, as_dict, build, read_toml, setting

_ROBOT_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_ZID = re.compile(r"^[1-9a-f][0-9a-f]{0,31}$")  # zenoh's: hex, no leading zero
_FRAME_ID = re.compile(r"^[A-Za-z_][A-Za-z0-9_/]{0,63}$")


@dataclass(frozen=True)
class RobotSettings:
    name: str = setting("sim1", doc="robot name, the zenoh key prefix placecell/<name>/")

    def __post_init__(self) -> None:
        if not _ROBOT_NAME.match(self.name):
            raise ValueError(
                f"robot.name {self.name!r} must be 1-64 letters, digits, '-' or '_' "
                "(it is a zenoh key segment)"
            )


@dataclass(frozen=True)
class ZenohSettings:
    mode: Literal["peer", "client"] = setting("peer")
    listen: list[str] = setting(["tcp/127.0.0.1:7448"], doc="endpoints to listen on (7448: "
                                "rmw_zenohd, a ROS 2 system's router, has 7447)")
    connect: list[str] = setting([], doc="endpoints to connect to")
    multicast_scouting: bool = setting(False, doc="off: nothing leaves the machine unasked")
    config_file: str = setting("", doc="a zenoh JSON5 configuration read first (access "
                               "control and certificates: config/zenoh/robot.json5, "
                               "docs/security.md); the keys above override its mode "
                               "and endpoints")
    id: str = setting("", doc="the daemon's zenoh id (1-32 hex digits, no leading 0); "
                      "empty: derived from the robot name, as placecellctl expects "
                      "(docs/security.md)")

    def __post_init__(self) -> None:
        if self.id and not _ZID.match(self.id):
            raise ValueError(f"zenoh.id {self.id!r} is not 1-32 lowercase hex digits "
                             "without a leading zero")


@dataclass(frozen=True)
class FleetSettings:
    enabled: bool = setting(False, doc="share places with the other robots of a fleet through "
                            "its routers' storage (docs/fleet.md; [zenoh] connect to one)")
    key_prefix: str = setting("placecell/fleet", doc="the fleet's key space: each robot puts "
                              "its places under <key_prefix>/<robot name>/")
    fetch_timeout_s: float = setting(10.0, gt=0.0, le=600.0, doc="at start, wait this long "
                                     "for the fleet's storage to answer before the robot "
                                     "acts on its own map")

    def __post_init__(self) -> None:
        chunks = self.key_prefix.split("/")
        if not all(c and not set(c) & set("*$?#") for c in chunks):
            raise ValueError(f"fleet.key_prefix {self.key_prefix!r} must be zenoh key "
                             "chunks (no empty chunk, no *, $, ? or #)")


@dataclass(frozen=True)
class Ros2Settings:
    enabled: bool = setting(False, doc="publish the pose for ROS 2 nodes over rmw_zenoh "
                           "(daemon/service/ros2.py)")
    domain_id: int = setting(0, ge=0, le=232, doc="ROS_DOMAIN_ID of the ROS 2 system")
    topic: str = setting("/placecell/pose", doc="the PoseWithCovarianceStamped topic")
    frame_id: str = setting("map", doc="header.frame_id of the published pose")
    initial_pose_topic: str = setting("/initialpose", doc="a PoseWithCovarianceStamped in the "
                                      "map frame here sets the pose (rviz's 2D Pose Estimate)")
    tf: bool = setting(True, doc="publish map -> odom on /tf while tracking, as nav2's "
                       "AMCL does (tf2_msgs/msg/TFMessage)")
    odom_frame: str = setting("odom", doc="the odometry frame (child of map on /tf)")
    base_frame: str = setting("base_link", doc="the robot's frame (child of odom)")
    odom_tf: bool = setting(False, doc="also publish odom -> base_link from the base's "
                            "odometry: for a base no ROS driver publishes (the XR4000)")
    transform_tolerance_s: float = setting(1.0, ge=0.0, le=10.0, doc="map -> odom is "
                                           "post-dated by this (AMCL's transform_tolerance)")
    tf_period_s: float = setting(0.1, gt=0.0, le=10.0, doc="map -> odom re-sent this often "
                                 "while tracking (between frames)")
    tie_site_map: bool = setting(False, doc="the first pose on initial_pose_topic (or "
                                 "set_initial_pose) while tracking and not yet tied ties the "
                                 "map frame to the site's map (nav2's occupancy map) instead "
                                 "of moving the pose; stored with the map, then every ROS 2 "
                                 "pose in and out is in the site's map")
    transient_local: bool = setting(True, doc="the pose topic keeps its last sample for late "
                                    "subscribers (transient-local durability, depth 1, as "
                                    "AMCL's amcl_pose)")
    particle_cloud_topic: str = setting("/particle_cloud", doc="the filter's particles in "
                                        "the map frame (geometry_msgs/msg/PoseArray, as rviz "
                                        "shows AMCL's), each tracked frame")
    particle_cloud_size: int = setting(200, ge=0, le=100_000, doc="at most this many of the "
                                       "particles, evenly drawn (0: no particle cloud)")

    def __post_init__(self) -> None:
        for name in ("topic", "initial_pose_topic", "particle_cloud_topic"):
            if not ROS2_TOPIC.match(getattr(self, name)):
                raise ValueError(f"ros2.{name} {getattr(self, name)!r} is not a ROS 2 topic "
                                 "name (e.g. /placecell/pose: letters, digits, '_' between "
                                 "slashes)")
        for name in ("frame_id", "odom_frame", "base_frame"):
            if not _FRAME_ID.match(getattr(self, name)):
                raise ValueError(f"ros2.{name} {getattr(self, name)!r} is not a frame name "
                                 "(letters, digits, '_' or '/', at most 64)")


@dataclass(frozen=True)
class FoxgloveSettings:
    enabled: bool = setting(False, doc="serve the live view to Foxglove over WebSocket")
    listen: str = setting("127.0.0.1:8765", doc="host:port of the WebSocket server "
                          "(loopback unless configured otherwise)")

    def host_port(self) -> tuple[str, int]:
        host, _, port = self.listen.rpartition(":")
        return host, int(port)

    def __post_init__(self) -> None:
        host, sep, port = self.listen.rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"foxglove.listen {self.listen!r} must be host:port, "
                             "e.g. 127.0.0.1:8765")


@dataclass(frozen=True)
class MapSettings:
    path: str = setting("var/placecell.db", doc="SQLite map file")
    resume: bool = setting(True, doc="start from the pose saved at the last stop")
    save_pose_period_s: float = setting(2.0, gt=0.0, le=3600.0,
                                        doc="save the tracked pose this often (and on stop)")
    if_unwritable: Literal["refuse", "localisation"] = setting(
        "refuse", doc="a map file that cannot be written, in mapping mode: refuse to start "
        "(exit 2), or start in localisation mode on it read-only and say so in status")


@dataclass(frozen=True)
class ServiceSettings:
    status_period_s: float = setting(1.0, gt=0.0, le=60.0)
    restart_backoff_initial_s: float = setting(0.2, gt=0.0, le=60.0)
    restart_backoff_max_s: float = setting(1.0, gt=0.0, le=600.0)
    fault_summary_s: float = setting(60.0, gt=0.0, le=86400.0,
                                     doc="the same device failure again is reported as a "
                                     "summary (how often, since when) once per this")
    stop_timeout_s: float = setting(1.5, gt=0.0, le=30.0, doc="grace period on SIGTERM")
    stale_after_s: float = setting(1.0, gt=0.0, le=60.0, doc="a device silent this long is faulty")
    min_processed_share: float = setting(
        0.8, ge=0.0, le=1.0, doc="processing is degraded (status) while it keeps less than "
        "this share of the camera's frames")


@dataclass(frozen=True)
class LogSettings:
    level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = setting("INFO")


@dataclass(frozen=True)
class PlacecellConfig:
    robot: RobotSettings = setting(default_factory=RobotSettings)
    camera: CameraSettings = setting(default_factory=CameraSettings)
    base: BaseSettings = setting(default_factory=BaseSettings)
    mirror: MirrorSettings = setting(default_factory=MirrorSettings)
    panorama: PanoramaSettings = setting(default_factory=PanoramaSettings)
    sim: SimSettings = setting(default_factory=SimSettings)
    tbl: TblSettings = setting(default_factory=TblSettings)
    mapping: MappingSettings = setting(default_factory=MappingSettings)
    odometry: OdometryNoiseSettings = setting(default_factory=OdometryNoiseSettings)
    localisation: LocalisationSettings = setting(default_factory=LocalisationSettings)
    zenoh: ZenohSettings = setting(default_factory=ZenohSettings)
    ros2: Ros2Settings = setting(default_factory=Ros2Settings)
    fleet: FleetSettings = setting(default_factory=FleetSettings)
    foxglove: FoxgloveSettings = setting(default_factory=FoxgloveSettings)
    map: MapSettings = setting(default_factory=MapSettings)
    service: ServiceSettings = setting(default_factory=ServiceSettings)
    log: LogSettings = setting(default_factory=LogSettings)

    @property
    def projection(self) -> Projection:
        """How the camera images the world: [mirror], or the [camera.*] section that
        ``camera.model`` names (kernel/camera_models.py)."""
        c = self.camera
        models: dict[str, Projection] = {
            "mirror": self.mirror, "ocamcalib": c.ocamcalib, "fisheye": c.fisheye,
            "equirectangular": c.equirectangular, "dual-fisheye": c.dual_fisheye}
        return models[c.model]

    @property
    def mount(self) -> Mount:
        """Where the camera sits on the robot ([camera] mount_*, kernel/mount.py)."""
        c = self.camera
        return Mount(SE2(c.mount_x_m, c.mount_y_m, c.mount_yaw_rad))

    def __post_init__(self) -> None:
        if self.camera.backend not in CAMERA_BACKENDS:
            raise ValueError(
                f"camera.backend {self.camera.backend!r} is not one of "
                f"{', '.join(sorted(CAMERA_BACKENDS))}"
            )
        if self.base.backend not in BASE_BACKENDS:
            raise ValueError(
                f"base.backend {self.base.backend!r} is not one of "
                f"{', '.join(sorted(BASE_BACKENDS))}"
            )


def from_dict(data: dict[str, Any]) -> PlacecellConfig:
    """Validate a parsed TOML document. An OCamCalib file named in
    ``camera.ocamcalib.file`` is read here: its values replace the section's own."""
    camera = data.get("camera")
    ocam = camera.get("ocamcalib") if isinstance(camera, dict) else None
    if (isinstance(camera, dict) and isinstance(ocam, dict) and isinstance(ocam.get("file"), str)
            and ocam["file"]):
        try:
            values = read_ocamcalib(ocam["file"])
        except ConfigError as e:
            raise ConfigError(f"camera.ocamcalib.file: {e}") from e
        data = {**data, "camera": {**camera, "ocamcalib": {**ocam, **values}}}
    return build(PlacecellConfig, data, "config")


def load(path: str | Path | None) -> PlacecellConfig:
    """Load and validate ``path``; ``None`` gives the built-in defaults."""
    if path is None:
        return from_dict({})
    p = Path(path)
    data = read_toml(p, "configuration")
    try:
        return from_dict(data)
    except ConfigError as e:
        raise ConfigError(f"{p}: {e}") from e


def to_toml(config: PlacecellConfig) -> str:
    """The effective configuration as TOML text (``placecelld --print-config``)."""
    lines: list[str] = []

    def emit(table: dict[str, Any], prefix: str) -> None:
        scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
        tables = {k: v for k, v in table.items() if isinstance(v, dict)}
        if prefix and scalars:
            lines.append(f"\n[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {_toml_value(v)}")
        for k, v in tables.items():
            emit(v, f"{prefix}.{k}" if prefix else k)

    emit(as_dict(config), "")
    return "\n".join(lines).lstrip("\n") + "\n"


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)
