"""``placecellctl``: the operator's command line for a running placecell daemon (over zenoh)."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import queue
import sys
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import zenoh

from daemon.service import zenoh_link
from kernel.errors import PlacecellError

DEFAULT_CONFIG = "config/placecell.toml"

# Exit codes, distinct so scripts can tell what happened.
EXIT_OK, EXIT_USAGE, EXIT_UNREACHABLE, EXIT_REFUSED, EXIT_ABORTED, EXIT_FAILED = 0, 2, 3, 4, 5, 6
_EXIT_OF_CODE = {"aborted": EXIT_ABORTED, "failed": EXIT_FAILED}


def _endpoints_from_config(path: str | None) -> tuple[str | None, list[str], str]:
    """The robot name, the daemon's listen endpoints and its ``[zenoh] id`` setting,
    read from its config file."""
    p = Path(path or DEFAULT_CONFIG)
    if not p.is_file():
        if path:
            raise SystemExit(f"placecellctl: cannot read configuration {p}")
        return None, ["tcp/127.0.0.1:7448"], ""
    data = tomllib.loads(p.read_text(encoding="utf-8"))
    robot = data.get("robot", {}).get("name")
    zenoh_section = data.get("zenoh", {})
    listen = zenoh_section.get("listen", ["tcp/127.0.0.1:7448"])
    return robot, listen, str(zenoh_section.get("id", ""))


def open_client(args: argparse.Namespace) -> tuple[zenoh.Session, str]:
    """A session connected to the daemon (listening nowhere itself: nobody needs to reach
    a command line); ``args.robot_zid`` is then the node allowed to answer for the robot
    (None when no robot is named: any answers)."""
    robot, listen, configured_zid = _endpoints_from_config(args.config)
    connect = args.connect or [ep for ep in listen if not ep.endswith(":0")]
    session = zenoh_link.open_session(
        "peer", [], connect, multicast_scouting=False,
        config_file=args.zenoh_config or "")
    name = args.robot or robot
    args.robot_zid = zenoh_link.robot_zid(name, configured_zid) if name else None
    return session, name or "*"


def from_robot(replies: Any, robot_zid: str | None) -> Iterator[zenoh.Sample]:
    """The successful replies that the robot's own node sent (docs/security.md): zenoh
    tells who replied, and a reply from any other node is reported and dropped."""
    for reply in replies:
        if reply.ok is None:
            continue
        replier = reply.replier_id
        if robot_zid is not None and (replier is None or str(replier.zid) != robot_zid):
            print(f"placecellctl: ignored a reply on {reply.ok.key_expr} from "
                  f"{replier.zid if replier else 'an unknown node'}, not the robot's node "
                  f"{robot_zid}", file=sys.stderr)
            continue
        yield reply.ok


def query_json(session: zenoh.Session, key: str, timeout_s: float, payload: bytes = b"",
               robot_zid: str | None = None) -> list[dict[str, Any]]:
    out = []
    for sample in from_robot(session.get(key, payload=payload or None, timeout=timeout_s),
                             robot_zid):
        try:
            out.append(zenoh_link.decode(sample.payload.to_bytes()))
        except ValueError:
            continue
    return out


def _unreachable(args: argparse.Namespace, key: str) -> int:
    where = args.connect or f"from {args.config or DEFAULT_CONFIG}"
    print(f"placecellctl: no placecell daemon answered on {key} within {args.timeout:.1f} s "
          f"(is placecelld running? endpoints: {where})", file=sys.stderr)
    return EXIT_UNREACHABLE


def _print(obj: Any) -> None:
    print(json.dumps(obj, separators=(",", ":")), flush=True)


# What to run next, by the daemon's stable reason (or code) for a refusal.
HINTS = {
    "job_running": "wait for it (`placecellctl status` shows it), or stop it with "
                   "`placecellctl abort`",
    "localisation_mode": "switch to mapping first: `placecellctl mode mapping`",
    "map_readonly": "the map file is read-only: `placecellctl status` says why; make it "
                    "writable and restart placecelld",
    "base_not_running": "`placecellctl status` shows the base's last error",
    "camera_not_running": "`placecellctl status` shows the camera's last error",
    "base_cannot_move": "learning needs a base that can move: see [base] in the "
                        "daemon's configuration",
    "localiser_not_running": "`placecellctl status` shows the processing step's last error",
    "empty_map": "learn a place first: `placecellctl learn`",
    "not_found": "`placecellctl places` lists the places",
}


def hint(reply: dict[str, Any]) -> str | None:
    """The placecellctl command to run after an error reply, if there is one."""
    return HINTS.get(str(reply.get("reason") or reply.get("code")))


def _error_exit(reply: dict[str, Any], as_json: bool) -> int:
    if as_json:
        _print(reply)
    else:
        print(f"placecellctl: {reply.get('code')}: {reply.get('message')}", file=sys.stderr)
        advice = hint(reply)
        if advice:
            print(f"  hint: {advice}", file=sys.stderr)
    return _EXIT_OF_CODE.get(str(reply.get("code")), EXIT_REFUSED)


def cmd_learn(args: argparse.Namespace) -> int:
    """Learn a place here: progress while the robot drives the cross, then the place."""
    request: dict[str, Any] = {}
    if args.label is not None:
        request["label"] = args.label
    if args.extent is not None:
        request["extent_m"] = args.extent
    session, robot = open_client(args)
    key = zenoh_link.key(robot, "cmd/learn_place")
    seen = False
    try:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        bar = None if args.json else Progress(
            TextColumn("learning a place: {task.description:18s}"), BarColumn(),
            TextColumn("{task.percentage:>3.0f} %"), TimeElapsedColumn(),
            console=_console())
        task = None
        if bar is not None:
            bar.start()
            task = bar.add_task("starting", total=1.0)
        try:
            # No consolidation: by default zenoh keeps only the last reply per key, and
            # every progress reply carries the same key.
            for sample in from_robot(
                    session.get(key, payload=json.dumps(request).encode(),
                                consolidation=zenoh.ConsolidationMode.NONE,
                                timeout=args.learn_timeout), args.robot_zid):
                try:
                    msg = zenoh_link.decode(sample.payload.to_bytes())
                except ValueError:
                    continue
                seen = True
                kind = msg.get("kind")
                if kind == "progress":
                    if bar is not None and task is not None:
                        bar.update(task, completed=float(msg["fraction"]),
                                   description=str(msg["phase"]))
                    else:
                        _print(msg)
                    continue
                if bar is not None:
                    bar.stop()
                    bar = None
                if kind == "error":
                    return _error_exit(msg, args.json)
                if args.json:
                    _print(msg)
                else:
                    place = msg["place"]
                    links = ", ".join(f"{t['from']} -> {t['to']}" for t in msg["transitions"])
                    print(f"learned place {place['id']} ({place['label'] or 'no label'}): "
                          f"{place['landmarks']} landmarks"
                          + (f"; transitions {links}" if links else ""))
                return EXIT_OK
        finally:
            if bar is not None:
                bar.stop()
    finally:
        session.close()
    if seen:
        print("placecellctl: the daemon stopped answering before learning ended",
              file=sys.stderr)
        return EXIT_FAILED
    return _unreachable(args, key)


def _console() -> Any:
    from rich.console import Console

    return Console(stderr=False)


def _simple_query(args: argparse.Namespace, leaf: str, payload: bytes = b""
                  ) -> tuple[int, dict[str, Any] | None]:
    session, robot = open_client(args)
    key = zenoh_link.key(robot, leaf)
    try:
        replies = query_json(session, key, args.timeout, payload, args.robot_zid)
    finally:
        session.close()
    if not replies:
        return _unreachable(args, key), None
    return EXIT_OK, replies[0]


def _command(args: argparse.Namespace, leaf: str, payload: bytes,
             describe: Callable[[dict[str, Any]], str]) -> int:
    """One query with one reply: an error exits non-zero, a result is printed."""
    code, reply = _simple_query(args, leaf, payload)
    if reply is None:
        return code
    if reply.get("kind") == "error":
        return _error_exit(reply, args.json)
    if args.json:
        _print(reply)
    else:
        print(describe(reply))
    return EXIT_OK


def cmd_abort(args: argparse.Namespace) -> int:
    return _command(args, "cmd/abort", b"", lambda r: (
        f"aborted the {r.get('aborted')} job started by {r.get('started_by', 'operator')}"
        + (f" (label {r['label']!r})" if r.get("label") else "")
        + ": the robot stopped, nothing stored"))


def cmd_places(args: argparse.Namespace) -> int:
    code, reply = _simple_query(args, "map/places")
    if reply is None:
        return code
    if args.json:
        _print(reply)
        return EXIT_OK
    places = reply["places"]
    if not places:
        print("no places learned yet")
    for p in places:
        bg = "unknown" if p["background_lrp"] is None else f"{p['background_lrp']:.3f}"
        print(f"{p['id']:5d}  {p['label'] or '-':20s} {p['landmarks']:3d} landmarks, "
              f"background LRP {bg}")
    return EXIT_OK


def cmd_map(args: argparse.Namespace) -> int:
    """Offline work on a map file: no daemon needed (it may be running and writing)."""
    from daemon.store.export import export_map, import_map
    from daemon.store.sqlite_store import MapStore
    from kernel.errors import MapStoreError

    try:
        if args.map_command == "info":
            with MapStore.open(args.file, None, readonly=True) as store:
                graph = store.load()  # every place decoded, its digest checked...
                for place in graph.places:  # ...and every panorama
                    store.reference_panorama(place.id)
                info: dict[str, Any] = {
                        "file": str(args.file), "schema_version": store.meta("schema_version"),
                        "geometry_checksum": store.meta("geometry_checksum"),
                        "places": len(graph), "transitions": len(graph.transitions),
                        # the file and its write-ahead log: where recent places sit
                        "bytes": _map_bytes(Path(args.file)),
                        "labels": {p.id: p.label for p in graph.places},
                        # design §4-5: what global localisation has to work with
                        "floor_model": graph.floor is not None,
                        "places_with_local_space": sum(p.local_space is not None
                                                       for p in graph.places),
                        "lookalike_pairs": len(graph.features)}
            if args.json:
                _print(info)
            else:
                print(f"{info['file']}: map schema {info['schema_version']}, geometry "
                      f"{info['geometry_checksum']}, {_count(info['places'], 'place')}, "
                      f"{_count(info['transitions'], 'transition')} (both ways), "
                      f"{_size(info['bytes'])}; floor model "
                      f"{'learned' if info['floor_model'] else 'none'}, "
                      f"{_count(info['places_with_local_space'], 'place')} with a local "
                      f"space profile, {_count(info['lookalike_pairs'], 'look-alike pair')} "
                      "with features")
            return EXIT_OK
        if args.map_command == "plot":
            return _plot(args)
        if args.map_command == "export":
            with MapStore.open(args.file, None, readonly=True) as store:
                n = export_map(store, args.folder)
            _done(args, f"exported {n} places to {args.folder}",
                  {"exported": n, "file": str(args.file), "folder": str(args.folder)})
            return EXIT_OK
        n = import_map(args.folder, args.file)
        _done(args, f"imported {n} places into {args.file}",
              {"imported": n, "file": str(args.file), "folder": str(args.folder)})
        return EXIT_OK
    except MapStoreError as e:
        if args.json:
            _print({"kind": "error", "code": "refused", "message": str(e)})
        else:
            print(f"placecellctl: {e}", file=sys.stderr)
        return EXIT_REFUSED


def _live_path(args: argparse.Namespace) -> list[dict[str, float]]:
    """The robot's poses in the `map` frame, as the daemon publishes them over
    ``--duration`` seconds."""
    session, robot = open_client(args)
    poses: queue.Queue[dict[str, float]] = queue.Queue()

    def on_pose(sample: Any) -> None:
        with contextlib.suppress(ValueError, KeyError, TypeError):
            body = zenoh_link.decode(sample.payload.to_bytes())
            if body["map"] is not None:
                poses.put({**body["map"], "stamp_ns": body["stamp_ns"]})

    subscriber = session.declare_subscriber(zenoh_link.key(robot, "pose"), on_pose)
    try:
        time.sleep(args.duration)  # the path is what the robot does in this window
    finally:
        subscriber.undeclare()
        session.close()
    return list(poses.queue)


def _plot(args: argparse.Namespace) -> int:
    """``map plot``: the map file drawn (design §6), with the robot's pose and recent
    path from the running daemon with --live."""
    from daemon.store.sqlite_store import MapStore
    from kernel.se2 import SE2
    from tools import mapplot

    with MapStore.open(args.file, None, readonly=True) as store:
        graph = store.load()
    if args.world and not (args.live and args.truth):
        print("placecellctl: --world needs --live and --truth (the simulator's true poses, "
              "[sim] truth_out): the plan is placed by the robot's path", file=sys.stderr)
        return EXIT_USAGE
    path = _live_path(args) if args.live else []
    pose = SE2(path[-1]["x"], path[-1]["y"], path[-1]["yaw"]) if path else None
    picture = mapplot.draw_map(graph, [(p["x"], p["y"]) for p in path], pose,
                               title=f"{Path(args.file).name}: "
                                     f"{_count(len(graph), 'place')}")
    plan_rms = None
    try:
        if args.world:
            plan_rms = _add_plan(picture, args.world, Path(args.truth), path)
        mapplot.write(picture, Path(args.out))
    except (OSError, ValueError, PlacecellError) as e:
        print(f"placecellctl: {e}", file=sys.stderr)
        return 2
    note = "" if not args.live else (
        f", the robot's last {_count(len(path), 'pose')}" if path
        else f"; no pose in the map frame heard in {args.duration:g} s")
    if plan_rms is not None:
        note += f"; the world's walls placed to {plan_rms:.2f} m (RMS over the path)"
    _done(args, f"drew {_count(len(graph), 'place')} to {args.out}{note}",
          {"file": str(args.file), "out": str(args.out), "places": len(graph),
           "poses": len(path), "plan_rms_m": plan_rms})
    return EXIT_OK


def _add_plan(picture: Any, world: str, truth: Path, path: list[dict[str, float]]) -> float:
    """The simulated world's walls under the map, placed by fitting the true poses of
    ``truth`` (JSON lines with ``stamp_ns``, x, y) to the daemon's path at the same
    stamps. Returns the RMS left (m); ValueError when they cannot be fitted."""
    import numpy as np

    from hal.sim.world import load_world
    from tools import mapplot

    rows = [json.loads(line) for line in truth.read_text().splitlines() if line.strip()]
    if not rows:
        raise ValueError(f"{truth}: no true poses (is it the [sim] truth_out file?)")
    stamps = np.array([r["stamp_ns"] for r in rows], dtype=np.int64)
    pairs = []
    for p in path:
        k = int(np.clip(np.searchsorted(stamps, p["stamp_ns"]), 1, len(stamps) - 1))
        k = k - 1 if abs(stamps[k - 1] - p["stamp_ns"]) < abs(stamps[k] - p["stamp_ns"]) \
            else k
        if abs(int(stamps[k]) - p["stamp_ns"]) <= 100_000_000:  # within 0.1 s
            pairs.append(((p["x"], p["y"]), (rows[k]["x"], rows[k]["y"])))
    T_map_world, rms = mapplot.fit_alignment(pairs)
    walls = [s for w in load_world(world).walls for s in w.segments()]
    mapplot.add_plan(picture, walls, T_map_world)
    return rms


def _done(args: argparse.Namespace, text: str, as_json: dict[str, Any]) -> None:
    if args.json:
        _print(as_json)
    else:
        print(text)


def set_pose_request(args: argparse.Namespace) -> dict[str, Any]:
    """Degrees at the command line, as ``pose`` shows them; radians on the wire (docs/api)."""
    request: dict[str, Any] = {"place": args.place, "x": args.x, "y": args.y,
                               "yaw": math.radians(args.yaw)}
    if args.sigma_xy is not None:
        request["sigma_xy"] = args.sigma_xy
    if args.sigma_yaw is not None:
        request["sigma_yaw"] = math.radians(args.sigma_yaw)
    return request


def cmd_set_pose(args: argparse.Namespace) -> int:
    """Tell the daemon where the robot stands in a place: it tracks from there."""
    def said(r: dict[str, Any]) -> str:
        return (f"pose set: place {r['place']} x {r['x']:+.3f} m, y {r['y']:+.3f} m, "
                f"yaw {math.degrees(r['yaw']):+.1f} deg")

    return _command(args, "cmd/set_pose", json.dumps(set_pose_request(args)).encode(), said)


def format_pose(p: dict[str, Any]) -> str:
    if p.get("x") is None:
        return f"{p['state']}: {p['reason']}"
    cov = p.get("covariance") or [0.0] * 9
    sigma_xy = math.sqrt(max(cov[0] + cov[4], 0.0) / 2)
    place = p["place"]
    label = f" ({place['label']})" if place.get("label") else ""
    return (f"{p['state']} in place {place['id']}{label}: x {p['x']:+.3f} m, "
            f"y {p['y']:+.3f} m, yaw {math.degrees(p['yaw']):+.1f} deg, "
            f"sigma {sigma_xy * 1000:.0f} mm, confidence {p['confidence']:.2f}")


def cmd_pose(args: argparse.Namespace) -> int:
    """The daemon's pose: the next one published, or every one with --follow."""
    return _follow(args, "pose", format_pose, silence_ok=False)


def format_belief(b: dict[str, Any]) -> str:
    """One line a person reads: the state (and the reason only where it adds to it), the
    places' leads over their backgrounds, the frame's timings."""
    where = "" if b.get("place_id") is None else f" in place {b['place_id']}"
    head = f"{b['state']}{where}"
    reason = b.get("reason") or ""
    parts = [head if not reason or reason == head else f"{head} ({reason})",
             f"confidence {b['confidence']:.2f}"]
    scores = b.get("scores", [])[:5]
    parts.append("leads over background: " + (", ".join(
        f"place {sc['place']} {sc['lead']:+.3f}" for sc in scores) if scores else "none"))
    timings = b.get("timings_ms") or {}
    if timings:
        total = timings.get("total", sum(v for k, v in timings.items() if k != "total"))
        stages = ", ".join(f"{k} {v:.1f}" for k, v in timings.items() if k != "total")
        parts.append(f"frame {total:.1f} ms ({stages})")
    return "; ".join(parts)


def cmd_belief(args: argparse.Namespace) -> int:
    """The localiser's belief (places scored, particles, timings): the next one, or every
    one with --follow."""
    return _follow(args, "belief", format_belief, silence_ok=False)


def cmd_mode(args: argparse.Namespace) -> int:
    """Report the daemon's mode, or switch it (mapping | localisation)."""
    payload = json.dumps({"mode": args.mode}).encode() if args.mode else b""
    return _command(args, "cmd/mode", payload, lambda r: f"mode: {r['mode']}")


def cmd_place(args: argparse.Namespace) -> int:
    """One place of the daemon's map; --panorama FILE saves its reference panorama with
    the landmarks drawn (PNG)."""
    session, robot = open_client(args)
    key = zenoh_link.key(robot, f"map/place/{args.id}")
    try:
        info = query_json(session, key, args.timeout, robot_zid=args.robot_zid)
        png = b""
        if info and info[0].get("kind") != "error" and args.panorama:
            png = next((s.payload.to_bytes() for s in from_robot(session.get(
                f"{key}/panorama", timeout=args.timeout), args.robot_zid)), b"")
    finally:
        session.close()
    if not info:
        return _unreachable(args, key)
    if info[0].get("kind") == "error":
        return _error_exit(info[0], args.json)
    if args.panorama:
        if not png.startswith(b"\x89PNG"):
            print(f"placecellctl: no panorama for place {args.id}", file=sys.stderr)
            return EXIT_FAILED
        Path(args.panorama).write_bytes(png)
    p = info[0]
    if args.json:
        _print(p)
    else:
        links = ", ".join(f"{t['to']} ({t['source']})" for t in p["transitions"]) or "none"
        print(f"place {p['id']} {p['label'] or '-'}: {len(p['landmarks'])} landmarks, "
              f"transitions to {links}" + (f"; panorama in {args.panorama}"
                                           if args.panorama else ""))
    return EXIT_OK


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3f}"
    if isinstance(v, str):
        return repr(v) if v else "none"
    if isinstance(v, list | tuple):
        return ", ".join(_value(x) for x in v) if v else "none"
    if v is None:
        return "none"
    return str(v)


def format_event(e: dict[str, Any], at: str = "") -> str:
    """``at`` the time the daemon published it (zenoh's timestamp), then the event and
    its fields as words: ``12:03:04.120 place_learned: place 3, label 'door', ...``."""
    fields = ", ".join(f"{k.replace('_', ' ')} {_value(v)}" for k, v in e.items()
                       if k not in ("schema", "event", "stamp_ns"))
    text = f"{e.get('event')}: {fields}" if fields else str(e.get("event"))
    return f"{at} {text}" if at else text


def cmd_events(args: argparse.Namespace) -> int:
    """The daemon's events (places learned, losses, relocalisations, faults...)."""
    return _follow(args, "events", format_event, silence_ok=True)


def cmd_relocalise(args: argparse.Namespace) -> int:
    return _command(args, "cmd/relocalise", b"", lambda r: (
        f"relocalising: searching {_count(int(r.get('places') or 0), 'place')}"))


def _published_at(sample: Any) -> str:
    """The local time of day the daemon published ``sample`` (its session stamps them)."""
    stamp = sample.timestamp
    if stamp is None:
        return ""
    return stamp.get_time().astimezone().strftime("%H:%M:%S.%f")[:-3]


def _follow(args: argparse.Namespace, leaf: str, fmt: Callable[..., str],
            silence_ok: bool) -> int:
    """The next message on ``leaf``, or every one with --follow (--count, --duration);
    --json prints one object per line. Nothing heard: "not reachable", unless
    ``silence_ok`` (a quiet topic)."""
    session, robot = open_client(args)
    key = zenoh_link.key(robot, leaf)
    messages: queue.Queue[tuple[dict[str, Any], str]] = queue.Queue()

    def on_sample(sample: Any) -> None:
        with contextlib.suppress(ValueError):  # not ours: ignored
            messages.put((zenoh_link.decode(sample.payload.to_bytes()),
                          _published_at(sample)))

    subscriber = zenoh_link.declare_history_subscriber(session, key, on_sample) \
        if leaf == "events" else session.declare_subscriber(key, on_sample)
    shown = 0
    try:
        deadline = time.monotonic() + (args.duration if args.follow else args.timeout)
        while time.monotonic() < deadline:
            try:
                message, at = messages.get(timeout=min(0.2, max(deadline - time.monotonic(),
                                                                 0.01)))
            except queue.Empty:
                continue
            text = json.dumps(message, separators=(",", ":")) if args.json else (
                fmt(message, at) if leaf == "events" else fmt(message))
            print(text, flush=True)
            shown += 1
            if not args.follow or (args.count and shown >= args.count):
                break
    except KeyboardInterrupt:
        pass
    finally:
        subscriber.undeclare()
        session.close()
    if shown == 0 and not silence_ok:
        return _unreachable(args, key)
    return EXIT_OK


def cmd_status(args: argparse.Namespace) -> int:
    session, robot = open_client(args)
    try:
        replies = query_json(session, zenoh_link.key(robot, "status"), args.timeout,
                             robot_zid=args.robot_zid)
    finally:
        session.close()
    if not replies:
        return _unreachable(args, zenoh_link.key(robot, "status"))
    if args.json:
        print(json.dumps(replies[0] if len(replies) == 1 else replies, indent=2))
        return 0
    for st in replies:
        print(format_status(st))
    return 0


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _map_bytes(path: Path) -> int:
    """The map's size on disk: the SQLite file with its write-ahead log (a running daemon
    keeps recent places there until a checkpoint)."""
    return sum(p.stat().st_size for p in (path, Path(f"{path}-wal"), Path(f"{path}-shm"))
               if p.exists())


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return _count(n, "byte")


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
    m = st["map"]
    readonly = "" if m.get("writable", True) else f"; READ-ONLY: {m.get('readonly_reason')}"
    lines.append(f"  map: {_count(m['places'], 'place')} in {m['path']}, {m['mode']} mode"
                 f"{readonly}")
    job = st.get("job")
    lines.append("  job: none" if job is None else
                 f"  job: {job['kind']} ({job['phase']}, {job['fraction']:.0%}) started by "
                 f"{job.get('started_by', 'operator')}")
    for name, comp in st["components"].items():
        err = f", last error {comp['last_error_age_s']} s ago: {comp['last_error']}" \
            if comp.get("last_error") else ""
        lines.append(f"  {name:10s} {comp['state']:8s} {comp['rate_hz']:6.1f} Hz, "
                     f"{comp['restarts']} restarts{err}")
    return "\n".join(lines)


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="placecellctl",
        description="Talk to a running placecell daemon over zenoh: its status, pose, "
                    "belief and events; learn a place, abort, set the pose, relocalise, "
                    "switch modes; and work on map files offline (map info, export, import).")
    parser.add_argument("--config", help=f"the daemon's configuration (default {DEFAULT_CONFIG})")
    parser.add_argument("--connect", action="append",
                        help="zenoh endpoint of the daemon (default: its listen endpoints)")
    parser.add_argument("--robot", help="robot name (default: from the configuration)")
    parser.add_argument("--zenoh-config", metavar="FILE",
                        help="a zenoh JSON5 file with this client's certificate and "
                        "access control (config/zenoh/operator.json5 or viewer.json5; "
                        "docs/security.md), for a daemon with access control")
    parser.add_argument("--timeout", type=float, default=3.0, help="seconds to wait for answers")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("status", help="show the daemon's health, rates and belief")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_status)
    p = sub.add_parser("learn", help="learn a place where the robot stands (it drives a "
                       "Turn-Back-and-Look cross)")
    p.add_argument("--label", help="the place's name")
    p.add_argument("--extent", type=float, help="cross arm in metres (default: [tbl])")
    p.add_argument("--learn-timeout", type=float, default=180.0,
                   help="seconds to wait for the whole job")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=cmd_learn)
    p = sub.add_parser("abort", help="stop the running job (the robot stops; nothing stored)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_abort)
    p = sub.add_parser("set-pose", help="tell the daemon where the robot stands in a place")
    p.add_argument("x", type=float, help="metres, in the place's frame")
    p.add_argument("y", type=float)
    p.add_argument("yaw", type=float, help="degrees")
    p.add_argument("--place", type=int, required=True, help="the place's id")
    p.add_argument("--sigma-xy", type=float, help="how sure, metres (default: the daemon's)")
    p.add_argument("--sigma-yaw", type=float,
                   help="degrees; above 11.5 (0.2 rad) the view decides the heading")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_set_pose)
    for leaf, what, func in (("pose", "the robot's pose in the current place", cmd_pose),
                             ("belief", "the localiser's belief: places scored, timings",
                              cmd_belief),
                             ("events", "the daemon's events (learned, lost, relocalised...)",
                              cmd_events)):
        p = sub.add_parser(leaf, help=what)
        p.add_argument("--follow", action="store_true", help="every one as it is published")
        p.add_argument("--count", type=int, default=0,
                       help="with --follow: stop after this many")
        p.add_argument("--duration", type=float, default=1e9,
                       help="with --follow: stop after this many seconds")
        p.add_argument("--json", action="store_true", help="one JSON object per line")
        p.set_defaults(func=func)
    p = sub.add_parser("relocalise", help="forget the pose and search the whole map")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_relocalise)
    p = sub.add_parser("mode", help="show or switch the mode (mapping: places may be "
                       "learned; localisation: the map is read-only)")
    p.add_argument("mode", nargs="?", choices=["mapping", "localisation"])
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_mode)
    p = sub.add_parser("place", help="one place of the daemon's map")
    p.add_argument("id", type=int)
    p.add_argument("--panorama", metavar="FILE", help="save its panorama, landmarks drawn")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_place)
    p = sub.add_parser("places", help="the places of the daemon's map")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_places)
    p = sub.add_parser("map", help="work on a map file offline")
    msub = p.add_subparsers(dest="map_command", required=True)
    m = msub.add_parser("info", help="what a map file holds (checks every place)")
    m.add_argument("file")
    m.add_argument("--json", action="store_true")
    m = msub.add_parser("plot", help="a picture of the map: places, transitions, segments "
                        "on a metric grid (with --live: the robot's pose and path)")
    m.add_argument("file")
    m.add_argument("--out", required=True, help="the picture: .svg or .png")
    m.add_argument("--live", action="store_true",
                   help="add the robot's pose and recent path from the running daemon")
    m.add_argument("--duration", type=float, default=5.0,
                   help="seconds of the robot's path to collect with --live")
    m.add_argument("--world", help="a simulated robot's world (a file or "
                   "generate:<kind>:<seed>): its walls drawn under the map, placed by the "
                   "path (needs --live and --truth)")
    m.add_argument("--truth", help="the simulator's true poses ([sim] truth_out) for --world")
    m.add_argument("--json", action="store_true")
    m = msub.add_parser("export", help="places and transitions to a folder (JSON, PNGs)")
    m.add_argument("file")
    m.add_argument("folder")
    m.add_argument("--json", action="store_true")
    m = msub.add_parser("import", help="a new map file from an exported folder")
    m.add_argument("folder")
    m.add_argument("file")
    m.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_map)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    try:
        return int(args.func(args))
    except zenoh_link.ConfigError as e:
        print(f"placecellctl: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (`placecellctl status | head -3`): a quiet end, as other
        # command-line tools have; stdout goes to /dev/null so the exit flush is quiet too.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
