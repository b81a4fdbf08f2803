"""``placecell-eval --seeds``: one experiment over many world seeds (tools/eval/seeds.py)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import pytest

from tools.eval.cli import main as eval_main
from tools.eval.seeds import parse_seeds, run_seeds, summarise, table


def test_seed_ranges_and_lists_are_read_in_order_each_seed_once() -> None:
    assert parse_seeds("101-105") == [101, 102, 103, 104, 105]
    assert parse_seeds("1-3,7, 2") == [1, 2, 3, 7]
    assert parse_seeds("4") == [4]
    for bad in ("5-3", "a-b", "1-", "", "-2"):
        with pytest.raises(argparse.ArgumentTypeError, match="seeds"):
            parse_seeds(bad)


def test_the_summary_is_mean_min_and_max_over_the_seeds_that_gave_a_value() -> None:
    per_seed = {1: {"rate": 0.5, "n": 3, "none": None, "flag": True},
                2: {"rate": 1.0, "n": 5, "none": None, "flag": False},
                3: {"rate": None, "n": 4, "none": None, "flag": True}}
    s = summarise(per_seed)
    assert s == {"rate_mean": 0.75, "rate_min": 0.5, "rate_max": 1.0,
                 "n_mean": 4.0, "n_min": 3.0, "n_max": 5.0}
    lines = table(per_seed, ["rate", "n"]).splitlines()
    assert lines[0].split() == ["seed", "rate", "n"]
    assert lines[3].split() == ["3", "-", "4"]  # no value: a dash, not a zero
    assert lines[4].split() == ["mean", "0.750", "4.000"]
    assert [line.split()[0] for line in lines[4:]] == ["mean", "min", "max"]


@pytest.mark.parametrize("jobs", [1, 2])
def test_each_seed_runs_with_its_own_world_and_map(tmp_path: Path, jobs: int) -> None:
    args = argparse.Namespace(world_seed=1, map=tmp_path / "tour.db")
    out = run_seeds("tests.seed_probe", args, [2, 3, 4], jobs)
    assert list(out["per_seed"]) == [2, 3, 4]
    assert [m["half"] for m in out["per_seed"].values()] == [1.0, 1.5, 2.0]
    assert out["metrics"]["half_mean"] == 1.5 and out["metrics"]["rate_max"] == 0.5
    assert out["config"]["map"] == str(tmp_path / "tour-seed2.db")
    pids = {m["pid"] for m in out["per_seed"].values()}
    assert (pids == {os.getpid()}) if jobs == 1 else (os.getpid() not in pids)
    assert args.world_seed == 1 and args.map == tmp_path / "tour.db"  # not changed


def test_bad_seed_options_are_refused_by_name(capsys: pytest.CaptureFixture[str],
                                             tmp_path: Path) -> None:
    for argv, named in ((["aliased", "--seeds", "120-101"], "--seeds"),
                        (["tbl-local", "--seeds", "1-2", "--plots", str(tmp_path)], "--seeds"),
                        (["aliased", "--seeds", "1-2", "--jobs", "0"], "--jobs")):
        with pytest.raises(SystemExit) as stopped:
            eval_main(argv)
        assert stopped.value.code == 2 and named in capsys.readouterr().err, argv
