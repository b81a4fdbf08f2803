"""``placecell-bench [--json] [--repeats N] [--only NAME]``: named speed figures.

Each group of figures lives in ``tools/bench/<module>.py`` and provides
``run(repeats: int) -> dict[str, float]``. Every figure is a median of ``repeats`` runs;
ratios (e.g. ``lrp_speedup``) are taken against a baseline measured in the same process.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys

from tools.bench.timing import pin_to_one_core

GROUPS = {
    "sim": "tools.bench.sim",
    "landmarks": "tools.bench.landmarks",
    "mapfile": "tools.bench.mapfile",
    "embedding": "tools.bench.embedding",
    "localisation": "tools.bench.localisation",
    "global": "tools.bench.global_search",
    "disambiguation": "tools.bench.disambiguation",
    "local_space": "tools.bench.local_space",
    "daemon": "tools.bench.daemon",
}
# Run only when named with --only: half an hour of the daemon mapping.
ON_REQUEST = {"soak": "tools.bench.soak"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="placecell-bench",
        description="Measure placecell's speed: named figures, each the median of "
                    "--repeats runs, ratios against a baseline measured in the same run.")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--only", choices=sorted(GROUPS | ON_REQUEST), action="append")
    args = parser.parse_args(argv)
    pin_to_one_core()
    figures: dict[str, float] = {}
    for name in args.only or GROUPS:
        module = (GROUPS | ON_REQUEST)[name]
        figures.update(importlib.import_module(module).run(args.repeats))
    if args.json:
        print(json.dumps({"repeats": args.repeats, "figures": figures}, indent=2,
                         sort_keys=True))
    else:
        for key, value in figures.items():
            print(f"{key:32s} {value:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
