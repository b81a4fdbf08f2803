"""Deciding on the robot's own when to learn a new place (design §6, thesis §7.1).

Watch the LRP of the most recent place as the robot moves away from it. Near the place
the LRP is high and falls; far from it, it settles at the set's *background*. The thesis
smooths the LRP over N frames, takes the windowed slope s_i = |LRP'_i − LRP'_{i−N}|,
smooths that again, and declares the background reached when the smoothed slope falls
below a threshold while the LRP lies between the default background (0.7) and the
maximum (0.85); an LRP below 0.7 is background at once. Here the samples are taken
against *distance travelled* (odometry), not frames, so the robot's speed does not change
the decision; frames while stationary or only turning add nothing. Once the place's
background can be estimated (daemon/mapping/backgrounds.py), a new place is learned a
little earlier, while the last one still stands ``coverage_margin`` above it (its LRP
averaged over ``coverage_window_m``, far less than the thesis's window): the background
rule alone leaves a stretch before each new place where no place is recognised.
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
    decision comes early (``coverage_margin``), the background the place is expected to
    settle at — the LRP here has not settled yet, and standing in for the background it
    would make the place look unrecognised where it still is."""

    place_id: int
    background_lrp: float
    distance_m: float  # travelled since the place
    lrp: float  # the smoothed LRP at the decision
    origin: Odometry | None = None  # the odometry where the place was first watched
    away_m: float = 0.0  # how far from ``origin`` the decision came


class PlaceAcquisition:
    def __init__(self, settings: AcquisitionSettings, default_background: float = 0.7) -> None:
        """``default_background``: the background LRP of a place never measured (the
        thesis's 0.7, ``[localisation] background_lrp``): a place whose smoothed LRP falls
        below it is left behind at once (§7.1)."""
        self.settings = settings
        self.default_background = default_background
        self._n = max(2, int(round(settings.window_m / settings.sample_step_m)))
        self.place_id: int | None = None
        self.reset(None)

    def reset(self, place_id: int | None, expected_background: float | None = None,
              reference: Odometry | None = None) -> None:
        """Watch ``place_id`` from here on (None: no place to watch). ``expected_background``:
        the background LRP the place is expected to settle at (see ``_decide``; the
        caller may update it as estimates come in). ``reference``: where the place's
        reference stands in the odometry frame, when the watch begins away from it (a
        restart resumed 0.7 m past the place): the distances count from there, and the
        coverage rule needs only its own short window of samples (the LRP nearer the
        place went unseen); None: from where the watch begins."""
        self.place_id = place_id
        self.reference = reference
        self.expected_background = expected_background
        self.distance_m = 0.0
        self._since_sample = 0.0
        self._pending: list[float] = []
        self._lrp: deque[float] = deque(maxlen=self._n)  # raw samples
        self._smooth: deque[float] = deque(maxlen=self._n + 1)  # LRP'
        self._slope: deque[float] = deque(maxlen=self._n)  # s_i
        self._last: Odometry | None = None
        # Where distances count from: the place's reference, or the first odometry while
        # watching the place.
        self.origin: Odometry | None = reference
        self.smoothed_lrp: float | None = None
        self.smoothed_slope: float | None = None

    def observe(self, lrp: float, odometry: Odometry | None) -> AcquisitionDecision | None:
        """One frame: the watched place's LRP and the odometry at the frame."""
        if self.place_id is None or odometry is None:
            return None
        last, self._last = self._last, odometry
        if last is None:
            if self.origin is None:
                self.origin = odometry
            else:  # begun away from the reference: as far from it as travelled
                self.distance_m = _apart(odometry, self.origin)
            return None
        step = _apart(odometry, last)
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
        # The LRP here, over a short window (below).
        k = max(1, min(self._n, int(round(s.coverage_window_m / s.sample_step_m))))
        if self.distance_m < s.min_distance_m or self._away() < s.min_distance_m \
                or len(self._lrp) < (k if self.reference is not None else self._n):
            return None  # too near, or a tour turning back near the place
        assert self.place_id is not None
        if m < self.default_background:  # below the default background: reached at once
            return self._decision(m, m)
        # Beyond the thesis: learn the next place while this one is still recognised, by
        # ``coverage_margin`` above the background it is expected to settle at, so the
        # map leaves no stretch where no place stands out.
        # The LRP here, over a short window: the thesis's average over window_m lags
        # half a window behind, and where a place is recognised only ~0.45 m about it
        # the next place came too late (corridor 1: the LRP here was 0.73, under the
        # expected background of 0.75, by the time the average came down to 0.83).
        recent = sum(list(self._lrp)[-k:]) / k
        expected = self.expected_background
        if expected is not None and s.coverage_margin > 0 \
                and recent < expected + s.coverage_margin:
            return self._decision(min(m, expected), m)
        slope = self.smoothed_slope
        if slope is not None and len(self._slope) == self._n and slope < s.slope_threshold \
                and m <= s.lrp_max:
            return self._decision(m, m)
        return None

    def _away(self) -> float:
        """How far the robot stands from ``origin`` (odometry): the place's reference, or
        where the watch began."""
        origin, here = self.origin, self._last
        return 0.0 if origin is None or here is None else _apart(here, origin)

    def _decision(self, background: float, lrp: float) -> AcquisitionDecision:
        assert self.place_id is not None
        return AcquisitionDecision(self.place_id, background, self.distance_m, lrp,
                                   self.origin, self._away())


def taken_over(leads: dict[int, float], settings: AcquisitionSettings,
               near: set[int] | None = None) -> int | None:
    """When a decision comes back on a known path (§7.1: the most likely place): the
    known place whose lead (LRP minus its background, by place id) is highest, if it is
    by the recognition margin — and by the coverage margin, for a place taken over below
    it would be left again as soon as the robot is ``min_distance_m`` on (corridor 1: a
    place 2.8 m behind, taken over at a lead of 0.055 in the aliased corridor, left a
    2.6 m gap between places). ``near``: the places the map puts near the robot; one
    outside it counts only by ``certain_lead`` (a look-alike elsewhere is no path back,
    but no look-alike stands that high). None: learn a new place here."""
    need = max(settings.recognition_margin, settings.coverage_margin)
    counted = {p: lead for p, lead in leads.items()
               if near is None or p in near or lead >= settings.certain_lead}
    best = max(counted, key=lambda p: counted[p], default=None)
    return best if best is not None and counted[best] >= need else None


class BackgroundMeter:
    """A place's background LRP (§7.1): the level its LRP settles at away from it. The
    acquisition's decision comes when the LRP *reaches* the background (or earlier, see
    ``coverage_margin``); the level it settles at is measured further on: the median LRP
    over ``window_m`` travelled after the first ``skip_m``, frames while stationary or
    turning ignored — and, given the ``origin`` where the place was watched from, frames
    nearer to it than ``min_away_m`` (where the decision came) ignored too: a tour that
    turns back past the place would otherwise take its view near the place for its
    background (office 1: a place learned 0.30 m from one whose background had been
    measured on the way back over it)."""

    def __init__(self, place_id: int, window_m: float, skip_m: float = 0.0,
                 origin: Odometry | None = None, min_away_m: float = 0.0) -> None:
        self.place_id = place_id
        self.window_m = window_m
        self.skip_m = skip_m
        self.origin = origin
        self.min_away_m = min_away_m
        self.samples: list[float] = []
        self.distance_m = 0.0  # travelled since the decision
        self.sampled_m = 0.0  # of which away from the place, after the skip
        self._last: Odometry | None = None

    def observe(self, lrp: float, odometry: Odometry | None) -> float | None:
        """The background once ``window_m`` is travelled away from the place after the
        first ``skip_m`` (then once only)."""
        if odometry is None:
            return None
        last, self._last = self._last, odometry
        if last is None:
            return None
        step = _apart(odometry, last)
        if step < 1e-4:
            return None
        self.distance_m += step
        if self.distance_m < self.skip_m or not self._away(odometry):
            return None
        self.samples.append(lrp)
        self.sampled_m += step
        if self.sampled_m < self.window_m:
            return None
        return float(sorted(self.samples)[len(self.samples) // 2])

    def _away(self, odometry: Odometry) -> bool:
        return self.origin is None or _apart(odometry, self.origin) >= self.min_away_m


def _apart(a: Odometry, b: Odometry) -> float:
    """The distance between two odometry positions, metres."""
    return math.hypot(a.x - b.x, a.y - b.y)
