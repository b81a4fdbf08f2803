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
global search's first frames included), ``first_tracking_frame``, ``false_losses_per_1000``
(losses declared per 1000 frames; the robot is never carried off here),
``process_ms_median``; and the active set's cue part (design §9: places whose signature
similarity is within the cue margin of the best) scored on every frame:
``inclusion_extra_cue`` (a right place in it), ``mean_set_fraction_extra_cue`` (its size
over the map's) at ``[localisation] cue_margin``, and ``by_cue_margin`` at a few others.
Local space profiles (the thesis's cue, §9.4.1) are not built yet: no ``inclusion``.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from daemon.vision.signature import signature, similarity
from kernel.panorama import to_grey
from kernel.se2 import SE2
from tools.eval.tour_map import Point, add_map_arguments, drive_to, mapped_run, right_place


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_map_arguments(p, places=50)


def _mapped_part(tour: list[Point], references: dict[int, SE2]) -> list[Point]:
    """The tour up to where it passes nearest the last place learned along it (a map of
    fewer places than the tour could hold covers only its beginning)."""
    last = references[max(references)]
    end = min(range(len(tour)), key=lambda i: math.dist(tour[i], (last.x, last.y)))
    return tour[:end + 1]


MARGINS = (0.02, 0.05, 0.1, 0.2)  # cue margins the active set is also scored at


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
        at = r.cfg.localisation.cue_margin
        margins = sorted({*MARGINS, at})
        included: dict[float, list[bool]] = {m: [] for m in margins}
        fraction: dict[float, list[float]] = {m: [] for m in margins}
        for target in _mapped_part(tour, r.references)[1::10]:  # every metre of it
            for belief in drive_to(r, target, args.speed):
                x, y, _ = r.robot.true_pose()
                right.append(right_place(r.references, belief.place_id, (x, y)))
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
        return {"metrics": {
            "places": len(r.references),
            "frames": len(right),
            "mlp_accuracy": round(float(np.mean(right)), 4),
            "first_tracking_frame": first_tracking,
            "false_losses_per_1000": round(1000.0 * losses / max(len(right), 1), 2),
            "process_ms_median": round(float(np.median(r.process_s)) * 1e3, 2),
            "inclusion_extra_cue": round(float(np.mean(included[at])), 4),
            "mean_set_fraction_extra_cue": round(float(np.mean(fraction[at])), 4),
            "by_cue_margin": {str(m): {"inclusion": round(float(np.mean(included[m])), 4),
                                       "mean_set_fraction": round(float(np.mean(
                                           fraction[m])), 4)} for m in MARGINS},
        }, "config": {"places": args.places, "spacing_m": args.spacing, "speed": args.speed,
                      "sensor_model": args.sensor_model, "cue_margin": at}}
