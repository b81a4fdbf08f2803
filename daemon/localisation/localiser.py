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
from daemon.mapping.acquisition import AcquisitionDecision, BackgroundMeter, PlaceAcquisition
from daemon.mapping.place import Place
from daemon.mapping.settings import AcquisitionSettings
from daemon.vision.recognition import FastMatcher, PreparedPanorama, PreparedTemplates
from daemon.vision.unwarp import Unwarper
from kernel.panorama import to_grey
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
    recent_place: int | None = None  # the place autonomous acquisition watches...
    recent_place_lrp: float | None = None  # ...its LRP in this frame
    acquisition: AcquisitionDecision | None = None  # learn a new place here (design §6)
    backgrounds: tuple[tuple[int, float], ...] = ()  # (place, background LRP) measured now


class Localiser:
    """Frames and odometry in, beliefs out."""

    # Odometry older than this at a frame's stamp counts as missing (SPEC §11: no invented
    # motion while the base is silent).
    ODOMETRY_STALE_NS = 250_000_000

    def __init__(self, mirror: MirrorSettings, panorama: PanoramaSettings,
                 places: int = 0, acquisition: AcquisitionSettings | None = None) -> None:
        self.unwarper = Unwarper(mirror, panorama)
        self.odometry = OdometryBuffer()
        self.places = places
        self.panorama: np.ndarray | None = None
        self._last_odometry: Odometry | None = None
        self.matcher = FastMatcher()
        self.acquisition = PlaceAcquisition(acquisition) if acquisition is not None \
            and acquisition.enabled else None
        self._watched: tuple[int, PreparedTemplates] | None = None
        self._watch_next: tuple[int, PreparedTemplates] | None = None  # from other threads
        self._known: dict[int, tuple[PreparedTemplates, float | None]] = {}
        self._meters: list[BackgroundMeter] = []  # places being left behind

    def know_place(self, place: Place) -> None:
        """A place of the map (its landmark set and background LRP, if measured). Safe to
        call from another thread."""
        self._known = {**self._known, place.id: (
            PreparedTemplates.of(place.landmarks.templates()), place.background_lrp)}
        self.places = len(self._known)

    def watch_place(self, place: Place) -> None:
        """Autonomous acquisition watches ``place`` (the one just learned) from the next
        frame on. Safe to call from another thread."""
        self.know_place(place)
        self._watch_next = (place.id, self._known[place.id][0])

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
        recent, recent_lrp, decision, background = self._acquire(odo)
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
            recent_place=recent, recent_place_lrp=recent_lrp, acquisition=decision,
            backgrounds=background,
        )

    def _acquire(self, odo: Odometry | None) -> tuple[
            int | None, float | None, AcquisitionDecision | None, tuple[tuple[int, float], ...]]:
        """The watched place's LRP in this frame, whether to learn a new place, and a
        background LRP measured as the robot left a place behind."""
        if self.acquisition is None or self.panorama is None:
            return None, None, None, ()
        if self._watch_next is not None:
            self._watched, self._watch_next = self._watch_next, None
            self.acquisition.reset(self._watched[0], self._expected_background())
        if self._watched is None and not self._meters:
            return None, None, None, ()
        prepared = PreparedPanorama.of(to_grey(self.panorama))
        background = self._measure_backgrounds(prepared, odo)
        if self._watched is None:
            return None, None, None, background
        place_id, templates = self._watched
        lrp = self.matcher.lrp(prepared, templates)
        decision = self.acquisition.observe(lrp, odo)
        if decision is None:
            return place_id, lrp, None, background
        # The watched place is behind us: measure the level its LRP settles at...
        acq = self.acquisition.settings
        self._meters.append(BackgroundMeter(place_id, decision.background_lrp,
                                            acq.background_window_m, acq.background_skip_m))
        # ...and back on a known path another place may be recognised here (the most
        # likely place, §7.1): watch that one instead of learning.
        known = self._most_likely(prepared, exclude=place_id)
        if known is not None:
            self._watched = (known, self._known[known][0])
            self.acquisition.reset(known, self._expected_background())
            return place_id, lrp, None, background
        self._watched = None  # until the new place is learned and watched
        self.acquisition.reset(None)
        return place_id, lrp, decision, background

    def _expected_background(self) -> float | None:
        """The median background LRP of the places measured so far (None: none yet)."""
        measured = sorted(b for _, b in self._known.values() if b is not None)
        return measured[len(measured) // 2] if measured else None

    def _measure_backgrounds(self, prepared: PreparedPanorama, odo: Odometry | None
                             ) -> tuple[tuple[int, float], ...]:
        done: list[tuple[int, float]] = []
        for meter in list(self._meters):
            known = self._known.get(meter.place_id)
            if known is None:
                self._meters.remove(meter)
                continue
            value = meter.observe(self.matcher.lrp(prepared, known[0]), odo)
            if value is not None:
                self._meters.remove(meter)
                self._known = {**self._known, meter.place_id: (known[0], value)}
                done.append((meter.place_id, value))
        return tuple(done)

    def _most_likely(self, prepared: PreparedPanorama, exclude: int) -> int | None:
        """The known place whose LRP stands highest above its background here, if that
        is by the acquisition's recognition margin (§9.2: LRP minus background)."""
        assert self.acquisition is not None
        s = self.acquisition.settings
        best, best_id = s.recognition_margin, None
        for pid, (templates, background) in self._known.items():
            if pid == exclude:
                continue
            lead = self.matcher.lrp(prepared, templates) - (
                s.lrp_background if background is None else background)
            if lead >= best:
                best, best_id = lead, pid
        return best_id
