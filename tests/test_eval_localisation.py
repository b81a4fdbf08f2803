"""Small versions of the local positioning experiments (the full ones: README,
"Evaluation and benchmarks"): they run the daemon's Localiser on the simulated robot in
lock-step and must keep the thesis beaten."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tools.eval.cli import main as eval_main


def _metrics(capsys: pytest.CaptureFixture[str], *args: str) -> dict[str, float]:
    assert eval_main([*args, "--json"]) == 0
    return dict(json.loads(capsys.readouterr().out)["metrics"])


def test_tbl_local_one_cross_beats_the_thesis(capsys: pytest.CaptureFixture[str],
                                             tmp_path: Path) -> None:
    m = _metrics(capsys, "tbl-local", "--crosses", "1", "--plots", str(tmp_path))
    assert m["frames"] > 150
    assert m["mean_error_m"] <= 0.02 and m["p95_error_m"] <= 0.04  # thesis: 30 mm mean
    assert (tmp_path / "tbl-local-path.png").stat().st_size > 1000
