"""Local positioning within one place (design §7, thesis §8.1): track the place's landmarks
in the current panorama and update the particle filter with them.

Per frame: resample → predict with the odometry since the last frame → track each landmark
in a window around where the current estimate expects it (wider as the estimate is less
sure) → weigh the particles with the sensor model → estimate (dominant mode, covariance)
and confidence (the raw sensor-model output at the estimate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from daemon.localisation.particle_filter import Estimate, ParticleFilter
from daemon.localisation.sensor_models import (
    LandmarkGeometry,
    SensorModel,
    combine,
    ncc_weights,
    raw_output,
)
from daemon.localisation.settings import LocalisationSettings
from daemon.mapping.place import Place
from daemon.vision.landmarks import TEMPLATE
from daemon.vision.tracking import Track, column_to_bearing_of_centre, predict_column, track
from kernel.angles import wrap_angle
from kernel.se2 import SE2


@dataclass(frozen=True)
class LocalResult:
    estimate: Estimate
    confidence: float  # raw sensor-model output at the estimate, [0, 1]
    support: float = 1.0  # the same over the landmarks usable from here, seen or not


def initial_orientation(bearings: np.ndarray, reference: np.ndarray, ncc: np.ndarray,
                        min_ncc: float, tolerance: float = math.radians(5.0)
                        ) -> float | None:
    """θ₀ from the landmarks matching at least ``min_ncc`` (eq. 8.34: the mean of reference
    minus current bearing, γ_i − φ_i). Made robust: the mean of the differences within
    ``tolerance`` of the one most others agree with; None with fewer than three."""
    good = ncc >= min_ncc
    if good.sum() < 3:
        return None
    diff = np.asarray(wrap_angle(reference[good] - bearings[good]))
    apart = np.abs(np.asarray(wrap_angle(diff[:, None] - diff[None, :])))
    support = (apart <= tolerance).sum(axis=1)
    best = int(np.argmax(support))
    if support[best] < 3:
        return None
    inliers = diff[apart[best] <= tolerance]
    return float(math.atan2(np.sin(inliers).mean(), np.cos(inliers).mean()))


class PlaceTracker:
    """The particle filter in one place's frame, fed by tracking its landmarks."""

    def __init__(self, place: Place, settings: LocalisationSettings, model: SensorModel,
                 rng: np.random.Generator,
                 mount: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        self.place = place
        self.settings = settings
        self.model = model
        self.geometry = LandmarkGeometry.of(place.landmarks, settings.far_depth_m)
        self.templates = place.landmarks.templates()
        self.rows = place.landmarks.rows().astype(float)
        self.width = place.landmarks.width
        self.margin = place.landmarks.margin
        self.filter = ParticleFilter(settings, rng, mount)
        self.estimate: Estimate | None = None
        self.confidence = 0.0  # of the last update
        self.support = 0.0

    def start(self, grey: np.ndarray, pose: tuple[float, float, float], sigma_xy: float,
              sigma_yaw: float) -> None:
        """Particles around ``pose``. When the orientation is barely known (σ_θ > 0.2 rad),
        it is first taken from the landmarks' bearings (§8.1.5, eq. 8.34), searched over
        the whole panorama."""
        if sigma_yaw > 0.2:
            found = self._track(grey, pose, radius=self.width // 2 - TEMPLATE)
            bearings = column_to_bearing_of_centre(found.cols, self.width)
            theta0 = initial_orientation(bearings, self.geometry.bearing, found.scores,
                                         self.settings.orientation_ncc)
            if theta0 is not None:
                pose, sigma_yaw = (pose[0], pose[1], theta0), math.radians(3.0)
        self._spread(pose, sigma_xy, sigma_yaw)

    def update(self, grey: np.ndarray, motion: tuple[float, float, float] | None,
               dt_s: float) -> LocalResult:
        """One frame: ``grey`` the panorama (with wrap margin), ``motion`` the odometry
        increment since the last frame (None: unknown, the particles only spread)."""
        assert self.estimate is not None, "start() first"
        f = self.filter
        f.resample()  # §8.1.3 step 1
        if motion is None:  # no odometry: motion unknown, spread as for a fast step
            f.predict((0.0, 0.0, 0.0), dt_s)
            f.particles[:, :2] += f.rng.normal(0.0, 0.05, (len(f.particles), 2))
        else:
            f.predict(motion, dt_s)  # step 2
        predicted = self._predicted_pose(motion)
        sigma = self.estimate.covariance
        spread = 3.0 * (math.sqrt(max(sigma[2, 2], 0.0))  # rad: yaw, plus xy as if 1 m off
                        + math.sqrt(max(sigma[0, 0] + sigma[1, 1], 0.0)))
        radius = self.settings.search_cols + int(math.ceil(spread * self.width
                                                           / (2 * math.pi)))
        found = self._track(grey, predicted, min(radius, self.width // 2 - TEMPLATE))
        # Rows follow the landmarks (their elevation changes with distance) while tracked.
        self.rows = np.where(found.scores >= self.settings.min_ncc, found.rows, self.rows)
        kept = self._scale_kept(predicted)
        return self._weigh(found, kept * self._innovation_gate(found, predicted, kept))

    def start_anywhere(self, grey: np.ndarray, radius_m: float,
                       centre: tuple[float, float] = (0.0, 0.0)) -> LocalResult:
        """Position in the place from nothing (§9.3.2 recovery over the whole place, and
        global relocalisation's pick): particles over ``radius_m`` around ``centre`` (the
        reference, or where a path of transitions puts the robot),
        each turned to the orientation on which its position and the landmarks' bearings
        (searched over the whole panorama) agree — eq. 8.34 per particle, with the
        landmarks' positions instead of the reference bearings — then weighed by this
        frame's observation, so the estimate is this frame's posterior."""
        s = self.settings
        found = self._track(grey, (0.0, 0.0, 0.0), radius=self.width // 2 - TEMPLATE)
        bearings = column_to_bearing_of_centre(found.cols, self.width)
        f = self.filter
        f.initialise((centre[0], centre[1], 0.0), radius_m, math.pi)
        good = found.scores >= s.orientation_ncc
        if good.sum() >= 3:
            mean = self.geometry.mean[good]
            towards = np.arctan2(mean[None, :, 1] - f.particles[:, 1:2],
                                 mean[None, :, 0] - f.particles[:, 0:1])
            f.particles[:, 2] = _robust_circular_mean(towards - bearings[None, good])
            f.particles[:, 2] += f.rng.normal(0.0, math.radians(2.0), len(f.particles))
        return self._weigh(found, np.ones(len(bearings)))

    def _weigh(self, found: Track, kept: np.ndarray) -> LocalResult:
        """Weigh the particles with this frame's tracked landmarks (``kept``: 1 for the
        landmarks to use) and take the estimate and its confidence."""
        f = self.filter
        bearings = column_to_bearing_of_centre(found.cols, self.width)
        weights = ncc_weights(found.scores, self.settings.min_ncc) * kept
        sigma_bearing = self._bearing_sigma(found.scores)
        likelihood = self.model(f.particles, bearings, sigma_bearing, self.geometry)
        f.weigh(combine(likelihood, weights, self.settings.outlier_floor))
        self.estimate = f.estimate()
        at_estimate = self.model(np.array([self.estimate.pose]), bearings, sigma_bearing,
                                 self.geometry)[0]
        self.confidence = raw_output(at_estimate, weights)
        # How much of the place is seen where the estimate expects it: every landmark
        # usable from here counted, seen or not (a kidnapped robot sees few, and fits
        # those few well); NaN with fewer than ``evidence_landmarks`` usable: no evidence
        # either way (leaving a place, on odometry; and a few landmarks fitted well are
        # found in wrong modes metres off, where the rest are out of range).
        usable = float(kept.sum())
        self.support = float((at_estimate * weights).sum() / usable) \
            if usable >= self.settings.evidence_landmarks else math.nan
        return LocalResult(self.estimate, self.confidence, self.support)

    def move_to(self, pose: tuple[float, float, float], covariance: np.ndarray) -> None:
        """Redistribute the particles around ``pose`` (a pose passed in from another
        place through a transition, §8.2)."""
        sigma_xy = float(np.clip(math.sqrt(max(covariance[0, 0] + covariance[1, 1], 0.0) / 2),
                                 0.03, 0.5))
        sigma_yaw = float(np.clip(math.sqrt(max(covariance[2, 2], 0.0)), 0.02, 0.3))
        self._spread(pose, sigma_xy, sigma_yaw)

    def _spread(self, pose: tuple[float, float, float], sigma_xy: float, sigma_yaw: float
                ) -> None:
        """Particles ~ N(pose, σ), and the estimate that says so until the next frame."""
        self.filter.initialise(pose, sigma_xy, sigma_yaw)
        self.estimate = Estimate(pose, np.diag([sigma_xy**2, sigma_xy**2, sigma_yaw**2]), 1.0)

    def _bearing_sigma(self, ncc: np.ndarray) -> np.ndarray:
        """A tracked bearing's std: ``bearing_sigma_deg`` at NCC 1, growing as it falls."""
        return math.radians(self.settings.bearing_sigma_deg) * (
            1.0 + 10.0 * (1.0 - np.clip(ncc, 0.0, 1.0)))

    def _innovation_gate(self, found: Track, pose: tuple[float, float, float],
                         kept: np.ndarray) -> np.ndarray:
        """1 for the landmarks found within ``innovation_gate`` standard deviations of
        where the predicted pose expects them, else 0 — an innovation gate, as an EKF
        keeps: a landmark coming into range near a place (its scale now close enough)
        whose template locks onto a look-alike 15-20° off, or whose depth from the
        cross is off, would pull the estimate by decimetres. σ² = σ_bearing² (by NCC)
        + σ_θ² + (σ_xy² + σ_landmark²) / range². When fewer than half of the found
        landmarks pass, the estimate itself is in doubt: nothing is gated."""
        s = self.settings
        if s.innovation_gate <= 0 or self.estimate is None:
            return np.ones(len(kept))
        g = self.geometry
        dx, dy = g.mean[:, 0] - pose[0], g.mean[:, 1] - pose[1]
        expected = np.arctan2(dy, dx) - pose[2]
        bearings = column_to_bearing_of_centre(found.cols, self.width)
        residual = np.abs(np.asarray(wrap_angle(bearings - expected)))
        cov = self.estimate.covariance
        range2 = np.maximum(dx * dx + dy * dy, 0.01)
        var = self._bearing_sigma(found.scores) ** 2 + max(cov[2, 2], 0.0) + (
            max(cov[0, 0] + cov[1, 1], 0.0) / 2 + np.trace(g.covariance, axis1=1, axis2=2) / 2
        ) / range2
        passed = (residual <= s.innovation_gate * np.sqrt(var)).astype(float)
        found_here = (found.scores >= s.min_ncc) & (kept > 0)
        if (passed * found_here).sum() < 0.5 * found_here.sum():
            return np.ones(len(kept))
        return passed

    def _scale_kept(self, pose: tuple[float, float, float]) -> np.ndarray:
        """1 for landmarks that appear at most ``max_zoom`` times larger or smaller than
        in the reference (reference depth over current distance), else 0: a fixed-size
        template on a landmark seen at another scale slides off its point and still
        matches well (as in Turn Back and Look, design §3)."""
        g = self.geometry
        now = np.hypot(g.mean[:, 0] - pose[0], g.mean[:, 1] - pose[1])
        zoom = g.depth / np.maximum(now, 1e-3)
        limit = math.log(self.settings.max_zoom)
        return (np.abs(np.log(zoom)) <= limit).astype(float)

    def _predicted_pose(self, motion: tuple[float, float, float] | None
                        ) -> tuple[float, float, float]:
        """The last estimate moved by the odometry increment (robot frame)."""
        assert self.estimate is not None
        if motion is None:
            return self.estimate.pose
        return SE2.of(self.estimate.pose).compose(SE2.of(motion)).as_tuple()

    def _track(self, grey: np.ndarray, pose: tuple[float, float, float], radius: int
               ) -> Track:
        g = self.geometry
        cols = np.array([predict_column(float(b), float(min(d, 50.0)), pose, self.width)
                         for b, d in zip(g.bearing, g.depth, strict=True)])
        return track(grey, self.margin, self.templates, cols, self.rows, radius,
                     self.settings.search_rows)


def _robust_circular_mean(angles: np.ndarray, tolerance: float = math.radians(10.0)
                          ) -> np.ndarray:
    """(N,) per row of (N, M) angles: the circular mean, then the mean again of those
    within ``tolerance`` of it (a mis-associated landmark moves it little)."""
    first = np.arctan2(np.sin(angles).mean(axis=1), np.cos(angles).mean(axis=1))
    near = np.abs(np.asarray(wrap_angle(angles - first[:, None]))) <= tolerance
    sin = np.where(near, np.sin(angles), 0.0).sum(axis=1)
    cos = np.where(near, np.cos(angles), 0.0).sum(axis=1)
    return np.where(near.any(axis=1), np.arctan2(sin, cos), first)
