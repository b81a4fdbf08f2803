"""The holonomic motion model of the particle filter (design §7, thesis §8.1.3, §8.1.5).

Each particle moves by the odometry increment (dx, dy, dθ), taken in the robot frame, plus
Gaussian noise: translation noise proportional to the distance moved, rotation noise to
the angle turned and to the distance, and noise for the delay between the camera's and the
odometry's sampling (the velocity times the delay's std, §8.1.5 "Implementation issues"),
plus a small constant diffusion so a converged cloud keeps exploring.
"""

from __future__ import annotations

import math

import numpy as np

from daemon.localisation.settings import LocalisationSettings
from kernel.se2 import SE2, compose_many


def motion_sigmas(motion: tuple[float, float, float], dt_s: float,
                  s: LocalisationSettings) -> tuple[float, float]:
    """(σ_xy, σ_θ) for one step of ``motion`` taking ``dt_s``."""
    dx, dy, dtheta = motion
    dist = math.hypot(dx, dy)
    delay = s.delay_sigma_s / max(dt_s, 1e-3)  # the delay as a fraction of the step
    # σ_xy = k_t |Δ| ⊕ (σ_delay / Δt) |Δ| ⊕ σ_diffusion
    sigma_xy = math.sqrt((s.translation_noise * dist) ** 2 + (delay * dist) ** 2
                         + s.diffusion_xy_m**2)
    # σ_θ = k_r |Δθ| ⊕ k_tθ |Δ| ⊕ (σ_delay / Δt) |Δθ| ⊕ σ_diffusion
    sigma_yaw = math.sqrt((s.rotation_noise * dtheta) ** 2 + (s.heading_noise_per_m * dist) ** 2
                          + (delay * dtheta) ** 2 + s.diffusion_yaw_rad**2)
    return sigma_xy, sigma_yaw


def predict(particles: np.ndarray, motion: tuple[float, float, float], dt_s: float,
            s: LocalisationSettings, rng: np.random.Generator,
            mount: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
    """Move ``particles`` (N, 3) in place by ``motion`` in each particle's own frame.

    ``mount``: T_robot_camera (kernel/mount.py). The particles and ``motion`` are then
    the camera's, but the noise arises in the robot's wheels: the camera's increment is
    taken back to the robot's, Δr = M Δc M⁻¹, made noisy there, and each particle moves
    by M⁻¹ Δr' M. A turn in place, which carries the camera along an arc, adds no
    translation noise of its own (the lever arm is rigid)."""
    if mount != (0.0, 0.0, 0.0):
        _predict_mounted(particles, motion, dt_s, s, rng, mount)
        return
    dx, dy, dtheta = motion
    sigma_xy, sigma_yaw = motion_sigmas(motion, dt_s, s)
    n = len(particles)
    noise = rng.standard_normal((n, 3))
    ux = dx + sigma_xy * noise[:, 0]  # the increment as this particle's robot made it
    uy = dy + sigma_xy * noise[:, 1]
    c, sn = np.cos(particles[:, 2]), np.sin(particles[:, 2])
    particles[:, 0] += c * ux - sn * uy  # x' = x + R(θ) u
    particles[:, 1] += sn * ux + c * uy
    particles[:, 2] = np.mod(particles[:, 2] + dtheta + sigma_yaw * noise[:, 2] + math.pi,
                             2.0 * math.pi) - math.pi  # θ' = θ + Δθ + ε, wrapped


def _predict_mounted(particles: np.ndarray, motion: tuple[float, float, float], dt_s: float,
                     s: LocalisationSettings, rng: np.random.Generator,
                     mount: tuple[float, float, float]) -> None:
    """:func:`predict` with the camera at ``mount`` on the robot."""
    inv = SE2(*mount).inverse().as_tuple()
    rx, ry, rt = (float(v) for v in compose_many(compose_many(mount, motion), inv))  # Δr
    sigma_xy, sigma_yaw = motion_sigmas((rx, ry, rt), dt_s, s)
    n = len(particles)
    noise = rng.standard_normal((n, 3))
    noisy = (rx + sigma_xy * noise[:, 0], ry + sigma_xy * noise[:, 1],
             rt + sigma_yaw * noise[:, 2])
    ux, uy, ut = compose_many(compose_many(inv, noisy), mount)  # M⁻¹ Δr' M
    c, sn = np.cos(particles[:, 2]), np.sin(particles[:, 2])
    particles[:, 0] += c * ux - sn * uy
    particles[:, 1] += sn * ux + c * uy
    particles[:, 2] = np.mod(particles[:, 2] + ut + math.pi, 2.0 * math.pi) - math.pi
