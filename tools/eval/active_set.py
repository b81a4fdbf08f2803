"""``placecell-eval active-set``: the active set's cue part along a tour through a map of
many places (design §9; thesis §9.4: the true place in the local-space set on 98 % of
frames, the set 40 % of the map).

The same tour as ``placecell-eval global`` (tools/eval/global_tour.py), scored by the
cue alone: on every frame the places whose signature similarity is within the cue
margin of the best. Metrics: ``inclusion_extra_cue``, ``mean_set_fraction_extra_cue``
(at ``[localisation] cue_margin``) and ``by_cue_margin``; the local space set (the
thesis's own cue, margin B = 0.1): ``inclusion``, ``mean_set_fraction``,
``by_local_margin``, and both sets' common part ``inclusion_combined``,
``mean_set_fraction_combined``; ``places``, ``frames``. ``--floor carpet`` (or another
of hal/sim/worldgen.py FLOORS) gives the world a hard floor.
"""

from __future__ import annotations

import argparse
from typing import Any

from tools.eval import global_tour

KEPT = ("places", "frames", "inclusion", "mean_set_fraction", "inclusion_extra_cue",
        "mean_set_fraction_extra_cue", "inclusion_combined", "mean_set_fraction_combined",
        "by_local_margin", "by_cue_margin")


def add_arguments(p: argparse.ArgumentParser) -> None:
    global_tour.add_arguments(p)


def run(args: argparse.Namespace) -> dict[str, Any]:
    result = global_tour.run(args)
    result["metrics"] = {k: result["metrics"][k] for k in KEPT}
    return result
