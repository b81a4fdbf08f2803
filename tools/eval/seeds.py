"""``placecell-eval EXPERIMENT --seeds A-B [--jobs N]``: one experiment over many worlds.

A claim made on the seeds a method was tuned on says little about the buildings it will
meet; the claims are made over seeds never used in development (README, "Evaluation and
benchmarks"). Each world seed runs the experiment as ``--world-seed`` would, in its own
process when ``--jobs`` > 1 (worlds are independent; a run is single-threaded), and the
result holds every seed's metrics and, for each numeric metric, its mean, minimum and
maximum over the seeds. ``--map FILE`` keeps one map per seed, ``FILE``'s name with
``-seedN`` added.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import copy
import importlib
import math
import multiprocessing
from pathlib import Path
from typing import Any, TypeGuard


def parse_seeds(text: str) -> list[int]:
    """``"101-120"``, ``"1,3,5"`` or a mix (``"1-3,7"``): the seeds in order, each once."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        lo, dash, hi = part.partition("-")
        try:
            first, last = (int(lo), int(hi)) if dash else (int(part), int(part))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"seeds {text!r}: {part!r} is not a seed or a range A-B of seeds") from None
        if first < 0 or last < first:
            raise argparse.ArgumentTypeError(
                f"seeds {text!r}: {part!r} is not a range A-B with 0 <= A <= B")
        seeds += [s for s in range(first, last + 1) if s not in seeds]
    return seeds


def seed_args(args: argparse.Namespace, seed: int) -> argparse.Namespace:
    """``args`` for one world seed: its own map file when maps are kept."""
    one = copy.copy(args)
    one.world_seed = seed
    path = getattr(args, "map", None)
    if path is not None:
        one.map = Path(path).with_name(f"{Path(path).stem}-seed{seed}{Path(path).suffix}")
    return one


def _run_one(module_name: str, args: argparse.Namespace) -> dict[str, Any]:
    return dict(importlib.import_module(module_name).run(args))


def run_seeds(module_name: str, args: argparse.Namespace, seeds: list[int], jobs: int
              ) -> dict[str, Any]:
    """The experiment on each world seed: ``{"config", "metrics": summary, "per_seed":
    {seed: metrics}}``; the summary holds ``NAME_mean``, ``NAME_min`` and ``NAME_max``
    of each numeric metric over the seeds that gave one."""
    one_args = [seed_args(args, s) for s in seeds]
    if jobs <= 1:
        results = [_run_one(module_name, a) for a in one_args]
    else:  # spawned: a forked child would inherit the parent's threads' locks
        with concurrent.futures.ProcessPoolExecutor(
                max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            results = list(pool.map(_run_one, [module_name] * len(seeds), one_args))
    per_seed = {s: r["metrics"] for s, r in zip(seeds, results, strict=True)}
    return {"config": results[0].get("config", {}), "metrics": summarise(per_seed),
            "per_seed": per_seed}


def summarise(per_seed: dict[int, dict[str, Any]]) -> dict[str, float]:
    """Mean, minimum and maximum of each numeric metric over the seeds (a seed whose
    metric is None, as a decision rate with no decision, does not count)."""
    out: dict[str, float] = {}
    for name in next(iter(per_seed.values())):
        numbers = [float(v) for m in per_seed.values() if _is_number(v := m.get(name))
                   and math.isfinite(v)]
        if not numbers:
            continue
        out[f"{name}_mean"] = round(sum(numbers) / len(numbers), 4)
        out[f"{name}_min"] = round(min(numbers), 4)
        out[f"{name}_max"] = round(max(numbers), 4)
    return out


def table(per_seed: dict[int, dict[str, Any]], columns: list[str] | None = None) -> str:
    """The per-seed table of ``columns`` (default: every numeric metric) with mean, min
    and max rows (text output)."""
    if columns is None:
        columns = [k for k, v in next(iter(per_seed.values())).items() if _is_number(v)]
    summary = summarise(per_seed)
    width = [max(len(c), 7) for c in columns]

    def cell(value: Any, w: int) -> str:
        if value is None:
            return "-".rjust(w)
        if isinstance(value, float):
            return f"{value:.3f}".rjust(w)
        return str(value).rjust(w)

    lines = ["seed  " + "  ".join(c.rjust(w) for c, w in zip(columns, width, strict=True))]
    for seed, m in per_seed.items():
        lines.append(f"{seed:<4d}  " + "  ".join(cell(m.get(c), w)
                                               for c, w in zip(columns, width, strict=True)))
    for row in ("mean", "min", "max"):
        lines.append(f"{row:<4s}  " + "  ".join(cell(summary.get(f"{c}_{row}"), w)
                                                for c, w in zip(columns, width, strict=True)))
    return "\n".join(lines)


def _is_number(value: Any) -> TypeGuard[int | float]:
    return isinstance(value, int | float) and not isinstance(value, bool)
