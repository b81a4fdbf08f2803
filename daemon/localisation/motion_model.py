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
    mx, my, mt = mount
    cm, sm = math.cos(mt), math.sin(mt)
    inv = (-cm * mx - sm * my, sm * mx - cm * my, -mt)  # M⁻¹

    def conjugate(a: tuple[float, float, float], x: np.ndarray, y: np.ndarray, t: np.ndarray,
                  b: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """a ∘ (x, y, t) ∘ b for arrays of (x, y, t)."""
        ct, st = np.cos(t), np.sin(t)
        x1, y1, t1 = x + ct * b[0] - st * b[1], y + st * b[0] + ct * b[1], t + b[2]
        ca, sa = math.cos(a[2]), math.sin(a[2])
        return a[0] + ca * x1 - sa * y1, a[1] + sa * x1 + ca * y1, t1 + a[2]

    rx, ry, rt = (float(v[0]) for v in conjugate(mount, np.array([motion[0]]),
                                                  np.array([motion[1]]),
                                                  np.array([motion[2]]), inv))
    sigma_xy, sigma_yaw = motion_sigmas((rx, ry, rt), dt_s, s)
    n = len(particles)
    noise = rng.standard_normal((n, 3))
    ux, uy, ut = conjugate(inv, rx + sigma_xy * noise[:, 0], ry + sigma_xy * noise[:, 1],
                           rt + sigma_yaw * noise[:, 2], mount)
    c, sn = np.cos(particles[:, 2]), np.sin(particles[:, 2])
    particles[:, 0] += c * ux - sn * uy
    particles[:, 1] += sn * ux + c * uy
    particles[:, 2] = np.mod(particles[:, 2] + ut + math.pi, 2.0 * math.pi) - math.pi
