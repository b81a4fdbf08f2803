"""The localiser: the one pipeline that the daemon, the evaluator and the benchmarks drive.

Per frame (SPEC §1): unwarp the raw image to a panorama (one ``cv2.remap``), take the
odometry motion since the previous frame, update the belief, return it. It is pure: the
caller hands in frames and odometry samples with their stamps; nothing here reads a clock
or a device.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from daemon.localisation.odometry import OdometryBuffer, relative_motion
from daemon.vision.unwarp import Unwarper
from kernel.sensor_settings import MirrorSettings, PanoramaSettings
from kernel.types import Frame, Odometry

BeliefState = Literal["uninitialised", "tracking", "lost", "relocalising"]


@dataclass(frozen=True)
class Belief:
    """What the localiser believes after a frame (published as ``belief``/``pose``)."""

    stamp_ns: int
    state: BeliefState
    reason: str
    odometry_ok: bool
    place_id: int | None = None
    pose_in_place: tuple[float, float, float] | None = None
    covariance: tuple[float, ...] | None = None
    motion_since_last: tuple[float, float, float] | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


class Localiser:
    """Frames and odometry in, beliefs out."""

    # Odometry older than this at a frame's stamp counts as missing (SPEC §11: no invented
    # motion while the base is silent).
    ODOMETRY_STALE_NS = 250_000_000

    def __init__(self, mirror: MirrorSettings, panorama: PanoramaSettings,
                 places: int = 0) -> None:
        self.unwarper = Unwarper(mirror, panorama)
        self.odometry = OdometryBuffer()
        self.places = places
        self.panorama: np.ndarray | None = None
        self._last_odometry: Odometry | None = None

    def add_odometry(self, samples: list[Odometry]) -> None:
        self.odometry.extend(samples)

    def process_frame(self, frame: Frame) -> Belief:
        t0 = time.perf_counter()  # timing only; never used by the method
        self.panorama = self.unwarper.unwarp(frame.image)
        unwarp_ms = (time.perf_counter() - t0) * 1e3
        odo = self.odometry.at(frame.stamp_ns, max_extrapolation_ns=self.ODOMETRY_STALE_NS)
        motion = None
        if odo is not None and self._last_odometry is not None:
            motion = relative_motion(self._last_odometry, odo)
        self._last_odometry = odo
        state: BeliefState = "uninitialised"
        if self.places == 0:
            reason = "the map has no places yet"
        else:
            reason = f"the map has {self.places} places; localising in them is not built yet"
        if odo is None:
            reason += "; no odometry at this frame (base silent): motion unknown"
        return Belief(
            stamp_ns=frame.stamp_ns, state=state, reason=reason, odometry_ok=odo is not None,
            motion_since_last=motion, timings_ms={"unwarp": round(unwarp_ms, 3)},
        )
