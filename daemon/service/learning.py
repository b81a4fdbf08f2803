"""Learning a place: the Turn-Back-and-Look state machine (daemon/mapping/tbl.py) driven
with frames, odometry and moves (design §3, thesis §4.3).

One loop, :func:`drive_tbl`, for every caller. What differs is where frames and odometry
come from (:class:`Sensors`): in the daemon from the components that own the devices
(daemon/service/learn_job.py), in the evaluator straight from the HAL devices with the
simulator in lock-step (:class:`DeviceSensors`). Moves go to a :class:`Mover`: the base
device itself, or the daemon's base component.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from daemon.localisation.odometry import OdometryBuffer
from daemon.mapping.settings import TblSettings
from daemon.mapping.tbl import CandidateChooser, Progress, TurnBackAndLook
from daemon.vision.landmarks import LandmarkSet
from daemon.vision.unwarp import Unwarper
from hal.base.base import BaseInfo, BaseStatus
from hal.base.settings import BaseSettings
from kernel.errors import (
    DeviceTimeoutError,
    HalError,
    LearningAbortedError,
    LearningError,
    LearningRefusedError,
)
from kernel.mount import Mount
from kernel.types import Frame, Odometry

log = logging.getLogger(__name__)

ProgressCallback = Callable[[Progress], None]


class Sensors(Protocol):
    rate_hz: float  # frames per second, to turn the move timeout into frames

    def frame(self) -> tuple[Frame, Odometry]:
        """The next frame and the odometry at its stamp; LearningError when either stops."""


class Ahead(Protocol):
    """What a learn measures while its cross is driven (daemon/service/learn_ahead.py)."""

    def begin(self, candidates: LandmarkSet, reference: np.ndarray) -> None: ...

    def view(self, grey: np.ndarray) -> None: ...

    def foresee(self, kept: list[int]) -> None: ...


class Mover(Protocol):
    @property
    def info(self) -> BaseInfo: ...

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None: ...

    def status(self) -> BaseStatus: ...

    def stop(self) -> None: ...


def odometry_at_frame(buffer: OdometryBuffer, frame: Frame,
                      read: Callable[[], list[Odometry]], settings: TblSettings,
                      link_up: Callable[[], bool] = lambda: True) -> Odometry | None:
    """The odometry at ``frame``'s stamp, reading more samples (``read``, which waits the
    base's configured read timeout and raises DeviceTimeoutError when none came) until
    the buffer reaches just past it. None: the frame was taken before the first sample
    this learn read (a frame delivered late by a starved camera thread): skip it.

    A late sample is told from a dead link: while ``link_up`` says the base is running,
    samples slowed by a busy CPU are waited for, up to ``frame_timeout_s`` in all; a link
    that is down ends learning at once, saying so."""
    deadline = time.monotonic() + settings.frame_timeout_s
    while True:
        latest = buffer.latest
        if latest is not None and latest.stamp_ns >= frame.stamp_ns:
            break
        try:
            buffer.extend(read())
        except DeviceTimeoutError as e:
            if not link_up():
                raise LearningError(f"the odometry link went down during learning: {e}"
                                    ) from e
            if time.monotonic() >= deadline:
                raise LearningError(f"odometry fell {settings.frame_timeout_s:.1f} s behind "
                                    f"the frames during learning ({e})") from e
    return buffer.at(frame.stamp_ns, max_extrapolation_ns=100_000_000)


def frame_with_odometry(read_frame: Callable[[float], Frame], buffer: OdometryBuffer,
                        read_odometry: Callable[[], list[Odometry]], settings: TblSettings,
                        link_up: Callable[[], bool] = lambda: True) -> tuple[Frame, Odometry]:
    """The next frame that odometry covers, with the odometry at its stamp (what every
    :class:`Sensors` returns): ``read_frame(timeout_s)`` the camera's next frame,
    ``read_odometry`` as :func:`odometry_at_frame` reads. Frames older than the learn's
    first odometry sample are passed over, for ``frame_timeout_s``."""
    deadline = time.monotonic() + settings.frame_timeout_s
    while True:
        try:
            frame = read_frame(settings.frame_timeout_s)
        except DeviceTimeoutError as e:
            raise LearningError(f"frames stopped arriving during learning: {e}") from e
        odo = odometry_at_frame(buffer, frame, read_odometry, settings, link_up)
        if odo is not None:
            return frame, odo
        if time.monotonic() >= deadline:
            raise LearningError("no odometry at the frames' time: cannot learn")


class DeviceSensors:
    """Frames and odometry read from the devices themselves (the evaluator, tests).
    ``odometry_timeout_s``: how long one read of the base waits ([base] read_timeout_s)."""

    def __init__(self, camera: Any, base: Any, settings: TblSettings,
                 odometry_timeout_s: float,
                 on_odometry: Callable[[list[Odometry]], None] | None = None,
                 mount: Mount | None = None) -> None:
        self.camera, self.base, self.settings = camera, base, settings
        self.odometry_timeout_s = odometry_timeout_s
        self.odometry = OdometryBuffer()
        self.rate_hz = float(getattr(camera.info, "rate_hz", 0.0) or 10.0)
        self._on_odometry = on_odometry  # every sample read is also handed here
        self._mount = mount or Mount()  # the method sees the camera's odometry

    def frame(self) -> tuple[Frame, Odometry]:
        return frame_with_odometry(self.camera.read, self.odometry, self._read, self.settings)

    def _read(self) -> list[Odometry]:
        samples = self._mount.camera_odometry(self.base.read(self.odometry_timeout_s))
        if self._on_odometry is not None:
            self._on_odometry(samples)
        return samples


def run_tbl(camera: Any, base: Any, unwarper: Unwarper, settings: TblSettings, *,
            progress: ProgressCallback | None = None,
            abort: threading.Event | None = None,
            choose: CandidateChooser | None = None,
            odometry_timeout_s: float = BaseSettings().read_timeout_s,
            mount: Mount | None = None) -> TurnBackAndLook:
    """:func:`drive_tbl` reading the camera and base devices directly."""
    return drive_tbl(DeviceSensors(camera, base, settings, odometry_timeout_s, mount=mount),
                     base, unwarper, settings, progress=progress, abort=abort, choose=choose,
                     mount=mount)


def drive_tbl(sensors: Sensors, mover: Mover, unwarper: Unwarper, settings: TblSettings, *,
              progress: ProgressCallback | None = None,
              abort: threading.Event | None = None,
              choose: CandidateChooser | None = None,
              on_start: Callable[[Odometry], None] | None = None,
              mount: Mount | None = None, ahead: Ahead | None = None) -> TurnBackAndLook:
    """Drive the whole cross; returns the finished state machine (its result, its
    reference panorama and odometry, and for evaluation every scored candidate).
    ``choose``: see TurnBackAndLook. ``on_start`` is told the odometry at the reference
    pose before the robot moves. ``mount``: where the camera sits on the robot; the
    odometry ``sensors`` give is the camera's (kernel/mount.py), the moves are the robot's.
    ``ahead`` is handed the candidates and the reference panorama as the cross starts,
    each view it takes (``TurnBackAndLook.views``) as it is taken, and with the last the
    candidates the cross would keep were it to end there.

    Refuses (LearningError) when the base cannot move or frames stop arriving; on
    ``abort`` the robot is stopped and LearningAbortedError raised (nothing is stored)."""
    if not mover.info.can_move:
        raise LearningRefusedError(f"the base ({mover.info.backend}) cannot move: Turn Back and "
                            "Look needs to drive the cross")
    margin = unwarper.panorama.wrap_margin
    _come_to_rest(sensors, mover, settings)
    f1, odo = sensors.frame()
    f2, _ = sensors.frame()
    tbl = TurnBackAndLook(settings, unwarper.unwarp(f1.image), unwarper.unwarp(f2.image),
                          margin, odo, choose, kinematics=mover.info.kinematics,
                          mount=(mount or Mount()).robot_camera)
    if on_start is not None:
        on_start(odo)
    if ahead is not None:
        ahead.begin(tbl.candidates, tbl.reference_panorama)
    frames_this_leg = 0
    max_frames_per_leg = max(1, int(settings.move_timeout_s * sensors.rate_hz))
    try:
        while not tbl.done:
            if abort is not None and abort.is_set():
                raise LearningAbortedError("learning aborted on request")
            command = tbl.next_command()
            if command is not None:
                mover.move_relative(command.dx, command.dy, command.dyaw, command.speed)
                frames_this_leg = 0
            frame, odo = sensors.frame()
            status = mover.status()
            # A move only counts as done once the base has seen it: not on the first frame.
            done = status.move_done and not status.moving and frames_this_leg > 0
            views = len(tbl.views)
            step = tbl.on_frame(unwarper.unwarp(frame.image), odo, done)
            if ahead is not None and len(tbl.views) > views:
                ahead.view(tbl.views[-1])
                if len(tbl.views) == tbl.views_expected:
                    ahead.foresee(tbl.kept_so_far())
            frames_this_leg += 1
            if frames_this_leg > max_frames_per_leg:
                raise LearningError(f"the base did not finish a move within "
                                    f"{settings.move_timeout_s:.0f} s")
            if progress is not None:
                progress(step)
    except (LearningError, HalError):
        _stop(mover)
        raise
    return tbl


def _come_to_rest(sensors: Sensors, mover: Mover, settings: TblSettings) -> None:
    """Stop the robot (it may be driving: autonomous acquisition, teleop) and wait until it
    stands still, so the two reference frames are taken at one pose (§4.2)."""
    mover.stop()
    for _ in range(max(2, int(settings.move_timeout_s * sensors.rate_hz))):
        if not mover.status().moving:
            return
        sensors.frame()
    raise LearningError(f"the base did not come to rest within {settings.move_timeout_s:.0f} s")


def _stop(mover: Mover) -> None:
    try:
        mover.stop()
    except HalError as e:  # the robot may be unreachable; report, do not mask the cause
        log.error("could not stop the base after learning failed: %s", e)
