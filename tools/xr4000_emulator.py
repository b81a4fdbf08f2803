"""``placecell-xr4000-emulator``: the XR4000 base controller over a serial port or CAN bus.

  placecell-xr4000-emulator --serial /tmp/xr4000-robot [--scenario S.toml | --recording R.mcap]
  placecell-xr4000-emulator --can slcan:/dev/pts/7 --drop-rate 0.05 --stats-out stats.json

By default it drives the simulated base (so motion commands such as a TBL cross are
executed); with --recording it replays recorded odometry in step with a replay camera
started at the same time. It runs until SIGTERM/SIGINT or --duration, then writes what it
sent and injected to --stats-out.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import signal
import sys
import threading
from pathlib import Path

from daemon import config as config_mod
from hal.sim.factory import build_sim_robot
from hal.sim.scenario import load_scenario
from kernel.errors import PlacecellError
from tools.xr4000.emulator import Emulator, RecordingSource, SimSource
from tools.xr4000.faults import FaultPlan
from tools.xr4000.transport import CanSide, SerialSide


def _pair(text: str) -> tuple[float, float]:
    a, b = text.split(":")
    return float(a), float(b)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="placecell-xr4000-emulator", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    link = p.add_mutually_exclusive_group(required=True)
    link.add_argument("--serial", metavar="PORT", help="serial port (a socat pty end)")
    link.add_argument("--can", metavar="INTERFACE:CHANNEL", help="python-can bus, e.g. "
                      "slcan:/dev/pts/5 or virtual:xr4000")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--scenario", help="simulate this scenario (default: the robot waits)")
    src.add_argument("--recording", help="replay the odometry of this MCAP recording")
    p.add_argument("--config", help="placecell configuration for the simulated base")
    p.add_argument("--seed", type=int, default=0, help="seed of the injected faults")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--corrupt-rate", type=float, default=0.0)
    p.add_argument("--drop-rate", type=float, default=0.0)
    p.add_argument("--garbage-rate", type=float, default=0.0)
    p.add_argument("--truncate-rate", type=float, default=0.0)
    p.add_argument("--time-backwards-rate", type=float, default=0.0)
    p.add_argument("--error-frame-rate", type=float, default=0.0)
    p.add_argument("--seq-jump-at", type=float, action="append", default=[],
                   metavar="T_S", help="the sequence counter jumps by 1000 at T_S seconds")
    p.add_argument("--silence", type=_pair, action="append", default=[],
                   metavar="START:DURATION", help="send nothing for a while")
    p.add_argument("--drop-answer", type=int, action="append", default=[], metavar="N",
                   help="do not send the N-th answer to a command (1: the first); repeatable")
    p.add_argument("--stats-out", help="JSON file: what was sent and injected")
    p.add_argument("--truth-out", help="JSON lines: the simulated base's true pose per sample")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s emulator: %(message)s")
    try:
        config = config_mod.load(args.config)
        if args.recording:
            source: SimSource | RecordingSource = RecordingSource(args.recording)
        else:
            scenario = load_scenario(args.scenario) if args.scenario else None
            # Without --scenario the base waits for commands (not the configuration's demo).
            config = dataclasses.replace(config, sim=dataclasses.replace(
                config.sim, realtime=True, scenario=""))
            source = SimSource(build_sim_robot(config, scenario, camera=False))
        if args.serial:
            side: SerialSide | CanSide = SerialSide(args.serial)
        else:
            interface, _, channel = args.can.partition(":")
            side = CanSide(interface, channel)
    except (PlacecellError, OSError, ValueError) as e:
        print(f"placecell-xr4000-emulator: {e}", file=sys.stderr)
        return 2
    plan = FaultPlan(args.corrupt_rate, args.drop_rate, args.garbage_rate, args.truncate_rate,
                     args.time_backwards_rate, args.error_frame_rate, tuple(args.seq_jump_at),
                     tuple(args.silence), tuple(args.drop_answer))
    emulator = Emulator(side, source, plan, seed=args.seed, truth_out=args.truth_out)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    logging.info("running on %s", args.serial or args.can)
    try:
        emulator.run(stop, args.duration)
    except OSError as e:
        logging.error("link failed: %s", e)
    finally:
        side.close()
        if args.stats_out:
            Path(args.stats_out).write_text(json.dumps(emulator.report(), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
