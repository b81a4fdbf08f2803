"""The daemon as it runs (docs/design.md §13): ``placecell-bench --only daemon``.

The real daemon process (``python -m daemon``) plays a recorded tour of the office
corridor through its `replay` camera and base at the camera's rate (10 Hz), so no
rendering is counted; this process listens to its beliefs and events over zenoh and reads
its CPU time and memory from /proc. Each figure is the median of the runs (``repeats``,
at most five).

- ``daemon_cpu_{localisation,mapping}``: the process's CPU time over wall time between
  its first and last belief (a share of one core), tracking on a three-place map; mapping
  mode with autonomous acquisition on (the replay base cannot drive a Turn Back and Look,
  so this is mapping outside learning);
- ``daemon_frame_p50_ms_M``, ``daemon_frame_p95_ms_M``: the localiser's time per frame
  (``timings_ms.total``), and ``daemon_stage_p95_ms_M_<stage>`` for each stage
  (unwarp, local_space, positioning, search, recognition, acquisition) over the frames
  that ran it;
- ``daemon_skipped_fraction_M``: frames of the recording that got no belief;
  ``daemon_rss_mb_M``: resident memory at the last belief;
- ``skipped_fraction_loaded``: the same in localisation mode with two busy-loop processes
  on the machine (the daemon not pinned: it shares the cores with them);
- ``start_to_tracking_s_{50,1000}``: from starting the process to its first `tracking`
  pose, on a map of the three places and 47 or 997 others (places cut from views of
  other generated offices, 0.5 m apart along their tours, each office a segment of its
  own), with no saved pose (a global relocalisation at start); ``rss_mb_{50,1000}``: its
  memory five seconds later;
- ``learn_compute_s_{50,1000}``: one learn's computing time after the drive
  (``place_learned.compute_s``) on those maps, the daemon on its simulated robot (the
  only base that drives a Turn Back and Look without hardware).
"""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from daemon.config import load
from daemon.mapping.place import Place, with_cues
from daemon.service.mapper import Mapper
from daemon.store.sqlite_store import MapStore
from hal.recording import TOPIC_FRAMES, RecordingReader
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.panorama import add_wrap_margin, geometry_checksum, to_grey
from kernel.se2 import SE2, UncertainSE2
from tools.bench.global_search import _landmarks
from tools.bench.timing import original_environment
from tools.daemon_process import (
    REPO,
    busy_loops,
    free_port,
    listening_session,
    unpinned,
    usage,
    write_daemon_config,
)
from tools.eval.lockstep import Run, lockstep_config
from tools.eval.tour_map import tour_points

ROBOT = "bench"
WORLD = "generate:office:1"
START = (3.0, 10.0, 0.0)  # the corridor; places every 1.5 m from here
TOUR_S = 30.0
STAGES = ("unwarp", "local_space", "positioning", "search", "recognition", "acquisition")
MAP_SIZES = (50, 1000)
TRACKED_FOR_S = 5.0  # start-up runs: tracking this long, then the memory is read
WAIT_S = 240.0  # any one daemon run gives up after this


# ------------------------------------------------------------------ the fixture
def _learned_map(path: Path) -> None:
    """Three places 1.5 m apart along the corridor, learned by the daemon's own Turn Back
    and Look on the lock-step simulator."""
    with Run(lockstep_config(1, world=WORLD, start_pose=START), map_path=path) as run:
        for i in range(3):
            if i:
                for _ in run.drive(1.5, 0.0, 0.0, 0.3):
                    pass
            run.learn(f"corridor {i + 1}")


def _tour(path: Path, tmp: Path) -> None:
    """TOUR_S seconds up and down the three places, recorded by the simulator with JPEG
    frames: what a USB camera delivers on the `v4l2` backend's default pixel format
    (MJPG), so the replay camera decodes what the real one would (1.5 ms a 640 x 480
    frame; a lossless PNG of the simulator's noisy frames takes 7.5 ms)."""
    from tools.sim_cli import main as sim_main

    scenario = tmp / "tour.toml"
    scenario.write_text(f'name = "bench-tour"\nworld = "{WORLD}"\n'
                        f"start_pose = [{START[0]}, {START[1]}, {START[2]}]\n"
                        '[trajectory]\nkind = "waypoints"\nspeed = 0.3\n'
                        "waypoints = [[5.8, 10.0], [3.2, 10.0], [5.8, 10.0], [3.2, 10.0]]\n")
    with contextlib.redirect_stdout(sys.stderr):
        assert sim_main(["record", str(scenario), "--out", str(path), "--jpeg",
                         "--duration", str(TOUR_S)]) == 0


def _other_offices(count: int) -> Iterator[tuple[int, Place, UncertainSE2 | None]]:
    """``count`` places from generated offices 2, 3, ...: (office, place, the step from
    the office's previous place when they are 0.5 m apart along its tour)."""
    cfg = load(None)
    margin = cfg.panorama.wrap_margin
    made, seed = 0, 2
    step_cov = np.diag([0.01, 0.01, 0.001])
    while made < count:
        world = load_world(f"generate:office:{seed}")
        renderer = Renderer(world, cfg.projection, cfg.panorama, (640, 480))
        previous: tuple[float, float] | None = None
        for x, y in tour_points(world, 0.5):
            if made == count:
                return
            pano = add_wrap_margin(renderer.panorama((x, y, 0.0)), margin)
            place = Place(_landmarks(to_grey(pano), margin), pano,
                          label=f"office {seed} ({x:.1f}, {y:.1f})", created_unix_s=1.7e9)
            step = None if previous is None or math.dist(previous, (x, y)) > 0.75 else \
                UncertainSE2(SE2(x - previous[0], y - previous[1], 0.0), step_cov)
            yield seed, place, step
            previous = (x, y)
            made += 1
        seed += 1


def _grown_map(learned: Path, path: Path, size: int) -> None:
    """The learned map and ``size`` - 3 places of other offices, with every cue the
    daemon stores (backgrounds measured as the mapper does on opening)."""
    shutil.copyfile(learned, path)
    cfg = load(None)
    with MapStore.open(path, geometry_checksum(cfg.projection, cfg.panorama)) as store:
        last = None
        for _, place, step in _other_offices(size - len(store.load())):
            links: list[tuple[int, UncertainSE2, str]] = \
                [] if step is None or last is None else [(last, step, "odometry")]
            last = store.add_place(with_cues(place), links).id
        Mapper(store, cfg.odometry)  # measures the cross backgrounds, once


@dataclass
class Fixture:
    tmp: Path
    tour: Path
    maps: dict[int, Path]  # by size: 3 (learned), 50, 1000
    frames: int  # in the tour


def _fixture(tmp: Path) -> Fixture:
    maps = {3: tmp / "map3.db"}
    _learned_map(maps[3])
    tour = tmp / "tour.mcap"
    _tour(tour, tmp)
    for size in MAP_SIZES:
        maps[size] = tmp / f"map{size}.db"
        _grown_map(maps[3], maps[size], size)
    frames = sum(1 for _ in RecordingReader(tour).messages([TOPIC_FRAMES]))
    return Fixture(tmp, tour, maps, frames)


# ------------------------------------------------------------------ one daemon run
@dataclass
class Observed:
    """What a run of the daemon showed this process."""

    spawned: float  # monotonic time the process was started
    beliefs: list[dict[str, Any]] = field(default_factory=list)
    arrivals: list[float] = field(default_factory=list)
    usage_at: list[tuple[float, float, float]] = field(default_factory=list)  # t, cpu, rss
    first_tracking: float | None = None
    events: list[dict[str, Any]] = field(default_factory=list)
    changed: threading.Condition = field(default_factory=threading.Condition)


@contextlib.contextmanager
def _daemon(run_dir: Path, overrides: dict[str, Any]
            ) -> Iterator[tuple[subprocess.Popen[bytes], Observed, zenoh.Session]]:
    """The daemon in its own process on ``overrides`` (a map file of its own in run_dir),
    its zenoh session connected to one this process listens on (so it hears the first
    pose), its log in run_dir."""
    port = free_port()
    config = run_dir / "placecell.toml"
    write_daemon_config(config, {
        "robot": {"name": ROBOT},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"],
                  "connect": [f"tcp/127.0.0.1:{port}"]},
        **overrides})
    session = listening_session(port)
    seen = Observed(spawned=0.0)  # set when the process is started

    def on_belief(sample: zenoh.Sample) -> None:
        body = json.loads(sample.payload.to_bytes())
        now = time.monotonic()
        with seen.changed:
            seen.beliefs.append(body)
            seen.arrivals.append(now)
            with contextlib.suppress(OSError):  # it may be ending
                use = usage(proc.pid)
                seen.usage_at.append((now, use.cpu_s, use.rss_mb))
            if body["state"] == "tracking" and seen.first_tracking is None:
                seen.first_tracking = now
            seen.changed.notify_all()

    def on_event(sample: zenoh.Sample) -> None:
        with seen.changed:
            seen.events.append(json.loads(sample.payload.to_bytes()))
            seen.changed.notify_all()

    subs = [session.declare_subscriber(f"placecell/{ROBOT}/belief", on_belief),
            session.declare_subscriber(f"placecell/{ROBOT}/events", on_event)]
    log = (run_dir / "daemon.log").open("w")
    seen.spawned = time.monotonic()
    proc = unpinned(subprocess.Popen([sys.executable, "-m", "daemon", "--config", str(config)],
                                      cwd=REPO, stdout=log, stderr=subprocess.STDOUT,
                                      env=original_environment()))
    try:
        yield proc, seen, session
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
        for sub in subs:
            sub.undeclare()
        session.close()
        log.close()


def _wait(seen: Observed, until: Any, what: str, run_dir: Path) -> None:
    with seen.changed:
        if not seen.changed.wait_for(lambda: until(seen), timeout=WAIT_S):
            raise RuntimeError(f"the daemon never {what} within {WAIT_S:.0f} s; "
                               + _log_tail(run_dir))


def _run_dir(fixture: Fixture, name: str, map_size: int) -> tuple[Path, dict[str, Any]]:
    """A fresh directory for one run with a copy of a map, and the setting naming it."""
    run_dir = fixture.tmp / name
    shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.mkdir()
    shutil.copyfile(fixture.maps[map_size], run_dir / "map.db")
    return run_dir, {"map": {"path": str(run_dir / "map.db")}}


def _replay(fixture: Fixture) -> dict[str, Any]:
    """The recorded tour at the camera's rate."""
    return {"camera": {"backend": "replay",
                       "replay": {"file": str(fixture.tour), "speed": 1.0}},
            "base": {"backend": "replay"}}


def tour_run(fixture: Fixture, mode: str, *, loaded: bool = False) -> dict[str, float]:
    """The whole recorded tour, tracking from place 1: CPU, frame times, skipped, RSS."""
    run_dir, map_setting = _run_dir(fixture, f"{mode}{'-loaded' if loaded else ''}", 3)
    overrides = _replay(fixture) | map_setting | {
        "mapping": {"mode": mode, "acquisition": {"enabled": mode == "mapping"}},
        "localisation": {"initial_place": 1, "initial_pose": [0.0, 0.0, 0.0]}}
    with contextlib.ExitStack() as stack:
        if loaded:
            stack.enter_context(busy_loops(2))
        _, seen, session = stack.enter_context(_daemon(run_dir, overrides))
        _wait_for_end(session, run_dir)
        with seen.changed:
            beliefs, use = list(seen.beliefs), list(seen.usage_at)
    (t0, cpu0, _), (t1, cpu1, rss) = use[0], use[-1]
    totals = [b["timings_ms"]["total"] for b in beliefs]
    out = {"cpu": (cpu1 - cpu0) / (t1 - t0),
           "frame_p50_ms": float(np.percentile(totals, 50)),
           "frame_p95_ms": float(np.percentile(totals, 95)),
           "skipped_fraction": max(0.0, 1.0 - len(beliefs) / fixture.frames),
           "rss_mb": rss,
           "tracking_fraction": sum(b["state"] == "tracking" for b in beliefs) / len(beliefs)}
    for stage in STAGES:
        ran = [b["timings_ms"][stage] for b in beliefs if stage in b["timings_ms"]]
        if ran:
            out[f"stage_p95_ms_{stage}"] = float(np.percentile(ran, 95))
    return out


def _wait_for_end(session: zenoh.Session, run_dir: Path) -> None:
    """Until the daemon's camera has played the whole recording (its status says so;
    polled twice a second: no event marks the end of a recording)."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        for reply in session.get(f"placecell/{ROBOT}/status", timeout=5.0):
            if reply.ok is not None:
                camera = json.loads(reply.ok.payload.to_bytes())["components"]["camera"]
                if "end of recording" in str(camera.get("last_error")):
                    return
        time.sleep(0.5)
    raise RuntimeError(f"the replay did not end within {WAIT_S:.0f} s; " + _log_tail(run_dir))


def _log_tail(run_dir: Path) -> str:
    tail = (run_dir / "daemon.log").read_text(errors="replace").splitlines()[-30:]
    return "its log ends:\n" + "\n".join(tail)


def start_run(fixture: Fixture, size: int) -> tuple[float, float]:
    """(seconds from start to the first `tracking` pose, RSS MB TRACKED_FOR_S later)."""
    run_dir, map_setting = _run_dir(fixture, f"start{size}", size)
    overrides = _replay(fixture) | map_setting | {"mapping": {"mode": "localisation"}}
    with _daemon(run_dir, overrides) as (_, seen, _session):
        _wait(seen, lambda s: s.first_tracking is not None, "tracked", run_dir)
        assert seen.first_tracking is not None
        tracked = seen.first_tracking
        _wait(seen, lambda s: s.arrivals[-1] >= tracked + TRACKED_FOR_S,
              f"ran {TRACKED_FOR_S} s after tracking", run_dir)
        return tracked - seen.spawned, seen.usage_at[-1][2]


def learn_run(fixture: Fixture, size: int) -> float:
    """One learn on the simulated robot beside the corridor's places: its computing time
    after the drive."""
    run_dir, map_setting = _run_dir(fixture, f"learn{size}", size)
    overrides = map_setting | {
        "sim": {"world": WORLD, "scenario": "", "start_pose": [4.5, 10.6, 0.0]},
        "mapping": {"mode": "mapping", "acquisition": {"enabled": False}}}
    with _daemon(run_dir, overrides) as (_, seen, session):
        _wait(seen, lambda s: len(s.beliefs) > 0, "published a belief", run_dir)
        for reply in session.get(f"placecell/{ROBOT}/cmd/learn_place", payload=b"{}",
                                 consolidation=zenoh.ConsolidationMode.NONE,
                                 timeout=WAIT_S):
            body = {} if reply.ok is None else json.loads(reply.ok.payload.to_bytes())
            if body.get("kind") == "error":
                raise RuntimeError(f"learning failed: {body}")
        _wait(seen, lambda s: any(e["event"] == "place_learned" for e in s.events),
              "learned a place", run_dir)
        learned = next(e for e in seen.events if e["event"] == "place_learned")
        return float(learned["compute_s"])


def run(repeats: int) -> dict[str, float]:
    runs = max(1, min(repeats, 5))
    figures: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        fixture = _fixture(Path(tmp))
        for mode in ("localisation", "mapping"):
            results = [tour_run(fixture, mode) for _ in range(runs)]
            for key in results[0]:
                values = [r[key] for r in results if key in r]
                name = (f"daemon_stage_p95_ms_{mode}_{key.removeprefix('stage_p95_ms_')}"
                        if key.startswith("stage_") else f"daemon_{key}_{mode}")
                figures[name] = round(statistics.median(values), 3)
        figures["skipped_fraction_loaded"] = round(statistics.median(
            tour_run(fixture, "localisation", loaded=True)["skipped_fraction"]
            for _ in range(runs)), 3)
        for size in MAP_SIZES:
            starts = [start_run(fixture, size) for _ in range(runs)]
            figures[f"start_to_tracking_s_{size}"] = round(
                statistics.median(s for s, _ in starts), 2)
            figures[f"rss_mb_{size}"] = round(statistics.median(r for _, r in starts), 1)
            figures[f"learn_compute_s_{size}"] = round(statistics.median(
                learn_run(fixture, size) for _ in range(runs)), 3)
    return figures
