"""``placecell-sim``: the simulator's command line (worlds, rendering, recordings, mirror).

Each subcommand lives in ``tools/simcmd/<name>.py`` and provides ``add_arguments(parser)``
and ``run(args) -> int``; this file only dispatches.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from kernel.errors import PlacecellError

# subcommand -> (module, one-line help)
SUBCOMMANDS = {
    "world": ("tools.simcmd.world", "generate a world: --kind K --seed N --out W.toml"),
    "render": ("tools.simcmd.render", "render plan view, donut and panorama PNGs"),
    "detect-mirror": ("tools.simcmd.detect_mirror", "find the mirror donut in a raw image"),
    "calibrate": ("tools.simcmd.calibrate", "a camera model's configuration from its "
                  "images (--model mirror|fisheye|dual-fisheye|equirectangular|ocamcalib)"),
    "verticals": ("tools.simcmd.verticals", "how vertical the world's vertical edges stand "
                  "in the panorama the configured camera model unwarps"),
    "record": ("tools.simcmd.record", "record a scenario to an MCAP file"),
    "ros2-robot": ("tools.simcmd.ros2_robot", "the simulated robot as a ROS 2 robot over "
                   "rmw_zenoh (images, /odom, /cmd_vel)"),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="placecell-sim",
        description="The simulator: generate worlds, render views, record runs, find "
                    "the mirror in a camera image.")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text)
        p.set_defaults(_module=module_name)
        importlib.import_module(module_name).add_arguments(p)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(importlib.import_module(args._module).run(args))
    except PlacecellError as e:
        print(f"placecell-sim {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
