"""A pose that says ``tracking`` is right or says how unsure it is (issue 31): driven off
the map on odometry alone, then carried off, the localiser went on publishing
``tracking`` far from the truth with confidence 0 for as long as the run lasted (with
``blind_m = 0``, the thesis's rule alone, this run: tracking all 270 frames off the map
and wrong on 70 of 70 after the kidnap). Now ``blind_m`` of travel with no evidence is a
loss, and no frame after the kidnap says ``tracking`` wrongly.

Lock-step: the office corridor's places a, b, c (x = 3, 4.5, 6 m); the robot starts at
c, is driven 8 m on past the map's end, then carried to x = 25 m and driven on."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from daemon.localisation.localiser import Belief
from tests.conftest import OfficeMap, run_at
from tools.eval.lockstep import Run


def _wrong(run: Run, belief: Belief) -> bool:
    """Published tracking, off by more than 0.5 m and three published sigmas (the truth
    read now: call it on the frame just processed)."""
    if belief.state != "tracking" or belief.covariance is None:
        return False
    error = run.error_m(belief)
    sigma = math.sqrt(max(belief.covariance[0], belief.covariance[4]))
    return error is not None and error > max(0.5, 3 * sigma)


@pytest.mark.timeout(600)
def test_odometry_alone_is_a_loss_and_a_kidnap_is_never_tracked(
        tmp_path: Path, office_map: OfficeMap) -> None:
    with run_at(tmp_path, office_map, "c") as (run, refs):
        run.references = {p.id: refs[p.label] for p in run.mapper.graph.places}
        run.restart_localiser()
        for _ in range(100):
            _, belief = run.step()
            if belief.state == "tracking":
                break
        assert belief.state == "tracking", belief.reason
        off_map = [(b, _wrong(run, b)) for b in run.drive(8.0, 0.0, 0.0, 0.3)]
        # Somewhere past the map's end the evidence ran out: declared lost there.
        lost = [i for i, (b, _) in enumerate(off_map) if b.event is not None
                and b.event.kind == "lost"]
        assert lost, [b.reason for b, _ in off_map[-3:]]
        assert off_map[-1][0].state != "tracking", off_map[-1][0].reason
        run.robot.kidnap(25.0, 10.0, 0.0)
        after = [(b, _wrong(run, b)) for b in run.drive(2.0, 0.0, 0.0, 0.3)]
        wrong_before = sum(w for _, w in off_map)
        wrong_after = sum(w for _, w in after)
    print(f"lost {len(off_map) - lost[0]} frames before the end of the 8 m; tracking wrong "
          f"{wrong_before} of {len(off_map)} frames off the map, {wrong_after} of "
          f"{len(after)} after the kidnap")
    assert wrong_after == 0 and wrong_before == 0
