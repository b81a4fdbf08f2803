"""Local positioning speed figures (design §7).

cycle_ms: one whole ``Localiser.process_frame`` while tracking — unwarp, landmark tracking,
the particle filter update with 2000 particles, and whatever recognition that frame runs
(every 5th: the current place and its neighbour) — median over the frames of a drive
between two learned places (the simulator in lock-step; rendering is not timed).
cycle_ms_recognising: the median over the frames that ran recognition alone.
pf_update_ms_N: one filter update with N particles and 16 landmarks (resample, predict,
ellipsoid-line sensor model, robust combination, estimate), median.
"""

from __future__ import annotations

import math
import time

import numpy as np

from daemon.localisation.particle_filter import ParticleFilter
from daemon.localisation.sensor_models import EllipsoidLine, LandmarkGeometry, combine
from daemon.localisation.settings import LocalisationSettings
from tools.bench.timing import median_seconds
from tools.eval.lockstep import Run, lockstep_config

PARTICLES = (500, 2000, 8000)


def _geometry(rng: np.random.Generator, n: int = 16) -> LandmarkGeometry:
    bearing = np.sort(rng.uniform(-math.pi, math.pi, n))
    depth = rng.uniform(1.0, 5.0, n)
    c, s = np.cos(bearing), np.sin(bearing)
    cov = np.array([np.diag([0.05**2, 0.01**2]) for _ in range(n)])
    J = np.stack([np.stack([c, -depth * s], -1), np.stack([s, depth * c], -1)], -2)
    return LandmarkGeometry(bearing, depth, np.full(n, 0.05), np.stack([depth * c,
                                                                         depth * s], -1),
                            J @ cov @ np.transpose(J, (0, 2, 1)))


def pf_update_ms(particles: int, repeats: int) -> float:
    rng = np.random.default_rng(0)
    settings = LocalisationSettings(particles=particles)
    lm = _geometry(rng)
    pf = ParticleFilter(settings, rng)
    pf.initialise((0.1, 0.0, 0.0), 0.1, 0.05)
    model = EllipsoidLine(settings)
    bearings = np.arctan2(lm.mean[:, 1], lm.mean[:, 0] - 0.1)
    sigma = np.full(len(bearings), math.radians(2.0))
    weights = np.ones(len(bearings))

    def update() -> None:
        pf.resample()
        pf.predict((0.02, 0.0, 0.0), 0.1)
        pf.weigh(combine(model(pf.particles, bearings, sigma, lm), weights, 0.02))
        pf.estimate()

    return median_seconds(update, repeats=repeats, inner=20) * 1e3


def cycle_ms(repeats: int) -> tuple[float, float]:
    cfg = lockstep_config(1, world="generate:office:1", start_pose=(3.0, 10.0, 0.0))
    with Run(cfg) as r:
        first = r.learn("a")
        for _ in r.drive(1.5, 0.0, 0.0, 0.3):
            pass
        r.learn("b")  # tracking starts at its reference
        r.process_s.clear()
        recognising = []
        for _ in range(max(1, repeats // 4)):
            for sign in (-1.0, 1.0):
                for belief in r.drive(sign * 1.5, 0.0, 0.0, 0.3):
                    if belief.scores:
                        recognising.append(r.process_s[-1])
                    assert belief.state == "tracking", belief.reason
        assert first.id == 1
        return float(np.median(r.process_s)) * 1e3, float(np.median(recognising)) * 1e3


def run(repeats: int) -> dict[str, float]:
    t0 = time.perf_counter()
    figures = {f"pf_update_ms_{n}": round(pf_update_ms(n, repeats), 3) for n in PARTICLES}
    cycle, recognising = cycle_ms(repeats)
    figures["cycle_ms"] = round(cycle, 3)
    figures["cycle_ms_recognising"] = round(recognising, 3)
    figures["localisation_bench_s"] = round(time.perf_counter() - t0, 1)
    return figures
