"""``placecell-sim world --kind K --seed N --out W.toml``: generate a world file."""

from __future__ import annotations

import argparse

from hal.sim.world import save_world
from hal.sim.worldgen import KINDS, generate


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--kind", choices=KINDS, required=True)
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--out", required=True, help="TOML file to write")


def run(args: argparse.Namespace) -> int:
    world = generate(args.kind, args.seed)
    save_world(world, args.out)
    x0, y0, x1, y1 = world.bounds()
    print(f"wrote {args.out}: {world.name}, {len(world.walls)} walls, "
          f"{x1 - x0:.1f} x {y1 - y0:.1f} m, start {world.start_pose}")
    return 0
