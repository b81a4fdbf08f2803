"""A stand-in experiment for tests/test_eval_seeds.py: its metrics are drawn from the
world seed it was given, so what runs on which seed can be checked."""

from __future__ import annotations

import argparse
import os
from typing import Any

SEED_COLUMNS = ("half", "rate")


def run(args: argparse.Namespace) -> dict[str, Any]:
    return {"config": {"map": None if args.map is None else str(args.map)},
            "metrics": {"half": args.world_seed / 2, "rate": None if args.world_seed == 3
                        else 1.0 / args.world_seed, "pid": os.getpid(), "name": "probe"}}
