"""Sensor models of local positioning (design §7, thesis §8.1.4): how likely a particle's
pose makes the bearings at which the current place's landmarks are tracked now.

One interface, three models (:data:`MODELS`): each takes the particles ``(N, 3)`` (x, y, θ
in the place frame), the tracked bearings ``(M,)`` (robot frame) and returns the
likelihood of each landmark's observation from each particle, ``(N, M)`` in [0, 1] — 1 at
the best pose. :func:`combine` weighs them by NCC and combines them robustly.

Geometry: landmark m was seen from the place's reference pose at bearing γ_m and depth d_m
(Turn Back and Look, §4.6), so it stands at μ_m = d_m (cos γ_m, sin γ_m) with the 2 x 2
covariance J Σ_(d,γ) Jᵀ, J = ∂μ/∂(d, γ). A particle p = (x, y, θ) that sees it at bearing
φ casts the ray p + t u, u = (cos(θ + φ), sin(θ + φ)), t > 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np

from daemon.localisation.settings import LocalisationSettings
from daemon.vision.landmarks import LandmarkSet

# Rays closer than this to parallel do not intersect usefully (thesis Figure 8.10).
PARALLEL_SIN = math.sin(math.radians(2.0))


@dataclass(frozen=True)
class LandmarkGeometry:
    """A place's landmarks in its reference frame (the inputs of every model)."""

    bearing: np.ndarray  # (M,) γ, reference bearing
    depth: np.ndarray  # (M,) d (far_depth where TBL found none)
    depth_sigma: np.ndarray  # (M,) std of d
    mean: np.ndarray  # (M, 2) μ
    covariance: np.ndarray  # (M, 2, 2) of μ

    @classmethod
    def of(cls, landmarks: LandmarkSet, far_depth: float) -> LandmarkGeometry:
        gamma = np.array([lm.bearing for lm in landmarks.landmarks], dtype=float)
        depth = np.array([lm.depth for lm in landmarks.landmarks], dtype=float)
        cov = np.array([lm.covariance for lm in landmarks.landmarks], dtype=float
                       ).reshape(-1, 2, 2)
        var_d = cov[:, 0, 0].copy()
        var_g = cov[:, 1, 1].copy()
        cov_dg = cov[:, 0, 1].copy()
        unknown = ~np.isfinite(depth) | (depth <= 0.0) | (depth > far_depth) \
            | ~np.isfinite(var_d)
        depth[unknown] = far_depth  # as far as it is uncertain
        var_d[unknown] = far_depth**2
        cov_dg[unknown | ~np.isfinite(cov_dg)] = 0.0
        var_g[~np.isfinite(var_g)] = math.radians(1.0) ** 2
        c, s = np.cos(gamma), np.sin(gamma)
        # μ = d (cos γ, sin γ);  J = [[cos γ, −d sin γ], [sin γ, d cos γ]];  Σ_μ = J Σ Jᵀ
        J = np.stack([np.stack([c, -depth * s], -1), np.stack([s, depth * c], -1)], -2)
        S = np.stack([np.stack([var_d, cov_dg], -1), np.stack([cov_dg, var_g], -1)], -2)
        cov_xy = J @ S @ np.transpose(J, (0, 2, 1))
        return cls(gamma, depth, np.sqrt(var_d), np.stack([depth * c, depth * s], -1), cov_xy)


class SensorModel(Protocol):
    def __call__(self, particles: np.ndarray, bearings: np.ndarray, sigma_bearing: np.ndarray,
                 lm: LandmarkGeometry) -> np.ndarray:
        """(N, M) likelihood of each observation from each particle, in [0, 1]."""


def _rays(particles: np.ndarray, bearings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray directions (N, M, 2) and origins (N, 1, 2) in the place frame."""
    angle = particles[:, 2:3] + bearings[None, :]  # θ + φ
    return np.stack([np.cos(angle), np.sin(angle)], -1), particles[:, None, :2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _line_intersection(particles: np.ndarray, bearings: np.ndarray, lm: LandmarkGeometry,
                       depth: np.ndarray, sigma: np.ndarray, sigma_bearing: np.ndarray
                       ) -> np.ndarray:
    """Both line-intersection models (§8.1.4, eqs. 8.13-8.16): the depth t_ref at which the
    current ray meets the reference ray γ, scored by a Gaussian around ``depth``."""
    u, p = _rays(particles, bearings)
    r = np.stack([np.cos(lm.bearing), np.sin(lm.bearing)], -1)[None, :, :]  # reference ray
    denom = _cross(r, u)  # sin of the angle between the rays
    # p + s u = t_ref r  →  t_ref = (p × u) / (r × u),  s = (p × r) / (r × u)   (eq. 8.14)
    safe = np.where(np.abs(denom) < 1e-12, 1e-12, denom)
    t_ref = _cross(p, u) / safe
    s = _cross(p, r) / safe
    crossing = np.exp(-0.5 * ((t_ref - depth) / sigma) ** 2)  # eq. 8.13 / 8.16, peak 1
    crossing = np.where((t_ref > 0.0) & (s > 0.0), crossing, 0.0)
    # Near-parallel rays (Figure 8.10): the intersection is undefined or far off. Our
    # alternative (eq. 8.16 is lost in the thesis's text): the landmark at its depth must lie
    # on the current ray, within the bearing noise at that range and the depth spread
    # across it.
    mu = depth[None, :, None] * r  # (1, M, 2)
    off = mu - p
    along = np.einsum("nmk,nmk->nm", off, u)
    lateral = _cross(u, off)
    spread = np.hypot(sigma * np.abs(denom), sigma_bearing * np.maximum(along, 0.0)) + 1e-6
    parallel = np.where(along > 0.0, np.exp(-0.5 * (lateral / spread) ** 2), 0.0)
    return np.where(np.abs(denom) < PARALLEL_SIN, parallel, crossing)


class AssumedDepth:
    """Every landmark at one assumed depth (thesis: the model without TBL's depths)."""

    def __init__(self, settings: LocalisationSettings) -> None:
        self.depth, self.sigma = settings.assumed_depth_m, settings.assumed_depth_sigma_m

    def __call__(self, particles: np.ndarray, bearings: np.ndarray, sigma_bearing: np.ndarray,
                 lm: LandmarkGeometry) -> np.ndarray:
        m = len(lm.bearing)
        return _line_intersection(particles, bearings, lm, np.full(m, self.depth),
                                  np.full(m, self.sigma), sigma_bearing)


class EstimatedDepth:
    """The EKF's depth and its std per landmark (§8.1.4, estimated depth)."""

    def __init__(self, settings: LocalisationSettings) -> None:
        self.floor = 0.02  # m: no depth is known better than this

    def __call__(self, particles: np.ndarray, bearings: np.ndarray, sigma_bearing: np.ndarray,
                 lm: LandmarkGeometry) -> np.ndarray:
        return _line_intersection(particles, bearings, lm, lm.depth,
                                  np.maximum(lm.depth_sigma, self.floor), sigma_bearing)


class EllipsoidLine:
    """The landmark as its uncertainty ellipse; the observation's likelihood is the highest
    value of the landmark's 2-D Gaussian along the particle's ray (§8.1.4, eqs. 8.18-8.33).

    The thesis finds it in three steps: map the ellipse to the unit circle, intersect the
    ray with it, and search the Gaussian along the chord. In closed form: the Gaussian's
    maximum along a line is exp(−m²/2), m the Mahalanobis distance from μ to the line,
    m² = (n · (μ − p))² / (nᵀ Σ n), n ⟂ u. The ellipse is ``gate_sigma`` standard deviations
    wide; a ray that misses it (m > gate) or points away from the landmark scores 0
    (eq. 8.33). Beyond the thesis, the current bearing's own noise (σ_φ at range r, across
    the ray) widens Σ: nᵀ Σ n + (r σ_φ)² — the ellipsoid-arc model the thesis proposed but
    found too costly (Figure 8.23), at no extra cost here."""

    def __init__(self, settings: LocalisationSettings) -> None:
        self.gate = settings.gate_sigma

    def __call__(self, particles: np.ndarray, bearings: np.ndarray, sigma_bearing: np.ndarray,
                 lm: LandmarkGeometry) -> np.ndarray:
        out = np.empty((len(particles), len(bearings)))
        S = lm.covariance
        _ellipsoid_line(np.ascontiguousarray(particles, dtype=np.float64),
                        np.cos(bearings), np.sin(bearings), lm.mean[:, 0].copy(),
                        lm.mean[:, 1].copy(), S[:, 0, 0].copy(), S[:, 0, 1].copy(),
                        S[:, 1, 1].copy(), np.asarray(sigma_bearing, float) ** 2,
                        self.gate**2, out)
        return out


@numba.njit(cache=True, nogil=True, fastmath=True)
def _ellipsoid_line(particles: np.ndarray, cos_b: np.ndarray, sin_b: np.ndarray,
                    mx: np.ndarray, my: np.ndarray, s00: np.ndarray, s01: np.ndarray,
                    s11: np.ndarray, sigma2: np.ndarray, gate2: float, out: np.ndarray
                    ) -> None:  # pragma: no cover (compiled)
    """EllipsoidLine for every particle n and landmark m (one pass, no N x M temporaries)."""
    for n in range(particles.shape[0]):
        x, y = particles[n, 0], particles[n, 1]
        ct, st = np.cos(particles[n, 2]), np.sin(particles[n, 2])
        for m in range(mx.shape[0]):
            ux = ct * cos_b[m] - st * sin_b[m]  # u = (cos(θ + φ), sin(θ + φ))
            uy = st * cos_b[m] + ct * sin_b[m]
            ox, oy = mx[m] - x, my[m] - y  # μ − p
            lateral = ux * oy - uy * ox  # n · (μ − p), n = (−u_y, u_x)
            along = ux * ox + uy * oy  # ahead when > 0
            nsn = s00[m] * uy * uy - 2.0 * s01[m] * ux * uy + s11[m] * ux * ux  # nᵀ Σ n
            m2 = lateral * lateral / (nsn + (ox * ox + oy * oy) * sigma2[m] + 1e-12)
            out[n, m] = np.exp(-0.5 * m2) if (m2 <= gate2 and along > 0.0) else 0.0


MODELS: dict[str, type[AssumedDepth] | type[EstimatedDepth] | type[EllipsoidLine]] = {
    "assumed": AssumedDepth, "estimated": EstimatedDepth, "ellipsoid": EllipsoidLine}


def make_model(settings: LocalisationSettings) -> SensorModel:
    return MODELS[settings.sensor_model](settings)


def ncc_weights(ncc: np.ndarray, min_ncc: float) -> np.ndarray:
    """w_m = (c_m − c_min) / (1 − c_min), clipped to [0, 1]: a landmark counts as much as it
    matched (eq. 8.10: the probability times the template's correlation)."""
    return np.clip((np.asarray(ncc, dtype=float) - min_ncc) / (1.0 - min_ncc), 0.0, 1.0)


def combine(likelihood: np.ndarray, weights: np.ndarray, floor: float) -> np.ndarray:
    """log w_n = Σ_m w_m log(ε + (1 − ε) p_nm)   (N,) — the product of eq. 8.12 made robust:
    a landmark that sees nothing where the particle expects it (occluded, mis-associated)
    lowers the particle's weight by at most a factor ε^w, not to zero."""
    out = np.empty(likelihood.shape[0])
    _combine(np.ascontiguousarray(likelihood, dtype=np.float64),
             np.asarray(weights, dtype=np.float64), floor, out)
    return out


@numba.njit(cache=True, nogil=True, fastmath=True)
def _combine(likelihood: np.ndarray, weights: np.ndarray, floor: float, out: np.ndarray
             ) -> None:  # pragma: no cover (compiled)
    for n in range(likelihood.shape[0]):
        total = 0.0
        for m in range(likelihood.shape[1]):
            total += weights[m] * np.log(floor + (1.0 - floor) * likelihood[n, m])
        out[n] = total


def raw_output(likelihood_row: np.ndarray, weights: np.ndarray) -> float:
    """The sensor model's raw output at one pose: Σ w_m p_m / Σ w_m in [0, 1] (design §9:
    loss detection watches it; published as the pose's confidence)."""
    total = float(weights.sum())
    return float((likelihood_row * weights).sum() / total) if total > 0.0 else 0.0
