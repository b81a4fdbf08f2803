"""Back at a known place the map does not link to (design §6): while mapping, a place
standing ``certain_lead`` above its background is where the robot is — acquisition
watches it and the tracker moves into it, so no new place is learned on top of it.

The office corridor's places "a" (x = 3 m) and "c" (x = 6 m) are known without any
transition between them (a tour's first pass and its way back, the chain between them
too long to trust); the robot starts at c, tracked there, and drives back past a. The
truth (the places' reference poses) stays on the test's side."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from daemon.localisation.acquisition_watch import Tracked, revisitable
from daemon.localisation.known_map import KnownMap, MapHolder
from daemon.localisation.localiser import Localiser
from daemon.mapping.settings import AcquisitionSettings
from daemon.mapping.transition import Transition
from kernel.se2 import SE2, UncertainSE2
from tests.conftest import OfficeMap
from tests.map_fixtures import synthetic_place
from tools.eval.lockstep import Run, lockstep_config

Frames = list[tuple[float, int | None, int | None, int | None]]


def _drive_back_past_a(tmp_path: Path, office_map: OfficeMap, candidates: int
                       ) -> tuple[Frames, dict[str, int]]:
    """Per frame: the true distance to a's reference, the watched place, the tracked
    place, the place the tracker switched from; and the places' ids by label."""
    refs = office_map(tmp_path / "map.db")
    a_ref, c_ref = refs["a"], refs["c"]
    cfg = lockstep_config(1, start_pose=(c_ref.x, c_ref.y, c_ref.yaw))
    # No decision to learn on the 3 m back (min_distance_m): only the revisit is looked at.
    acquisition = AcquisitionSettings(enabled=True, min_distance_m=10.0,
                                      revisit_candidates=candidates)
    with Run(cfg, map_path=tmp_path / "map.db") as run:
        ids = {p.label: p.id for p in run.mapper.graph.places}
        # The localiser knows a and c only: nothing joins them.
        known = KnownMap.of([run.mapper.graph.place(ids["a"]), run.mapper.graph.place(ids["c"])])
        localiser = Localiser(cfg.projection, cfg.panorama, acquisition=acquisition,
                              settings=cfg.localisation, odometry_noise=cfg.odometry,
                              known_map=MapHolder(known))
        localiser.watch_place(ids["c"])
        localiser.set_pose(ids["c"], (0.0, 0.0, 0.0), 0.03, 0.03)
        run.localiser = localiser
        out: Frames = []
        for belief in run.drive(a_ref.x - c_ref.x - 0.4, 0.0, 0.0, 0.3):
            x, y, _ = run.robot.true_pose()
            out.append((math.hypot(x - a_ref.x, y - a_ref.y), belief.recent_place,
                        belief.place_id, belief.switched_from))
        return out, ids


@pytest.mark.timeout(300)
def test_a_known_place_passed_again_is_watched_and_tracked_in(
        tmp_path: Path, office_map: OfficeMap) -> None:
    frames, ids = _drive_back_past_a(tmp_path, office_map, candidates=3)
    a, c = ids["a"], ids["c"]
    first = next(i for i, f in enumerate(frames) if f[1] == a)
    distance, _, tracked, switched_from = frames[first]
    assert distance <= 0.5, f"a taken for the robot's place {distance:.2f} m from it"
    assert tracked == a and switched_from == c
    assert all(f[1] == a and f[2] == a for f in frames[first:])  # kept to the end
    assert all(f[1] == c for f in frames[:first])  # c watched until then


@pytest.mark.timeout(300)
def test_without_the_revisit_check_the_place_passed_again_is_not_seen(
        tmp_path: Path, office_map: OfficeMap) -> None:
    frames, ids = _drive_back_past_a(tmp_path, office_map, candidates=0)
    assert min(f[0] for f in frames) < 0.2  # the robot did pass a
    assert all(f[1] == ids["c"] for f in frames)


def test_a_place_the_map_puts_near_is_left_to_the_switcher() -> None:
    """revisitable: places 1-2-3 in a row 1.5 m apart, 4 linked to nothing. Tracked in 2
    at its reference, a revisit may find 4 only: 1 and 3 are the switcher's (within
    3 m through the map), 2 is tracked, and the watched one is left out; not tracking,
    every place but the watched one may be revisited; 20 m on along the row (the
    estimate far from 1 and 3), 1 and 3 may be again."""
    rng = np.random.default_rng(7)
    places = [dataclasses.replace(synthetic_place(rng, str(k), n=4, width=64, height=24,
                                                  margin=0), id=k) for k in (1, 2, 3, 4)]
    step = UncertainSE2(SE2(1.5, 0.0, 0.0), np.diag([1e-4, 1e-4, 1e-5]))
    known = KnownMap.of(places, [Transition(1, 2, step, "vision"),
                                 Transition(2, 3, step, "vision")])
    assert revisitable(known, 1, Tracked(known, 2, True, (0.0, 0.0, 0.0)), 3.0) == [4]
    assert revisitable(known, 4, Tracked(known, 2, True, (0.0, 0.0, 0.0)), 3.0) == []
    assert revisitable(known, 1, Tracked(known, None, False), 3.0) == [2, 3, 4]
    assert revisitable(known, 4, Tracked(known, 2, True, (20.0, 0.0, 0.0)), 3.0) == [1, 3]
