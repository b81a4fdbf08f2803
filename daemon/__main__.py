"""``placecelld`` / ``python -m daemon``: the placecell localisation daemon."""

from __future__ import annotations

# One BLAS thread, before numpy loads OpenBLAS (kernel/threads.py).
from kernel.threads import one_blas_thread

one_blas_thread()

# Two malloc arenas and fixed thresholds, before any thread starts: each learn left tens
# of MB in arenas of its own and in a heap grown for its temporaries
# (daemon/service/memory.py, docs/design.md §13).
from daemon.service.memory import tune_heap  # noqa: E402 - before numpy's threads

tune_heap()

import argparse  # noqa: E402 - after the thread settings above
import logging  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from daemon import config as config_mod  # noqa: E402
from kernel.errors import PlacecellError  # noqa: E402

log = logging.getLogger("placecelld")

DEFAULT_CONFIG = "config/placecell.toml"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="placecelld", description=__doc__)
    p.add_argument("--config", metavar="PATH",
                   help=f"configuration TOML (default: {DEFAULT_CONFIG} if present, "
                        "else built-in defaults)")
    p.add_argument("--print-config", action="store_true",
                   help="print the effective configuration and exit")
    p.add_argument("--check-devices", action="store_true",
                   help="open each configured device, read a few frames/samples, report, exit")
    p.add_argument("--record", metavar="FILE",
                   help="record what the daemon sees (frames, odometry, beliefs) to MCAP")
    p.add_argument("--log-level", choices=["DEBUG", "INFO", "WARNING", "ERROR"],
                   help="overrides [log] level")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    path = args.config
    if path is None and Path(DEFAULT_CONFIG).is_file():
        path = DEFAULT_CONFIG
    try:
        config = config_mod.load(path)
    except PlacecellError as e:
        print(f"placecelld: configuration error: {e}", file=sys.stderr)
        return 2
    if args.print_config:
        sys.stdout.write(config_mod.to_toml(config))
        return 0
    logging.basicConfig(level=args.log_level or config.log.level,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.check_devices:
        from daemon.service.check_devices import check_devices

        lines = check_devices(config)
        print("\n".join(lines))
        return 1 if any(line.startswith("FAIL") for line in lines) else 0
    from daemon.service.app import Daemon
    from daemon.service.notify import Notifier

    recorder = None
    try:
        if args.record:
            from hal.recording import Recorder

            recorder = Recorder(args.record, {"source": "placecelld",
                                              "config": config_mod.to_toml(config)})
        service = Daemon(config, Notifier(), recorder=recorder)
        service.install_signal_handlers()
        return service.run()
    except PlacecellError as e:
        log.error("%s", e)
        return 2


if __name__ == "__main__":
    sys.exit(main())
