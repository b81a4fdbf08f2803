"""How the daemon joins a place being learned to the last one (design §6): the odometry
between the two reference poses, fused with the localiser's estimate when the two agree,
and never with an estimate the odometry contradicts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from daemon.mapping.settings import OdometryNoiseSettings
from daemon.service.mapper import Mapper
from daemon.store.sqlite_store import MapStore
from kernel.se2 import SE2, UncertainSE2
from kernel.types import Odometry
from tests.map_fixtures import synthetic_place


def _driven(mapper: Mapper, metres: float) -> Odometry:
    """Learn a place at the odometry origin, then drive ``metres`` along x at 50 Hz."""
    start = Odometry(0.0, 0.0, 0.0, 1_000_000_000, 0)
    mapper.begin_place(start)
    mapper.add_place(synthetic_place(np.random.default_rng(1), "dock"), None)
    samples = [Odometry(metres * k / 100, 0.0, 0.0, start.stamp_ns + k * 20_000_000, k)
               for k in range(1, 101)]
    mapper.on_odometry(samples)
    return samples[-1]


def test_a_seen_pose_agreeing_with_odometry_is_fused_one_it_contradicts_is_not(
        tmp_path: Path) -> None:
    with MapStore.open(tmp_path / "map.db", "abc123") as store:
        mapper = Mapper(store, OdometryNoiseSettings())
        here = _driven(mapper, 2.0)
        alone = mapper.begin_place(here)
        assert alone is not None and alone.source == "odometry"
        assert alone.T_from_new.mean.x == 2.0
        near = UncertainSE2(SE2(2.03, 0.01, 0.0), np.diag([0.02, 0.02, 0.01]) ** 2)
        fused = mapper.begin_place(here, (1, near))
        assert fused is not None and fused.source == "vision"
        assert 2.0 < fused.T_from_new.mean.x < 2.03
        assert fused.T_from_new.covariance[0, 0] < alone.T_from_new.covariance[0, 0]
        # Confident and 3 m / 160° away (a tracker locked onto a wrong mode): refused.
        wrong = UncertainSE2(SE2(-1.0, 0.5, 2.8), np.diag([0.02, 0.02, 0.01]) ** 2)
        kept = mapper.begin_place(here, (1, wrong))
        assert kept is not None and kept.source == "odometry"
        assert kept.T_from_new.mean == alone.T_from_new.mean
