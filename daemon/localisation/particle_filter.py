"""The particle filter of local positioning (design §7, thesis §8.1.3: Condensation).

Particles are one ``(N, 3)`` array of (x, y, θ) in the current place's reference frame,
with log-weights ``(N,)``. Each frame: resample by the last weights (systematic, keeping
every particle whose weight exceeds mean + variance, the thesis's rule), predict with the
motion model, weigh with the sensor model. The estimate is the weighted mean of the
dominant mode, not the single best particle the thesis took, with its 3 x 3 covariance.
Plain functions for each step; :class:`ParticleFilter` holds the state. No global random
state: an ``np.random.Generator`` is passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from daemon.localisation import motion_model
from daemon.localisation.settings import LocalisationSettings


def normalise(log_weights: np.ndarray) -> np.ndarray:
    """w_i = exp(l_i − max l) / Σ exp(l_j − max l)."""
    w = np.exp(log_weights - log_weights.max())
    return np.asarray(w / w.sum())


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn at the N evenly spaced positions (u + i) / N, u ~ U[0, 1), along the
    cumulative weights: every particle with weight w gets ⌊N w⌋ or ⌈N w⌉ copies."""
    n = len(weights)
    positions = (rng.random() + np.arange(n)) / n
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0  # guard against rounding
    return np.searchsorted(cumulative, positions)


def resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling plus the thesis's keep rule (§8.1.3): a particle whose weight
    exceeds mean + variance of the weights survives at least once."""
    indices = systematic_resample(weights, rng)
    keep = np.flatnonzero(weights > weights.mean() + weights.var())
    missing = keep[np.bincount(indices, minlength=len(weights))[keep] == 0]
    if len(missing):  # replace random draws by the missing ones
        slots = rng.choice(len(indices), size=len(missing), replace=False)
        indices[slots] = missing
    return indices


@dataclass(frozen=True)
class Estimate:
    pose: tuple[float, float, float]  # (x, y, θ) in the place frame
    covariance: np.ndarray  # (3, 3) of (x, y, θ)
    mode_share: float  # the weight the dominant mode holds (1: unimodal)


def weighted_covariance(particles: np.ndarray, weights: np.ndarray, mean: np.ndarray
                        ) -> np.ndarray:
    """Σ = Σ_i w_i e_i e_iᵀ, e_i = particle − mean, θ wrapped."""
    w = weights / weights.sum()
    e = particles - mean
    e[:, 2] = np.mod(e[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    return np.asarray((e * w[:, None]).T @ e)


def dominant_mode(particles: np.ndarray, weights: np.ndarray, radius_m: float = 0.3,
                  radius_yaw: float = 0.3, steps: int = 3) -> Estimate:
    """The weighted mean of the particles near the heaviest particle, refined by a few
    mean-shift steps (particles within ``radius`` of the current mean), with their
    weighted covariance."""
    mean = particles[int(np.argmax(weights))].copy()
    near = np.ones(len(particles), bool)
    c, s = np.cos(particles[:, 2]), np.sin(particles[:, 2])
    cos_radius = math.cos(radius_yaw)
    for _ in range(steps):
        # |θ − θ̄| <= r  ⇔  cos(θ − θ̄) >= cos r
        near = ((particles[:, 0] - mean[0]) ** 2 + (particles[:, 1] - mean[1]) ** 2
                <= radius_m**2) & (c * math.cos(mean[2]) + s * math.sin(mean[2]) >= cos_radius)
        if not near.any():
            break
        w = weights[near]
        total = w.sum()
        mean = np.array([w @ particles[near, 0] / total, w @ particles[near, 1] / total,
                         math.atan2(float(w @ s[near]), float(w @ c[near]))])
    cov = weighted_covariance(particles[near], weights[near], mean)
    cov += np.diag([1e-8, 1e-8, 1e-10])  # never singular
    return Estimate((float(mean[0]), float(mean[1]), float(mean[2])), cov,
                    float(weights[near].sum() / weights.sum()))


class ParticleFilter:
    """The filter's state and its three steps (module docstring)."""

    def __init__(self, settings: LocalisationSettings, rng: np.random.Generator,
                 mount: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """``mount``: T_robot_camera, the particles being the camera's (motion_model)."""
        self.settings = settings
        self.rng = rng
        self.mount = mount
        self.particles = np.zeros((settings.particles, 3))
        self.log_weights = np.zeros(settings.particles)

    def initialise(self, pose: tuple[float, float, float], sigma_xy: float, sigma_yaw: float
                   ) -> None:
        """Particles ~ N(pose, diag(σ_xy², σ_xy², σ_θ²)), equal weights (thesis: 2000
        particles, 0.1 m around the reference, §8.1.5)."""
        n = self.settings.particles
        noise = self.rng.standard_normal((n, 3)) * np.array([sigma_xy, sigma_xy, sigma_yaw])
        self.particles = np.asarray(pose, dtype=float)[None, :] + noise
        self.particles[:, 2] = np.mod(self.particles[:, 2] + math.pi, 2 * math.pi) - math.pi
        self.log_weights = np.zeros(n)

    def resample(self) -> None:
        idx = resample(normalise(self.log_weights), self.rng)
        self.particles = self.particles[idx]
        self.log_weights = np.zeros(len(idx))

    def predict(self, motion: tuple[float, float, float], dt_s: float) -> None:
        motion_model.predict(self.particles, motion, dt_s, self.settings, self.rng, self.mount)

    def weigh(self, log_likelihood: np.ndarray) -> None:
        self.log_weights = self.log_weights + log_likelihood

    @property
    def weights(self) -> np.ndarray:
        return normalise(self.log_weights)

    def estimate(self) -> Estimate:
        return dominant_mode(self.particles, self.weights)
