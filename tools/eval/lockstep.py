"""The simulated robot in lock-step, driving the daemon's own pipeline (design §10).

:class:`Run` opens the HAL sim camera and base of one configuration, feeds every frame and
every odometry sample to one :class:`~daemon.localisation.localiser.Localiser` (the
object the daemon runs), learns places with the daemon's Turn Back and Look loop, changes
the map only through the daemon's :class:`~daemon.service.mapping_session.MappingSession`
(a real map file; what a belief, a learned place or a closed cycle does to the map is the
daemon's own code), and reads ground truth through the simulator's truth interface
(``true_pose``) for the evaluator only.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import tempfile
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

import numpy as np

from daemon.config import PlacecellConfig, load
from daemon.localisation.belief import Belief, MapUpdates
from daemon.localisation.localiser import Localiser
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.place import Place
from daemon.mapping.settings import AcquisitionSettings
from daemon.mapping.tbl import cross_legs
from daemon.service.learning import DeviceSensors, drive_tbl
from daemon.service.mapper import Link, Mapper
from daemon.service.mapping_session import Event, MappingSession
from daemon.service.pipeline import make_localiser, resume
from daemon.store.sqlite_store import MapStore, SavedPose
from hal.registry import HalContext, create_base, create_camera
from hal.sim.factory import build_sim_robot
from hal.sim.robot import SimRobot
from hal.sim.scenario import Scenario
from kernel.errors import LearningError
from kernel.panorama import geometry_checksum
from kernel.se2 import SE2
from kernel.settings import as_dict, build
from kernel.types import Frame
from tools.eval.cameras import with_camera_model
from tools.eval.ros2_robot import RemoteSimRobot, ros2_robot

# An evaluator's change to a raw frame before the localiser sees it (occlusion).
FrameFilter = Callable[[np.ndarray], np.ndarray]


def add_mount_arguments(p: argparse.ArgumentParser) -> None:
    """Where the simulated camera sits (kernel/mount.py) and whether the method is told."""
    p.add_argument("--camera-ahead", type=float, default=0.0, metavar="M",
                   help="the camera this far ahead of the rotation centre")
    p.add_argument("--mount-left-out", action="store_true",
                   help="...and the configuration says it is centred")


def add_localisation_arguments(p: argparse.ArgumentParser) -> None:
    """The options every localisation experiment takes (see localisation_settings)."""
    p.add_argument("--sensor-model", choices=("assumed", "estimated", "ellipsoid"),
                   default="ellipsoid")
    p.add_argument("--particles", type=int, default=None)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a [localisation] setting (repeatable)")


def localisation_settings(default: LocalisationSettings, args: argparse.Namespace
                          ) -> LocalisationSettings:
    """The [localisation] settings with the experiment's overrides (``--set k=v``)."""
    data = as_dict(default) | {"sensor_model": args.sensor_model, "seed": args.seed}
    if args.particles:
        data["particles"] = args.particles
    for item in args.set:
        key, _, value = item.partition("=")
        data[key] = tomllib.loads(f"v = {value}")["v"]
    return build(LocalisationSettings, data, "localisation")


def with_kinematics(cfg: PlacecellConfig, kinematics: str) -> PlacecellConfig:
    """The simulated base holonomic or differential (Turn Back and Look drives its cross
    with turns on the latter, design §3)."""
    if kinematics not in ("holonomic", "differential"):
        raise ValueError(f"kinematics {kinematics!r}: holonomic or differential")
    sim_base = dataclasses.replace(cfg.base.sim, kinematics=kinematics)  # type: ignore[arg-type]
    return dataclasses.replace(cfg, base=dataclasses.replace(cfg.base, sim=sim_base))


def add_backends_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--backends", choices=("sim", "ros2"), default="sim",
                   help="ros2: the simulated robot as a ROS 2 robot in its own process, in "
                        "real time, read and driven through the ros2 camera and base "
                        "backends (tools/eval/ros2_robot.py)")


@contextlib.contextmanager
def open_run(cfg: PlacecellConfig, backends: str = "sim", map_path: Path | None = None
             ) -> Iterator[Run]:
    """A :class:`Run` of ``cfg`` on the sim backends in lock-step, or (``ros2``) on the
    ros2 backends with the robot in its own process, in real time."""
    if backends == "sim":
        with Run(cfg, map_path=map_path) as run:
            yield run
        return
    with ros2_robot(cfg) as (ros2_cfg, remote), \
            Run(ros2_cfg, map_path=map_path, remote=remote) as run:
        yield run


def lockstep_config(seed: int, scenario: str = "", world: str = "",
                    start_pose: tuple[float, float, float] | None = None,
                    localisation: LocalisationSettings | None = None,
                    kinematics: str = "holonomic", camera_model: str = "mirror",
                    camera_ahead_m: float = 0.0, mount_known: bool = True) -> PlacecellConfig:
    """The default configuration for a lock-step run: the simulated robot (not in real
    time, seeded) in ``world`` or ``scenario``, with its kinematics and camera model; its
    camera ``camera_ahead_m`` ahead of the rotation centre, which the configuration says
    when ``mount_known`` (else the camera is centred as far as the method knows)."""
    base = with_camera_model(load(None), camera_model)
    if camera_ahead_m:
        said = camera_ahead_m if mount_known else 0.0
        base = dataclasses.replace(
            base, camera=dataclasses.replace(base.camera, mount_x_m=said),
            sim=dataclasses.replace(base.sim, mount_error_x_m=camera_ahead_m - said))
    sim = dataclasses.replace(base.sim, realtime=False, seed=seed, scenario=scenario)
    if world:
        sim = dataclasses.replace(sim, world=world)
    if start_pose is not None:
        sim = dataclasses.replace(sim, start_pose=list(start_pose))
    return with_kinematics(dataclasses.replace(base, sim=sim,
                                               localisation=localisation or base.localisation),
                           kinematics)


class Run:
    """One lock-step run; use as a context manager."""

    def __init__(self, cfg: PlacecellConfig, scenario: Scenario | None = None,
                 frame_filter: FrameFilter | None = None, map_path: Path | None = None,
                 remote: RemoteSimRobot | None = None) -> None:
        """``map_path``: keep the map file there (default: a temporary one). ``remote``:
        the robot runs in its own process (``cfg`` on the ros2 backends, open_run); the
        experiment's truth comes from it, at the frames the run reads."""
        self.cfg = cfg
        self.ctx = HalContext(cfg)
        camera = create_camera(cfg.camera, self.ctx)
        if remote is None:
            self.robot: SimRobot = self.ctx.shared("sim.robot",
                                                   lambda: build_sim_robot(cfg, scenario))
        else:  # answers what open_run's experiments ask of a SimRobot
            self.robot, camera = cast(SimRobot, remote), remote.watch(camera)
        self.camera, self.base = camera, create_base(cfg.base, self.ctx)
        self._tmp = tempfile.TemporaryDirectory()
        self.store = MapStore.open(map_path or Path(self._tmp.name) / "map.db",
                                   geometry_checksum(cfg.projection, cfg.panorama))
        self.mapper = Mapper(self.store, cfg.odometry, cfg.mapping.learn_threads)
        self.session = MappingSession(self.mapper, cfg.mapping.acquisition, cfg.localisation)
        self.localiser = Localiser(cfg.projection, cfg.panorama, settings=cfg.localisation,
                                   odometry_noise=cfg.odometry, known_map=self.session.holder,
                                   mount=cfg.mount)
        self.events: list[Event] = []  # what the map's owner said, as the daemon publishes
        self.updates = MapUpdates()  # what the last frame found that changes the map
        self.sensors = DeviceSensors(self.camera, self.base, cfg.tbl,
                                     cfg.base.read_timeout_s, on_odometry=self._odometry,
                                     mount=cfg.mount)
        self.frame_filter = frame_filter
        # the true pose of each place's frame: the camera's at its reference (truth)
        self.references: dict[int, SE2] = {}
        self.process_s: list[float] = []

    def __enter__(self) -> Run:
        self.camera.open()
        self.base.open()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.camera.close()
        self.base.close()
        self.store.close()
        self._tmp.cleanup()

    def _odometry(self, samples: list[Any]) -> None:
        self.localiser.add_odometry(samples)
        self.mapper.on_odometry(samples)

    # ------------------------------------------------------------------ driving
    def step(self) -> tuple[Frame, Belief]:
        """The next frame through the localiser."""
        frame, _ = self.sensors.frame()
        if self.frame_filter is not None:
            frame = dataclasses.replace(frame, image=self.frame_filter(frame.image))
        t0 = time.perf_counter()
        belief, self.updates = self.localiser.process_frame(frame)
        self.process_s.append(time.perf_counter() - t0)
        self.events += self.session.observe(belief, self.updates)  # as the daemon does
        return frame, belief

    def drive(self, dx: float, dy: float, dyaw: float, speed: float) -> Iterator[Belief]:
        """Command one relative move and process every frame until it is done."""
        self.base.move_relative(dx, dy, dyaw, speed)
        frames, limit = 0, int(60 * self.sensors.rate_hz)
        while True:
            _, belief = self.step()
            yield belief
            frames += 1
            status = self.base.status()
            if (status.move_done and not status.moving and frames > 1) or frames > limit:
                return

    def drive_cross(self, extent: float, speed: float) -> Iterator[Belief]:
        """The Turn Back and Look cross (§4.3) from here, heading kept."""
        mount = self.cfg.mount.robot_camera
        for leg in cross_legs(extent, self.base.info.kinematics, (mount.x, mount.y)):
            yield from self.drive(leg.dx, leg.dy, leg.dyaw, speed)

    def learn(self, label: str = "") -> Place:
        """Turn Back and Look here with the daemon's loop; the place is stored with its
        transition from the place learned before and handed to the localiser, which
        tracks from its reference, as in the daemon."""
        links: list[Link] = []
        truth: list[tuple[float, float, float]] = []

        def start(odo: Any) -> None:  # at rest at the reference pose
            links.extend(self.session.begin_place(odo, self.localiser.reliable_estimate()))
            truth.append(self.robot.true_pose())

        self.localiser.learning(True)  # as the daemon does while a learn job runs
        try:
            tbl = drive_tbl(self.sensors, self.base, self.localiser.unwarper, self.cfg.tbl,
                            on_start=start, mount=self.cfg.mount,
                            ahead=self.session.learn_ahead())
        except LearningError:  # as the daemon's job ends: nothing stored
            self.session.cancel_place()
            self.localiser.learning_not_started()
            raise
        finally:
            self.localiser.learning(False)
        learned = self.session.store_place(
            Place(tbl.result(), tbl.reference_panorama, label=label,
                  local_space=self.localiser.place_profile(tbl.reference_panorama)),
            links, tbl.views, seen_at_end=self.localiser.reliable_estimate())
        self.events += learned.events
        self.localiser.place_learned(learned.place.id)  # as the daemon does
        self.references[learned.place.id] = self.cfg.mount.camera_pose(SE2.of(truth[0]))
        return learned.place

    def restart(self, acquisition: AcquisitionSettings | None = None,
                saved: SavedPose | None = None) -> Localiser:
        """The daemon stopped and started again on the same map file: a new Mapper,
        MappingSession and Localiser (with ``acquisition`` on, as the daemon runs it),
        resumed from ``saved`` (the pose saved at the stop) as the daemon resumes."""
        self.mapper = Mapper(self.store, self.cfg.odometry,
                             self.cfg.mapping.learn_threads)
        self.session = MappingSession(self.mapper, self.cfg.mapping.acquisition,
                                      self.cfg.localisation)
        with self.mapper.lock:
            self.localiser = make_localiser(self.cfg, self.session.holder, self.mapper.graph,
                                            acquisition)
        if saved is not None:
            resume(self.localiser, saved)
        return self.localiser

    def restart_localiser(self) -> Localiser:
        """A new Localiser on the map as stored, as the daemon builds one when it starts:
        no pose, so it localises globally (design §9)."""
        with self.mapper.lock:
            self.localiser = make_localiser(self.cfg, self.session.holder, self.mapper.graph)
        return self.localiser

    # ------------------------------------------------------------------ truth
    def truth_in(self, place_id: int) -> SE2:
        """The true pose of the method's camera (the robot's, with the configured mount,
        kernel/mount.py) in place ``place_id``'s frame (evaluator only)."""
        return self.references[place_id].between(
            self.cfg.mount.camera_pose(SE2.of(self.robot.true_pose())))

    def error_m(self, belief: Belief) -> float | None:
        """Distance between the robot's pose the belief gives and the truth."""
        if belief.pose_in_place is None or belief.place_id is None:
            return None
        mount = self.cfg.mount
        truth = mount.robot_pose(self.truth_in(belief.place_id))
        estimate = mount.robot_pose(SE2.of(belief.pose_in_place))
        return math.hypot(estimate.x - truth.x, estimate.y - truth.y)
