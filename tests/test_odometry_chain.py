"""A transition's covariance from odometry (daemon/mapping/odometry_chain.py) matches the
spread of odometry runs drawn from the same noise model, random and systematic parts."""

from __future__ import annotations

import math

import numpy as np

from daemon.mapping.odometry_chain import OdometryChain
from daemon.mapping.settings import OdometryNoiseSettings
from kernel.se2 import SE2
from kernel.types import Odometry

NOISE = OdometryNoiseSettings(translation_m_per_sqrt_m=0.02, heading_rad_per_sqrt_m=0.01,
                              scale_sigma=0.02, heading_drift_sigma_rad_per_m=0.03)


def _true_steps() -> list[SE2]:
    """An L-shaped drive: 2 m ahead, a quarter turn, 1.5 m ahead, in 2 cm steps."""
    steps = [SE2(0.02, 0.0, 0.0)] * 100 + [SE2(0.0, 0.0, math.pi / 40)] * 20
    return steps + [SE2(0.02, 0.0, 0.0)] * 75


def _odometry_run(rng: np.random.Generator) -> list[Odometry]:
    """Odometry that reports each true step distorted by the model's errors."""
    s = rng.normal(0, NOISE.scale_sigma)
    b = rng.normal(0, NOISE.heading_drift_sigma_rad_per_m)
    pose, out = SE2(), [Odometry(0.0, 0.0, 0.0, 0, 0)]
    for i, step in enumerate(_true_steps()):
        ds = math.hypot(step.x, step.y)
        # reported = true / (1 - s), heading + b ds, plus the random parts
        w = rng.normal(0, 1, 3) * np.sqrt([ds, ds, ds]) * [
            NOISE.translation_m_per_sqrt_m, NOISE.translation_m_per_sqrt_m,
            NOISE.heading_rad_per_sqrt_m]
        reported = SE2(step.x * (1 + s) + w[0], step.y * (1 + s) + w[1],
                       step.yaw + b * ds + w[2])
        pose = pose.compose(reported)
        out.append(Odometry(pose.x, pose.y, pose.yaw, (i + 1) * 20_000_000, i + 1))
    return out


def test_covariance_matches_the_spread_of_runs() -> None:
    rng = np.random.default_rng(5)
    truth = SE2()
    for step in _true_steps():
        truth = truth.compose(step)
    errors, predicted = [], None
    for _ in range(400):
        run = _odometry_run(rng)
        chain = OdometryChain(run[0], NOISE)
        for sample in run[1:]:
            chain.add(sample)
        rel = chain.relative()
        predicted = rel.covariance
        # the error of the odometry estimate, in the same linearisation
        errors.append([rel.mean.x - truth.x, rel.mean.y - truth.y,
                       math.remainder(rel.mean.yaw - truth.yaw, 2 * math.pi)])
    empirical = np.cov(np.array(errors).T)
    assert predicted is not None
    np.testing.assert_allclose(np.sqrt(np.diag(predicted)), np.sqrt(np.diag(empirical)),
                               rtol=0.2)
    assert abs(chain.distance_m - 3.5) < 0.2


def test_a_gap_in_odometry_breaks_the_chain() -> None:
    chain = OdometryChain(Odometry(0, 0, 0, 0, 0), NOISE)
    chain.add(Odometry(0.1, 0, 0, 100_000_000, 1))
    assert not chain.broken
    chain.add(Odometry(0.2, 0, 0, 2_000_000_000, 2))  # 1.9 s of silence
    assert chain.broken
    assert chain.broken_by is not None and "1.90 s" in chain.broken_by
    chain.break_off("later")
    assert "1.90 s" in chain.broken_by  # the first reason is kept
