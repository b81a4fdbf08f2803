"""``placecell-eval global``: the most likely place along a tour through a map of many
places, the robot started with no pose (design §9; thesis §9.2: a path through a
50-place map, right on 100 % of its images).

The map: ``--places`` places learned every ``--spacing`` m along the world's tour
(tools/eval/tour_map.py). The robot is then carried back to the tour's start without
odometry knowing, a new Localiser is started on the map (as the daemon starts), and the
robot drives the tour again as far as the map covers it. Each frame's place is *right*
when its reference is the nearest to the true position, or no more than 0.5 m farther
than the nearest.

Metrics: ``places``, ``frames``, ``mlp_accuracy`` (right on the tour's frames, the
global search's first frames included), ``first_tracking_frame``, ``mean_error_m`` (the
tracked pose against the truth in its place's frame, on frames tracking in a right
place), ``false_losses_per_1000`` (losses declared per 1000 frames; the robot is never
carried off here),
``process_ms_median``; and the active set's cue part (design §9: places whose signature
similarity is within the cue margin of the best) scored on every frame:
``inclusion_extra_cue`` (a right place in it), ``mean_set_fraction_extra_cue`` (its size
over the map's) at ``[localisation] cue_margin``, and ``by_cue_margin`` at a few others.
The local space set (design §4, thesis §9.4.1): the method's ``LocalSpace`` learns the
floor on the tour's first frame and runs its floor grid on every frame; each place's
profile is its reference panorama's; the set is every place whose profile matches within
``LOCAL_MARGIN`` (0.1; the thesis's B was 0.075) of the best: ``inclusion``,
``mean_set_fraction``, and ``by_local_margin``; ``inclusion_combined`` /
``mean_set_fraction_combined`` for the places in both sets. Scored here on the
evaluator's side; the Localiser's search narrows its active set the same way only with
``[localisation] local_space_margin`` below 1 (design §9). ``--floor`` gives the world
a hard floor (design §4): on the generated, nearly flat one every floor detector looks
perfect.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from daemon.vision.local_space import CAP_M, LocalSpace, match_many
from daemon.vision.signature import signature, similarity
from kernel.panorama import core_of, to_grey
from kernel.se2 import SE2
from tools.eval.lockstep import add_backends_argument
from tools.eval.tour_map import Point, add_map_arguments, drive_to, mapped_run, right_place

CAMERA_MODELS = True  # --camera-model M: any of kernel/camera_models.py MODEL_NAMES


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_map_arguments(p, places=50)
    add_backends_argument(p)


def _mapped_part(tour: list[Point], references: dict[int, SE2]) -> list[Point]:
    """The tour up to where it passes nearest the last place learned along it (a map of
    fewer places than the tour could hold covers only its beginning)."""
    last = references[max(references)]
    end = min(range(len(tour)), key=lambda i: math.dist(tour[i], (last.x, last.y)))
    return tour[:end + 1]


MARGINS = (0.02, 0.05, 0.1, 0.2)  # cue margins the active set is also scored at
LOCAL_MARGIN = 0.1  # B of thesis §9.4.1 (0.075 there; design §9)
LOCAL_MARGINS = (0.03, 0.05, 0.075, 0.1, 0.15)


def _rate(flags: list[bool] | list[float]) -> float:
    return round(float(np.mean(flags)), 4) if flags else float("nan")


def run(args: argparse.Namespace) -> dict[str, Any]:
    with mapped_run(args) as (r, tour):
        start = r.cfg.sim.start_pose
        r.robot.kidnap(start[0], start[1], start[2])
        r.process_s.clear()
        ids = sorted(r.references)
        margin = r.cfg.panorama.wrap_margin
        signatures = np.stack([signature(to_grey(r.store.reference_panorama(p)), margin)
                               for p in ids])
        right, losses, first_tracking = [], 0, None
        errors: list[float] = []  # of the tracked pose in the right place
        at = r.cfg.localisation.cue_margin
        margins = sorted({*MARGINS, at})
        included: dict[float, list[bool]] = {m: [] for m in margins}
        fraction: dict[float, list[float]] = {m: [] for m in margins}
        local = LocalSpace((r.cfg.panorama.height, r.cfg.panorama.width),
                           int(math.floor(r.localiser.unwarper.horizon_row())),
                           r.localiser.unwarper.floor_distance_of_rows())
        profiles: np.ndarray | None = None  # each place's, once the floor is learned
        local_in: dict[float, list[bool]] = {m: [] for m in LOCAL_MARGINS}
        local_fraction: dict[float, list[float]] = {m: [] for m in LOCAL_MARGINS}
        both_in: list[bool] = []
        both_fraction: list[float] = []
        for target in _mapped_part(tour, r.references)[1::10]:  # every metre of it
            for belief in drive_to(r, target, args.speed, start[2]):
                x, y, _ = r.robot.true_pose()
                right.append(right_place(r.references, belief.place_id, (x, y)))
                error = r.error_m(belief)
                if belief.state == "tracking" and right[-1] and error is not None:
                    errors.append(error)
                losses += belief.event is not None and belief.event.kind == "lost"
                if first_tracking is None and belief.state == "tracking":
                    first_tracking = len(right)
                assert r.localiser.panorama is not None
                cue = similarity(signature(to_grey(r.localiser.panorama), margin), signatures)
                for m in margins:  # the active set's cue part at margin m (design §9)
                    members = [p for p, c in zip(ids, cue, strict=True) if c >= cue.max() - m]
                    included[m].append(any(right_place(r.references, p, (x, y))
                                           for p in members))
                    fraction[m].append(len(members) / len(ids))
                local.update(core_of(r.localiser.panorama, margin))
                if profiles is None:
                    profiles = np.stack([local.profile_of(core_of(
                        r.store.reference_panorama(p), margin)) for p in ids])
                c = match_many(local.profile(), profiles, CAP_M)
                for m in LOCAL_MARGINS:
                    members = [p for p, v in zip(ids, c, strict=True) if v >= c.max() - m]
                    local_in[m].append(any(right_place(r.references, p, (x, y))
                                           for p in members))
                    local_fraction[m].append(len(members) / len(ids))
                    if m == LOCAL_MARGIN:
                        sig = {p for p, v in zip(ids, cue, strict=True) if v >= cue.max() - at}
                        both = [p for p in members if p in sig]
                        both_in.append(any(right_place(r.references, p, (x, y))
                                           for p in both))
                        both_fraction.append(len(both) / len(ids))
        return {"metrics": {
            "places": len(r.references),
            "frames": len(right),
            "mlp_accuracy": round(float(np.mean(right)), 4),
            "mean_error_m": _rate(errors),
            "first_tracking_frame": first_tracking,
            "false_losses_per_1000": round(1000.0 * losses / max(len(right), 1), 2),
            "process_ms_median": round(float(np.median(r.process_s)) * 1e3, 2),
            "inclusion_extra_cue": round(float(np.mean(included[at])), 4),
            "mean_set_fraction_extra_cue": round(float(np.mean(fraction[at])), 4),
            "inclusion": _rate(local_in[LOCAL_MARGIN]),
            "mean_set_fraction": _rate(local_fraction[LOCAL_MARGIN]),
            "inclusion_combined": _rate(both_in),
            "mean_set_fraction_combined": _rate(both_fraction),
            "by_local_margin": {str(m): {"inclusion": _rate(local_in[m]),
                                         "mean_set_fraction": _rate(local_fraction[m])}
                                for m in LOCAL_MARGINS},
            "by_cue_margin": {str(m): {"inclusion": round(float(np.mean(included[m])), 4),
                                       "mean_set_fraction": round(float(np.mean(
                                           fraction[m])), 4)} for m in MARGINS},
        }, "config": {"places": args.places, "spacing_m": args.spacing, "speed": args.speed,
                      "sensor_model": args.sensor_model, "cue_margin": at,
                      "floor": getattr(args, "floor", None) or "fine",
                      "local_margin": LOCAL_MARGIN, "backends": args.backends}}
