"""``placecell-eval recognition-range``: the area around a place's reference pose where
its landmark set is still recognised (docs/design.md §3: selection matters; thesis §4.3).

For each place (the centre of a generated cluttered room, one world seed each) the set
chosen by Turn Back and Look and the 16 best of static selection alone are learned at the
same reference. On a grid of poses around the reference (same heading, 0.25 m apart, at
least 0.4 m from any wall), the set counts as recognised where its LRP stays above its
background LRP + 0.05. The background is what the thesis calls it (§7.1): the level the
LRP settles at away from the place, in the same surroundings — the median LRP of the set
at free poses of the same world beyond the grid (more than ``REACH`` + 0.5 m away). The
recognised area is reported for both selections.

Why one selection wins is measured too: for each of the place's TBL candidates, its
usefulness — how far its own best NCC stands above its own background (median at the far
poses), averaged over the grid — and the rank correlation of each selection score (TBL's
recognition margin, static selection's valley measure r) with that usefulness; as a bound
rather than a method, the area of the 16 candidates that proved most useful; and the area
of static selection held to the light test TBL's sets must pass (``keep_in_light``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from daemon.config import load
from daemon.mapping.tbl import keep_in_light
from daemon.vision.landmarks import LandmarkSet
from daemon.vision.recognition import FastMatcher, PreparedPanorama, PreparedTemplates
from daemon.vision.unwarp import Unwarper
from hal.sim.world import load_world
from kernel.errors import PlacecellError
from kernel.panorama import to_grey
from tools.eval import plots
from tools.eval.places import LearnedPlace, learn, view

DRAWS_PLOTS = True  # --plots DIR: range-NN-{tbl,static}.png, the LRP grid of each place
STEP = 0.25
REACH = 2.0
MARGIN = 0.05
FAR_POSES = 30


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--places", type=int, default=5)


def _free(place: LearnedPlace, x: float, y: float) -> bool:
    """Inside the world (walls all round) and at least 0.4 m from every wall and
    obstacle: a robot could stand there."""
    angles = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    hit = place.renderer._cast(x, y, angles, ())
    nearest = np.minimum(hit["t_full"], hit.get("t_low", hit["t_full"]))
    return bool(nearest.min() > 0.4 and np.all(np.isfinite(hit["t_full"])))


def _far_poses(place: LearnedPlace, world: str, rng: np.random.Generator
               ) -> list[tuple[float, float, float]]:
    """Up to ``FAR_POSES`` free poses of the world beyond the grid, any heading."""
    x_min, y_min, x_max, y_max = load_world(world).bounds()
    x0, y0, _ = place.pose
    out = []
    for x in np.arange(x_min + 0.25, x_max, 0.5):
        for y in np.arange(y_min + 0.25, y_max, 0.5):
            if math.hypot(x - x0, y - y0) > REACH + 0.5 and _free(place, x, y):
                out.append((float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
    if len(out) > FAR_POSES:
        out = [out[i] for i in sorted(rng.choice(len(out), FAR_POSES, replace=False))]
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    config = load(None)
    kind = args.world_kind or "open-room"
    worlds = [f"generate:{kind}:{args.world_seed + k}" for k in range(args.places)]
    places = [learn(w, load_world(w).start_pose, args.seed) for w in worlds]
    unwarper = Unwarper(config.projection, config.panorama)
    matcher = FastMatcher()
    rng = np.random.default_rng(args.seed)
    areas: dict[str, list[float]] = {"tbl": [], "static": []}
    far_counts = []
    correlation: dict[str, list[float]] = {"tbl_score": [], "valley_r": []}
    oracle_areas, static_light_areas = [], []
    for world, place in zip(worlds, places, strict=True):
        # Both sets are drawn from TBL's candidates (same templates): match the candidates
        # once and take each set's columns.
        templates = PreparedTemplates.of(place.candidates.templates())
        columns = {"tbl": _columns(place.candidates, place.tbl),
                   "static": _columns(place.candidates, place.static)}
        far_views = [PreparedPanorama.of(to_grey(view(place, unwarper, pose, rng)))
                     for pose in _far_poses(place, world, rng)]
        if not far_views:
            raise PlacecellError(f"{world}: no free pose beyond {REACH + 0.5} m of the place "
                                 "to measure the background LRP at")
        far_counts.append(len(far_views))
        # Best NCC of every candidate: at the far poses (n_far, n), on the grid (ny, nx, n).
        far = np.array([matcher.best_ncc(p, templates) for p in far_views])
        x0, y0, yaw = place.pose
        offsets = np.arange(-REACH, REACH + 1e-9, STEP)
        grid = np.full((len(offsets), len(offsets), len(templates.norms)), np.nan)
        for j, dx in enumerate(offsets):
            for i, dy in enumerate(offsets):
                x, y = x0 + dx, y0 + dy
                if not _free(place, x, y):
                    continue
                pano = PreparedPanorama.of(to_grey(view(place, unwarper, (x, y, yaw), rng)))
                grid[i, j] = matcher.best_ncc(pano, templates)
        for name, at in columns.items():
            values, background, recognised = _recognised(grid[..., at], far[:, at])
            areas[name].append(int(recognised.sum()) * STEP * STEP)
            if args.plots:
                plots.grid(Path(args.plots) / f"range-{len(areas[name]) - 1:02d}-{name}.png",
                           values, recognised, title=f"{world}: LRP of the {name} set "
                           f"(background {background:.2f})", lo=background - 0.1,
                           hi=float(np.nanmax(values)), cell_m=STEP)
        # Which selection score predicts a candidate's own usefulness for recognition: how
        # far its best NCC stands above its own background, averaged over the grid.
        usefulness = np.nanmean(grid - np.median(far, axis=0), axis=(0, 1))
        correlation["tbl_score"].append(_rank_correlation(
            np.array([lm.score for lm in place.candidates.landmarks]), usefulness))
        correlation["valley_r"].append(_rank_correlation(place.candidate_valley, usefulness))
        # Not a method (it ranks by the test views themselves): the area the 16 most useful
        # candidates reach: what a score of single candidates could at best achieve.
        top = np.argsort(usefulness)[::-1][:16]
        _, _, recognised = _recognised(grid[..., top], far[:, top])
        oracle_areas.append(int(recognised.sum()) * STEP * STEP)
        # Static selection held to TBL's light test (keep_in_light): static's 16 best
        # alone are not, and lose more of their LRP when the light changes.
        held = keep_in_light(place.candidate_valley, place.candidate_light_ncc, 16,
                             config.tbl.light_ncc)
        _, _, recognised = _recognised(grid[..., held], far[:, held])
        static_light_areas.append(int(recognised.sum()) * STEP * STEP)
    return {
        "world": {"kind": kind, "seed": args.world_seed},
        "config": {"places": args.places, "grid_step_m": STEP, "reach_m": REACH,
                   "margin": MARGIN, "background_poses_per_place": far_counts},
        "metrics": {
            "tbl_area_m2": round(float(np.mean(areas["tbl"])), 3),
            "static_area_m2": round(float(np.mean(areas["static"])), 3),
            "tbl_larger_fraction": round(float(np.mean(
                [t > s for t, s in zip(areas["tbl"], areas["static"], strict=True)])), 3),
            "tbl_area_per_place_m2": [round(a, 3) for a in areas["tbl"]],
            "static_area_per_place_m2": [round(a, 3) for a in areas["static"]],
            # Spearman rank correlation, over each place's TBL candidates, of a selection
            # score with the candidate's usefulness (mean over places).
            "candidate_usefulness_correlation": {
                name: round(float(np.mean(v)), 3) for name, v in correlation.items()},
            "oracle_area_m2": round(float(np.mean(oracle_areas)), 3),
            "static_light_area_m2": round(float(np.mean(static_light_areas)), 3),
        },
    }


def _columns(candidates: LandmarkSet, subset: LandmarkSet) -> list[int]:
    """Where each landmark of ``subset`` stands among ``candidates`` (same template, same
    place in the reference panorama)."""
    index = {(lm.row, lm.col): i for i, lm in enumerate(candidates.landmarks)}
    return [index[lm.row, lm.col] for lm in subset.landmarks]


def _recognised(grid_best: np.ndarray, far_best: np.ndarray
                ) -> tuple[np.ndarray, float, np.ndarray]:
    """A set's LRP on the grid (from its templates' best NCC there, (ny, nx, n)), its
    background (median LRP at the far poses, (n_far, n)) and where it is recognised."""
    values = grid_best.mean(axis=2)
    background = float(np.median(far_best.mean(axis=1)))
    return values, background, np.nan_to_num(values, nan=-1.0) > background + MARGIN


def _rank_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation (no ties expected: continuous scores)."""
    ranks_a, ranks_b = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ranks_a, ranks_b)[0, 1])
