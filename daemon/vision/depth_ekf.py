"""Landmark depth by a bearing-only EKF during Turn Back and Look (docs/design.md §3, thesis §4.6).

State: the robot pose (x, y, θ) relative to the reference pose, then for each landmark
(ρ_i, γ_i): inverse depth and reference bearing. Inverse depth (ρ = 1/d) keeps the
filter honest for far landmarks: a landmark the TBL cross cannot resolve keeps a wide,
nearly Gaussian ρ (d reaching to infinity) instead of a Gaussian in d that claims too much.
Estimates are reported as depth d = 1/ρ, bearing γ and the 2 x 2 covariance of (d, γ)
(first-order: var d = var ρ / ρ⁴).

Observation of landmark i (§4.6):
    φ_i = atan2(d_i sin γ_i − y, d_i cos γ_i − x) − θ + v
        = atan2(sin γ_i − ρ_i y, cos γ_i − ρ_i x) − θ + v          (multiplied through by ρ_i > 0)
    σ² = s ((1 − c) π + π/180)² + (k ln z)²
The first term is the thesis's (§4.6.2: c = NCC score clamped to >= 0.5, a poor match
≈ (π/2)², a perfect one ≈ (1°)²) times s. The second is ours: a fixed-size template matched
on a landmark that now appears z times larger or smaller than when it was cut slides
across it, and it slides the same way frame after frame, so its error does not average
out (k radians per unit of ln z). Calibrated on the simulator (``placecell-eval depth``):
the thesis's term alone cannot be honest both for markers 0.7 m away, whose zoom changes
fast over the cross, and for landmarks 3-6 m away, which it tracks to a tenth of a
degree; scaled to fit the one it is four times too wide or too narrow for the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kernel.angles import wrap_angle
from kernel.se2 import SE2


@dataclass(frozen=True)
class DepthEstimate:
    depth: float  # metres (inf when ρ <= 0: no evidence of a finite depth)
    bearing: float
    covariance: np.ndarray  # (2, 2) of (d, γ)
    inverse_depth: float
    inverse_depth_var: float


def observation_variance(ncc: float) -> float:
    """σ² = ((1 − c) π + π/180)², c clamped to >= 0.5 (§4.6.2)."""
    c = max(0.5, min(1.0, ncc))
    return ((1.0 - c) * math.pi + math.pi / 180.0) ** 2


class BearingOnlyEKF:
    def __init__(self, bearings: np.ndarray, *, initial_depth: float = 2.5,
                 inverse_depth_sigma: float = 0.5, bearing_sigma: float = math.radians(1.0),
                 translation_noise: float = 0.01, rotation_noise: float = 0.10,
                 heading_noise_per_m: float = 0.002, observation_variance_scale: float = 1.0,
                 zoom_noise_rad: float = 0.0) -> None:
        n = len(bearings)
        self.n = n
        self.x = np.zeros(3 + 2 * n)
        self.x[3::2] = 1.0 / initial_depth
        self.x[4::2] = bearings
        self.P = np.zeros((3 + 2 * n, 3 + 2 * n))  # the start pose is known exactly
        self.P[3::2, 3::2][np.diag_indices(n)] = inverse_depth_sigma**2
        self.P[4::2, 4::2][np.diag_indices(n)] = bearing_sigma**2
        self.translation_noise = translation_noise  # std per metre travelled
        self.rotation_noise = rotation_noise  # std per radian turned
        self.heading_noise_per_m = heading_noise_per_m  # heading std gained per metre
        # s and k of the observation noise (module docstring).
        self.observation_variance_scale = observation_variance_scale
        self.zoom_noise_rad = zoom_noise_rad

    @property
    def pose(self) -> tuple[float, float, float]:
        return float(self.x[0]), float(self.x[1]), float(self.x[2])

    def predict(self, dx: float, dy: float, dtheta: float,
                mount: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """Odometry increment in the robot frame; noise proportional to the motion.

        ``mount``: T_robot_camera (kernel/mount.py). The pose and the increment are then
        the camera's, but the noise arises in the robot's wheels: it is taken at the
        robot's increment Δr = M Δc M⁻¹ and carried to the camera's through the lever
        arm (:func:`camera_increment_jacobian`), so a turn in place swings the camera's
        position with the turn's heading error instead of adding translation noise of
        its own (as the localiser's motion model, daemon/localisation/motion_model.py)."""
        x, y, th = self.x[:3]
        c, s = math.cos(th), math.sin(th)
        self.x[0] = x + c * dx - s * dy
        self.x[1] = y + s * dx + c * dy
        self.x[2] = float(wrap_angle(th + dtheta))
        F = np.eye(3)
        F[0, 2] = -s * dx - c * dy
        F[1, 2] = c * dx - s * dy
        if mount == (0.0, 0.0, 0.0):
            Q_increment = self._increment_noise(dx, dy, dtheta)
        else:
            m = SE2(*mount)
            robot = m.compose(SE2(dx, dy, dtheta)).compose(m.inverse()).as_tuple()
            J = camera_increment_jacobian(robot[2], mount)
            Q_increment = J @ self._increment_noise(*robot) @ J.T
        G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        Q = G @ Q_increment @ G.T
        P = self.P
        P[:3, :] = F @ P[:3, :]
        P[:, :3] = P[:, :3] @ F.T
        P[:3, :3] += Q

    def _increment_noise(self, dx: float, dy: float, dtheta: float) -> np.ndarray:
        """Covariance of an increment (dx, dy, dθ) in the frame it starts in: translation
        under translation, rotation under rotation (thesis: 0.01 and 0.10), a little
        rotation under translation."""
        dist = math.hypot(dx, dy)
        q_t = (self.translation_noise * dist) ** 2 + 1e-10
        q_r = (self.rotation_noise * abs(dtheta)) ** 2 + (self.heading_noise_per_m * dist
                                                          ) ** 2 + 1e-10
        return np.diag([q_t, q_t, q_r])

    def update(self, i: int, bearing: float, ncc: float, log_zoom: float = 0.0) -> None:
        """Observation of landmark ``i`` at ``bearing`` (rad) with match score ``ncc``,
        the landmark appearing exp(``log_zoom``) times as large as in the reference."""
        x, y, th = self.x[:3]
        k = 3 + 2 * i
        rho, gamma = self.x[k], self.x[k + 1]
        u = math.cos(gamma) - rho * x
        v = math.sin(gamma) - rho * y
        q = u * u + v * v
        if q < 1e-12:
            return
        predicted = math.atan2(v, u) - th
        innovation = float(wrap_angle(bearing - predicted))
        H = np.zeros(3 + 2 * self.n)
        H[0] = v * rho / q
        H[1] = -u * rho / q
        H[2] = -1.0
        H[k] = (-u * y + v * x) / q
        H[k + 1] = (u * math.cos(gamma) + v * math.sin(gamma)) / q
        R = (observation_variance(ncc) * self.observation_variance_scale
             + (self.zoom_noise_rad * log_zoom) ** 2)
        PH = self.P @ H
        S = float(H @ PH) + R
        K = PH / S
        self.x += K * innovation
        self.x[2] = float(wrap_angle(self.x[2]))
        # Joseph form keeps P symmetric and positive semi-definite.
        IKH = np.eye(len(self.x)) - np.outer(K, H)
        self.P = IKH @ self.P @ IKH.T + np.outer(K, K) * R

    def estimate(self, i: int) -> DepthEstimate:
        k = 3 + 2 * i
        rho, gamma = float(self.x[k]), float(wrap_angle(self.x[k + 1]))
        P = self.P[k:k + 2, k:k + 2]
        if rho <= 1e-6:
            return DepthEstimate(math.inf, gamma, np.array([[math.inf, 0.0], [0.0, P[1, 1]]]),
                                 rho, float(P[0, 0]))
        J = np.array([[-1.0 / rho**2, 0.0], [0.0, 1.0]])  # d(d, γ)/d(ρ, γ)
        return DepthEstimate(1.0 / rho, gamma, J @ P @ J.T, rho, float(P[0, 0]))


def camera_increment_jacobian(robot_turn: float, mount: tuple[float, float, float]
                              ) -> np.ndarray:
    """∂Δc/∂Δr of the camera's increment Δc = M⁻¹ Δr M in the robot's Δr = (t_r, θ_r),
    for the mount M = (m, φ): Δc = (R(−φ) (t_r + R(θ_r) m − m), θ_r), so

        ∂t_c/∂t_r = R(−φ),   ∂t_c/∂θ_r = R(−φ) R(θ_r) m⊥   (m⊥ = (−m_y, m_x)),   ∂θ_c/∂θ_r = 1.
    """
    mx, my, phi = mount
    c, s = math.cos(-phi), math.sin(-phi)
    R_back = np.array([[c, -s], [s, c]])
    ct, st = math.cos(robot_turn), math.sin(robot_turn)
    swing = R_back @ np.array([ct * -my - st * mx, st * -my + ct * mx])
    J = np.eye(3)
    J[:2, :2] = R_back
    J[:2, 2] = swing
    return J
