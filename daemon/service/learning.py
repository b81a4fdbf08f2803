"""Learning a place with real devices: the Turn-Back-and-Look state machine driven through
the HAL (SPEC §3.2). The same function runs in the daemon and in the evaluator (with the
simulator in lock-step)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from daemon.localisation.odometry import OdometryBuffer
from daemon.mapping.settings import TblSettings
from daemon.mapping.tbl import CandidateChooser, Progress, TurnBackAndLook
from daemon.vision.landmarks import LandmarkSet
from daemon.vision.unwarp import Unwarper
from kernel.errors import DeviceTimeoutError, HalError, LearningAbortedError, LearningError
from kernel.types import Frame, Odometry

log = logging.getLogger(__name__)

ProgressCallback = Callable[[Progress], None]


class _Sensors:
    """Frames and the odometry at their stamps."""

    def __init__(self, camera: Any, base: Any, settings: TblSettings) -> None:
        self.camera, self.base, self.settings = camera, base, settings
        self.odometry = OdometryBuffer()

    def frame(self) -> tuple[Frame, Odometry]:
        try:
            frame: Frame = self.camera.read(self.settings.frame_timeout_s)
        except DeviceTimeoutError as e:
            raise LearningError(f"frames stopped arriving during learning: {e}") from e
        for _ in range(50):  # odometry up to (and just past) the frame's stamp
            latest = self.odometry.latest
            if latest is not None and latest.stamp_ns >= frame.stamp_ns:
                break
            try:
                self.odometry.extend(self.base.read(0.2))
            except DeviceTimeoutError as e:
                raise LearningError(f"odometry stopped arriving during learning: {e}") from e
        odo = self.odometry.at(frame.stamp_ns, max_extrapolation_ns=100_000_000)
        if odo is None:
            raise LearningError("no odometry at the frame's time: cannot learn")
        return frame, odo


def learn_place(camera: Any, base: Any, unwarper: Unwarper, settings: TblSettings, *,
                progress: ProgressCallback | None = None,
                abort: threading.Event | None = None) -> LandmarkSet:
    """Turn Back and Look at the current pose; returns the place's landmark set."""
    return run_tbl(camera, base, unwarper, settings, progress=progress, abort=abort).result()


def run_tbl(camera: Any, base: Any, unwarper: Unwarper, settings: TblSettings, *,
            progress: ProgressCallback | None = None,
            abort: threading.Event | None = None,
            choose: CandidateChooser | None = None) -> TurnBackAndLook:
    """Drive the whole cross; returns the finished state machine (its result, and for
    evaluation every scored candidate). ``choose``: see TurnBackAndLook.

    Refuses (LearningError) when the base cannot move or frames stop arriving; on
    ``abort`` the robot is stopped and LearningAbortedError raised (nothing is stored)."""
    if not base.info.can_move:
        raise LearningError(f"the base ({base.info.backend}) cannot move: Turn Back and Look "
                            "needs to drive the cross")
    sensors = _Sensors(camera, base, settings)
    margin = unwarper.panorama.wrap_margin
    f1, odo = sensors.frame()
    f2, _ = sensors.frame()
    tbl = TurnBackAndLook(settings, unwarper.unwarp(f1.image), unwarper.unwarp(f2.image),
                          margin, odo, choose)
    frames_this_leg = 0
    max_frames_per_leg = None
    try:
        while not tbl.done:
            if abort is not None and abort.is_set():
                raise LearningAbortedError("learning aborted on request")
            command = tbl.next_command()
            if command is not None:
                base.move_relative(command.dx, command.dy, command.dyaw, command.speed)
                frames_this_leg = 0
            frame, odo = sensors.frame()
            status = base.status()
            # A move only counts as done once the base has seen it: not on the first frame.
            done = status.move_done and not status.moving and frames_this_leg > 0
            step = tbl.on_frame(unwarper.unwarp(frame.image), odo, done)
            frames_this_leg += 1
            rate = getattr(camera.info, "rate_hz", 0.0) or 10.0
            max_frames_per_leg = max_frames_per_leg or int(settings.move_timeout_s * rate)
            if frames_this_leg > max_frames_per_leg:
                raise LearningError(f"the base did not finish a move within "
                                    f"{settings.move_timeout_s:.0f} s")
            if progress is not None:
                progress(step)
    except (LearningError, HalError):
        _stop(base)
        raise
    return tbl


def _stop(base: Any) -> None:
    try:
        base.stop()
    except HalError as e:  # the robot may be unreachable; report, do not mask the cause
        log.error("could not stop the base after learning failed: %s", e)
