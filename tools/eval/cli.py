"""``placecell-eval EXPERIMENT [--world-kind K] [--world-seed N | --seeds A-B [--jobs N]]
[--seed N] [--json] [--plots DIR]``

Each experiment lives in ``tools/eval/<module>.py`` and provides
``add_arguments(parser)`` and ``run(args) -> dict`` returning ``{"metrics": {...},
"config": {...}}`` (plus optional ``"world"``). This file dispatches and prints one JSON
object ``{"experiment", "world": {kind, seed}, "seed", "config", "metrics"}``. With
``--seeds`` it runs on each world seed (tools/eval/seeds.py): ``world`` names the seeds,
``metrics`` holds each metric's mean, min and max over them and ``per_seed`` every seed's
metrics; the text output is the per-seed table of the experiment's ``SEED_COLUMNS``.
"""

from __future__ import annotations

# One BLAS thread, before numpy loads OpenBLAS (kernel/threads.py): the experiments drive
# the daemon's Localiser as the daemon runs it.
from kernel.threads import one_blas_thread

one_blas_thread()

import argparse  # noqa: E402 - after the thread setting above
import importlib  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
from typing import Any  # noqa: E402

from kernel.camera_models import MODEL_NAMES  # noqa: E402
from kernel.errors import PlacecellError  # noqa: E402
from tools.eval.seeds import parse_seeds, run_seeds, table  # noqa: E402

# experiment -> (module, default world kind, one-line help)
EXPERIMENTS: dict[str, tuple[str, str, str]] = {
    "depth": ("tools.eval.depth", "open-room", "TBL depth-estimate error (docs/design.md §3)"),
    "recognise": ("tools.eval.recognise", "", "LRP of a landmark set in real images"),
    "recognition-range": (
        "tools.eval.recognition_range", "open-room", "area where a place's LRP stays up (§3.4)"
    ),
    "robustness": ("tools.eval.robustness", "office", "LRP under light changes and occlusion"),
    "tbl-local": ("tools.eval.tbl_local", "office", "local positioning along the TBL path "
                  "(design §7, thesis §8.1.5)"),
    "cyclic": ("tools.eval.cyclic", "office", "tracking lap after lap round a loop of "
               "places, against odometry (design §8, thesis §8.2)"),
    "replay": ("tools.eval.replay", "", "a recording through the daemon's pipeline: "
               "the daemon's poses, frame by frame (design §10)"),
    "global": ("tools.eval.global_tour", "office", "the most likely place along a tour "
               "through a map of many places, started with no pose (design §9)"),
    "active-set": ("tools.eval.active_set", "office", "the active set's cue along the "
                   "global tour: inclusion of the right place and the set's size (design §9)"),
    "kidnap": ("tools.eval.kidnap", "office", "the kidnapped robot: loss detected, right "
               "place, error, over many random kidnaps (design §9, thesis §9.6)"),
    "floor": ("tools.eval.floor", "office", "floor detection against the simulator's floor "
              "masks on hard floors, and local space profiles (design §4)"),
    "aliased": ("tools.eval.aliased", "aliased-corridor", "look-alike places told apart "
                "by their features, against the lower levels alone (design §5)"),
    "mapping": ("tools.eval.mapping", "open-room", "places learned on the robot's own along "
                "a tour, and how well they cover it (design §6)"),
    "endurance": ("tools.eval.endurance", "office", "the daemon left to its job in mapping "
                  "mode: laps of a tour with kidnaps, restarts and operator learns (design "
                  "§6)"),
    "fleet": ("tools.eval.fleet", "office", "three robots share one map through two fleet "
              "routers: a robot with an empty map, propagation, segments joined, a router "
              "killed (docs/fleet.md)"),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="placecell-eval",
        description="Run one of placecell's experiments on a simulated world and print its "
                    "metrics (--json: one JSON object with the world, seeds, settings and "
                    "metrics). Worlds are drawn from --world-kind and --world-seed.")
    sub = parser.add_subparsers(dest="experiment", required=True)
    for name, (module_name, world_kind, help_text) in EXPERIMENTS.items():
        p = sub.add_parser(name, help=help_text)
        p.set_defaults(_module=module_name)
        p.add_argument("--world-kind", default=world_kind or None)
        p.add_argument("--world-seed", type=int, default=1)
        p.add_argument("--seeds", type=parse_seeds, metavar="A-B",
                       help="run on each of these world seeds (A-B, or a list: 1,3,5-7) "
                       "and print the per-seed table and its mean, min and max")
        p.add_argument("--jobs", type=int, default=1,
                       help="with --seeds: worlds run at once, each in its own process")
        p.add_argument("--seed", type=int, default=1, help="seed of the experiment's randomness")
        p.add_argument("--json", action="store_true", help="print one JSON object")
        p.add_argument("--plots", metavar="DIR", help="write PNG figures of the experiment here")
        p.add_argument("--camera-model", choices=MODEL_NAMES, default="mirror",
                       help="the simulated camera and the daemon's camera model "
                       "(tools/eval/cameras.py)")
        importlib.import_module(module_name).add_arguments(p)
    args = parser.parse_args(argv)
    if args.plots and not getattr(importlib.import_module(args._module), "DRAWS_PLOTS", False):
        parser.error(f"{args.experiment} draws no figures yet: drop --plots")
    if args.camera_model != "mirror" and not getattr(importlib.import_module(args._module),
                                                     "CAMERA_MODELS", False):
        parser.error(f"{args.experiment} runs on the mirror camera only: drop --camera-model")
    if args.seeds and args.plots:
        parser.error("--plots draws one world's figures: drop --seeds")
    if args.jobs < 1:
        parser.error(f"--jobs {args.jobs}: at least 1")
    logging.basicConfig(level=logging.WARNING if args.json else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    module = importlib.import_module(args._module)
    try:
        result: dict[str, Any] = (run_seeds(args._module, args, args.seeds, args.jobs)
                                  if args.seeds else module.run(args))
    except PlacecellError as e:
        print(f"placecell-eval {args.experiment}: error: {e}", file=sys.stderr)
        return 2
    out = {
        "experiment": args.experiment,
        "world": ({"kind": args.world_kind, "seeds": args.seeds} if args.seeds else
                  result.get("world", {"kind": args.world_kind, "seed": args.world_seed})),
        "seed": args.seed,
        "config": {**result.get("config", {}), "camera_model": args.camera_model},
        "metrics": result["metrics"],
    }
    if args.seeds:
        out["per_seed"] = result["per_seed"]
    if args.json:
        print(json.dumps(out, indent=2, sort_keys=True))
    elif args.seeds:
        columns = getattr(module, "SEED_COLUMNS", None)
        print(table(result["per_seed"], None if columns is None else list(columns)))
    else:
        for key, value in out["metrics"].items():
            print(f"{key:32s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
