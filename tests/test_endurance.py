"""A small version of ``placecell-eval endurance`` (issue 31, design §6): the daemon's
pieces left to map on their own along the start of the office tour, twice, through a
kidnap into unmapped space, a kidnap back into mapped space, a restart and an operator's
learn. The full experiment: ``placecell-eval endurance --json`` (README, "Evaluation")."""

from __future__ import annotations

import json

import pytest

from tools.eval.cli import main as eval_main


@pytest.mark.timeout(900)
def test_a_short_endurance_tour_never_gets_stuck(capsys: pytest.CaptureFixture[str]) -> None:
    assert eval_main(["endurance", "--json", "--waypoints", "30", "--restarts", "1",
                      "--mapped-kidnaps", "1", "--unmapped-kidnaps", "1",
                      "--operator-learns", "1"]) == 0
    m = json.loads(capsys.readouterr().out)["metrics"]
    assert m["tour_done"] and m["frames"] > 200, m
    assert m["unmapped_kidnaps"] == 1 and m["mapped_kidnaps"] == 1, m
    # Carried off the map: a place learned there, tracked in it well within 45 s.
    assert m["unmapped_kidnap_tracking_within_s"] is not None, m
    assert m["unmapped_kidnap_tracking_within_s"] <= 45.0, m
    assert m["mapped_kidnap_recovered_within_10"] == 1.0, m
    assert m["segments_final"] == 1, m  # the second lap joined the two
    assert m["duplicate_places"] == 0 and m["learn_failures"] == 0, m  # restart included
    assert m["operator_learns"] == 1 and m["operator_learns_refused"] == 0, m
    assert m["tracking_fraction"] >= 0.9 and m["tracking_wrong_fraction"] <= 0.01, m
    assert m["coverage"] >= 0.95, m
