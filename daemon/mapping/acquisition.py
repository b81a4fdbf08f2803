"""Deciding on the robot's own when to learn a new place (design §6, thesis §7.1).

Watch the LRP of the most recent place as the robot moves away from it. Near the place
the LRP is high and falls; far from it, it settles at the set's *background*. The thesis
smooths the LRP over N frames, takes the windowed slope s_i = |LRP'_i − LRP'_{i−N}|,
smooths that again, and declares the background reached when the smoothed slope falls
below a threshold while the LRP lies between the default background (0.7) and the
maximum (0.85); an LRP below 0.7 is background at once. Here the samples are taken
against *distance travelled* (odometry), not frames, so the robot's speed does not change
the decision; frames while stationary or only turning add nothing. Once backgrounds have
been measured nearby, a new place is learned a little earlier, while the last one still
stands ``coverage_margin`` above that background: the background rule alone leaves a
stretch before each new place where no place is recognised.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from daemon.mapping.settings import AcquisitionSettings
from kernel.types import Odometry


@dataclass(frozen=True)
class AcquisitionDecision:
    """Learn a new place here; ``background_lrp`` is the first estimate of the last
    place's background: the LRP here once it has settled (the thesis's rule), or, when the
    decision comes early (``coverage_margin``), the background the places around here
    settle at — the LRP here has not settled yet, and standing in for the background it
    would make the place look unrecognised where it still is."""

    place_id: int
    background_lrp: float
    distance_m: float  # travelled since the place
    lrp: float  # the smoothed LRP at the decision


class PlaceAcquisition:
    def __init__(self, settings: AcquisitionSettings) -> None:
        self.settings = settings
        self._n = max(2, int(round(settings.window_m / settings.sample_step_m)))
        self.place_id: int | None = None
        self.reset(None)

    def reset(self, place_id: int | None, expected_background: float | None = None) -> None:
        """Watch ``place_id`` from here on (None: no place to watch). ``expected_background``:
        the background LRP places here are known to settle at (see ``_decide``)."""
        self.place_id = place_id
        self.expected_background = expected_background
        self.distance_m = 0.0
        self._since_sample = 0.0
        self._pending: list[float] = []
        self._lrp: deque[float] = deque(maxlen=self._n)  # raw samples
        self._smooth: deque[float] = deque(maxlen=self._n + 1)  # LRP'
        self._slope: deque[float] = deque(maxlen=self._n)  # s_i
        self._last: Odometry | None = None
        self.smoothed_lrp: float | None = None
        self.smoothed_slope: float | None = None

    def observe(self, lrp: float, odometry: Odometry | None) -> AcquisitionDecision | None:
        """One frame: the watched place's LRP and the odometry at the frame."""
        if self.place_id is None or odometry is None:
            return None
        last, self._last = self._last, odometry
        if last is None:
            return None
        step = math.hypot(odometry.x - last.x, odometry.y - last.y)
        if step < 1e-4:  # stationary or turning on the spot: no new information
            return None
        self.distance_m += step
        self._since_sample += step
        self._pending.append(lrp)
        if self._since_sample < self.settings.sample_step_m:
            return None
        self._since_sample = 0.0
        self._lrp.append(sum(self._pending) / len(self._pending))
        self._pending = []
        return self._decide()

    def _decide(self) -> AcquisitionDecision | None:
        s = self.settings
        self._smooth.append(sum(self._lrp) / len(self._lrp))  # LRP' (moving average)
        m = self._smooth[-1]
        self.smoothed_lrp = m
        if len(self._smooth) > self._n:
            self._slope.append(abs(self._smooth[-1] - self._smooth[0]))  # s_i
            self.smoothed_slope = sum(self._slope) / len(self._slope)
        if self.distance_m < s.min_distance_m or len(self._lrp) < self._n:
            return None
        assert self.place_id is not None
        if m < s.lrp_background:  # below the default background: reached at once
            return AcquisitionDecision(self.place_id, m, self.distance_m, m)
        # Beyond the thesis: learn the next place while this one is still recognised, by
        # ``coverage_margin`` above the background the places around here settle at, so
        # the map leaves no stretch where no place stands out.
        expected = self.expected_background
        if expected is not None and s.coverage_margin > 0 \
                and m < expected + s.coverage_margin:
            return AcquisitionDecision(self.place_id, min(m, expected), self.distance_m, m)
        slope = self.smoothed_slope
        if slope is not None and len(self._slope) == self._n and slope < s.slope_threshold \
                and m <= s.lrp_max:
            return AcquisitionDecision(self.place_id, m, self.distance_m, m)
        return None


class BackgroundMeter:
    """A place's background LRP (§7.1): the level its LRP settles at away from it. The
    acquisition's decision comes when the LRP *reaches* the background (or earlier, see
    ``coverage_margin``); the level it settles at is measured further on: the median LRP
    over ``window_m`` travelled after the first ``skip_m``, frames while stationary or
    turning ignored."""

    def __init__(self, place_id: int, first_estimate: float, window_m: float,
                 skip_m: float = 0.0) -> None:
        self.place_id = place_id
        self.window_m = window_m
        self.skip_m = skip_m
        self.first_estimate = first_estimate
        self.samples: list[float] = []
        self.distance_m = 0.0
        self._last: Odometry | None = None

    def observe(self, lrp: float, odometry: Odometry | None) -> float | None:
        """The background once ``skip_m + window_m`` is travelled (then once only)."""
        if odometry is None:
            return None
        last, self._last = self._last, odometry
        if last is None or math.hypot(odometry.x - last.x, odometry.y - last.y) < 1e-4:
            return None
        self.distance_m += math.hypot(odometry.x - last.x, odometry.y - last.y)
        if self.distance_m >= self.skip_m:
            self.samples.append(lrp)
        if self.distance_m < self.skip_m + self.window_m:
            return None
        values = sorted(self.samples) or [self.first_estimate]
        return float(values[len(values) // 2])
