"""``placecellctl``: the operator's command line for a running placecell daemon (over zenoh)."""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from pathlib import Path
from typing import Any

import zenoh

from daemon.service import zenoh_link

DEFAULT_CONFIG = "config/placecell.toml"


def _endpoints_from_config(path: str | None) -> tuple[str | None, list[str]]:
    """The robot name and the daemon's listen endpoints, read from its config file."""
    p = Path(path or DEFAULT_CONFIG)
    if not p.is_file():
        if path:
            raise SystemExit(f"placecellctl: cannot read configuration {p}")
        return None, ["tcp/127.0.0.1:7447"]
    data = tomllib.loads(p.read_text(encoding="utf-8"))
    robot = data.get("robot", {}).get("name")
    listen = data.get("zenoh", {}).get("listen", ["tcp/127.0.0.1:7447"])
    return robot, listen


def open_client(args: argparse.Namespace) -> tuple[zenoh.Session, str]:
    robot, listen = _endpoints_from_config(args.config)
    connect = args.connect or [ep for ep in listen if not ep.endswith(":0")]
    session = zenoh_link.open_session(
        "peer", ["tcp/127.0.0.1:0"], connect, multicast_scouting=False)
    return session, args.robot or robot or "*"


def query_json(session: zenoh.Session, key: str, timeout_s: float) -> list[dict[str, Any]]:
    out = []
    for reply in session.get(key, timeout=timeout_s):
        if reply.ok is not None:
            try:
                out.append(zenoh_link.decode(reply.ok.payload.to_bytes()))
            except ValueError:
                continue
    return out


def cmd_status(args: argparse.Namespace) -> int:
    session, robot = open_client(args)
    try:
        replies = query_json(session, zenoh_link.key(robot, "status"), args.timeout)
    finally:
        session.close()
    if not replies:
        where = args.connect or f"from {args.config or DEFAULT_CONFIG}"
        print(f"placecellctl: no placecell daemon answered on placecell/{robot}/status within "
              f"{args.timeout:.1f} s (is placecelld running? endpoints: {where})",
              file=sys.stderr)
        return 3
    if args.json:
        print(json.dumps(replies[0] if len(replies) == 1 else replies, indent=2))
        return 0
    for st in replies:
        print(format_status(st))
    return 0


def format_status(st: dict[str, Any]) -> str:
    lines = [
        f"robot {st['robot']}: {'healthy' if st['healthy'] else 'DEGRADED'}, "
        f"up {st['uptime_s']:.0f} s, placecell {st['versions']['placecell']}",
        f"  frames {st['rates']['frames_hz']:.1f} Hz, odometry {st['rates']['odometry_hz']:.1f} "
        f"Hz, processed {st['rates']['processed_hz']:.1f} Hz",
    ]
    belief = st.get("belief") or {}
    if belief:
        lines.append(f"  belief: {belief['state']} ({belief['reason']})")
    lines.append(f"  map: {st['map']['places']} places in {st['map']['path']}")
    for name, comp in st["components"].items():
        err = f", last error {comp['last_error_age_s']} s ago: {comp['last_error']}" \
            if comp.get("last_error") else ""
        lines.append(f"  {name:10s} {comp['state']:8s} {comp['rate_hz']:6.1f} Hz, "
                     f"{comp['restarts']} restarts{err}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="placecellctl", description=__doc__)
    parser.add_argument("--config", help=f"the daemon's configuration (default {DEFAULT_CONFIG})")
    parser.add_argument("--connect", action="append",
                        help="zenoh endpoint of the daemon (default: its listen endpoints)")
    parser.add_argument("--robot", help="robot name (default: from the configuration)")
    parser.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for answers")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("status", help="show the daemon's health, rates and belief")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_status)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except zenoh_link.ConfigError as e:
        print(f"placecellctl: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
