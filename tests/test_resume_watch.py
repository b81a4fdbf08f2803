"""Restarts resume, never re-learn (issue 31, point 2): a localiser started on a map with
places watches the place it is tracked in, with nothing learned at the start; and a
decision whose learn did not happen is asked again, not dropped for good.

The office corridor's places "a", "b", "c" (1.5 m apart) are known; the robot stands at
b's reference. The truth stays on the test's side."""

from __future__ import annotations

from pathlib import Path

import pytest

from daemon.localisation.localiser import Localiser
from daemon.mapping.settings import AcquisitionSettings
from tests.conftest import OfficeMap, run_at
from tools.eval.lockstep import Run


def _resumed_at_b(run: Run, acquisition: AcquisitionSettings) -> tuple[Localiser, dict]:
    ids = {p.label: p.id for p in run.mapper.graph.places}
    cfg = run.cfg
    localiser = Localiser(cfg.projection, cfg.panorama, acquisition=acquisition,
                          settings=cfg.localisation, odometry_noise=cfg.odometry,
                          known_map=run.session.holder)  # the map as stored
    localiser.resume(ids["b"], (0.0, 0.0, 0.0), 0.05, 0.05)  # as the daemon's restart does
    run.localiser = localiser
    return localiser, ids


@pytest.mark.timeout(300)
def test_a_resumed_localiser_watches_its_place_and_asks_for_none(
        tmp_path: Path, office_map: OfficeMap) -> None:
    with run_at(tmp_path, office_map, "b") as (run, _):
        localiser, ids = _resumed_at_b(run, AcquisitionSettings(enabled=True))
        beliefs = [run.step()[1] for _ in range(30)]
    tracking = [i for i, bl in enumerate(beliefs) if bl.state == "tracking"]
    assert tracking, [bl.reason for bl in beliefs[-3:]]
    after = beliefs[tracking[0] + 1:]
    assert after and all(bl.recent_place == ids["b"] for bl in after)
    assert all(bl.acquisition is None for bl in beliefs)  # standing at a place: no learn
    assert all(bl.recent_place is None for bl in beliefs[:tracking[0]])


@pytest.mark.timeout(300)
def test_a_decision_whose_learn_did_not_happen_is_asked_again(
        tmp_path: Path, office_map: OfficeMap) -> None:
    with run_at(tmp_path, office_map, "c") as (run, _):
        # Past c into the corridor nobody mapped: c fades; nothing is known further on.
        localiser, ids = _resumed_at_b(run, AcquisitionSettings(enabled=True,
                                                               min_distance_m=0.5))
        localiser.resume(ids["c"], (0.0, 0.0, 0.0), 0.05, 0.05)
        decisions: list[int] = []
        watched_after: list[int | None] = []
        for belief in run.drive(3.0, 0.0, 0.0, 0.3):
            if decisions and len(watched_after) < 5:
                watched_after.append(belief.recent_place)
            if belief.acquisition is not None:
                decisions.append(belief.acquisition.place_id)
                localiser.learning_not_started()  # the daemon had a job: no learn now
    assert len(decisions) >= 2, decisions  # asked again further on
    assert watched_after and all(w is not None for w in watched_after[1:]), watched_after
