"""``placecell-eval fleet``: three robots share one map through two fleet routers (issue
"A fleet shares one map", docs/fleet.md).

Every part runs as it does on a site: two ``zenohd`` routers with the storage manager
plugin (tools/fleet_router.py, config/fleet/router.json5), each storing the fleet's key
space and replicating it to the other, and three daemons (``python -m daemon``), each its
own process, map file, simulated robot and truth file, with the autopilot learning places
(mapping mode, autonomous acquisition) and ``[fleet] enabled``. What they do is read as an
operator reads it, by ``placecellctl events|pose --follow`` in processes of their own; the
truth only from the simulator's truth files, by this evaluator:

1. robots A and B drive two stretches of the world's tour (hal/sim/tour.py) that overlap
   by ``--overlap-m``: A the first ``--stretch-m`` from the start, B the next stretch,
   starting ``--overlap-m`` before A's end, at the same time: B maps the overlap first
   and A comes to B's places there at the end of its stretch (two robots reaching one
   spot at the same moment would each learn a place there before either is in the fleet:
   not what this measures); A connects to router 1 first, B to router 2 first, each to
   both;
2. while they drive, router 2 is killed (when A has learned ``--kill-after-places``
   places) and restarted empty ``--router-down-s`` later;
3. once both have stopped at their stretch's end, robot C starts with an empty map at B's
   end and drives ``--c-drive-m`` back along B's way.

Metrics: ``robot_c_frames_to_tracking`` (the frames C's search took, from its
``relocalised`` event, when its first ``tracking`` pose lies within 0.5 m of the truth in
the place it names; None otherwise), ``robot_c_places_learned``,
``place_propagation_s_median`` (from a robot's ``place_learned`` to the other's
``place_adopted`` of it, both stamped on this machine's monotonic clock),
``fleet_segments`` (segments of C's map, which holds every place and transition of the
fleet), ``duplicate_places`` (pairs of places learned by any robot whose true references
stand within 0.3 m), ``router_kill_places_lost`` (places A and B learned that neither
router's storage holds at the end) and ``router_caught_up`` (both storages hold the same
samples, byte for byte); ``learn_failures`` (learns that ended storing nothing, but those
refused) and ``learns_refused`` (an autopilot's learn that, at the end of its drive, found
a place another robot had learned there meanwhile: docs/fleet.md).
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import functools
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from daemon.store.sqlite_store import MapStore
from hal.sim.tour import plan_tour
from hal.sim.world import load_world
from kernel.se2 import SE2
from tools.daemon_process import REPO, free_port, read_json_lines, write_daemon_config
from tools.fleet_router import FleetRouter, client_session, fleet_routers, stored

RIGHT_M = 0.5  # a tracked pose this near the truth is right (design §9's slack)
DUPLICATE_M = 0.3  # two places whose true references stand this near are one place twice
PREFIX = "placecell/fleet"  # [fleet] key_prefix
Point = tuple[float, float]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--stretch-m", type=float, default=10.0,
                        help="the length of each of A's and B's stretches of the tour")
    parser.add_argument("--overlap-m", type=float, default=3.0,
                        help="how much of the tour both A and B drive")
    parser.add_argument("--speed", type=float, default=0.3, help="the autopilot's m/s")
    parser.add_argument("--b-after-s", type=float, default=0.0,
                        help="robot B starts this long after robot A (with --overlap-m "
                             "equal to --stretch-m both drive one way: B comes to each of "
                             "A's spots this much later, while A may still be learning)")
    parser.add_argument("--c-drive-m", type=float, default=2.0,
                        help="how far robot C drives along B's way once it has started")
    parser.add_argument("--kill-after-places", type=int, default=2,
                        help="router 2 is killed once A has learned this many places")
    parser.add_argument("--router-down-s", type=float, default=20.0,
                        help="router 2 is restarted (empty) this long after its kill")
    parser.add_argument("--start-s", type=float, default=60.0,
                        help="the longest a router or daemon may take to start, and a "
                             "restarted router to catch up (a loaded machine)")
    parser.add_argument("--timeout-s", type=float, default=1800.0,
                        help="the longest the tours may take before the run is given up")
    parser.add_argument("--keep", default="",
                        help="a folder to keep the configurations, logs, map files, "
                             "events, poses and truth files in (default: a temporary one)")


# ----------------------------------------------------------------- pure rules


def along(points: list[Point], s: float) -> Point:
    """The point ``s`` metres along the polyline ``points`` (clamped to its ends)."""
    for a, b in zip(points[:-1], points[1:], strict=True):
        leg = math.dist(a, b)
        if s <= leg and leg > 0:
            f = max(0.0, s / leg)
            return a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])
        s -= leg
    return points[-1]


def stretch(points: list[Point], start_m: float, end_m: float, step_m: float = 0.5
            ) -> list[Point]:
    """The polyline ``points`` from ``start_m`` to ``end_m`` along it (backwards when
    ``end_m`` < ``start_m``), as waypoints every ``step_m`` and at each corner."""
    lo, hi = sorted((start_m, end_m))
    marks = [lo + k * step_m for k in range(int((hi - lo) / step_m) + 1)] + [hi]
    s, corners = 0.0, []
    for a, b in zip(points[:-1], points[1:], strict=True):
        s += math.dist(a, b)
        if lo < s < hi:
            corners.append(s)
    keep = corners + [lo, hi]  # a mark this near one of them would be a leg of nothing
    marks = [m for m in marks if min(abs(m - k) for k in keep) >= 0.1]
    out = [along(points, m) for m in sorted(set(marks + keep))]
    return out if end_m >= start_m else out[::-1]


def propagation_s(learned: dict[str, list[dict[str, Any]]],
                  adopted: dict[str, list[dict[str, Any]]]) -> list[float]:
    """Seconds from each ``place_learned`` of a robot to another robot's ``place_adopted``
    of that place (``learned`` and ``adopted``: each robot's events); a place some
    robot never took is left out (``propagated`` counts them)."""
    out = []
    for robot, events in learned.items():
        for e in events:
            for other, taken in adopted.items():
                if other == robot:
                    continue
                got = [a for a in taken if a["robot"] == robot and a["origin_id"] == e["place"]]
                if got:
                    out.append((got[0]["stamp_ns"] - e["stamp_ns"]) / 1e9)
    return out


def duplicate_pairs(references: list[Point], within_m: float = DUPLICATE_M) -> int:
    """Pairs of places whose true references stand within ``within_m`` of each other."""
    return sum(1 for i, a in enumerate(references) for b in references[i + 1:]
               if math.dist(a, b) < within_m)


# ----------------------------------------------------------------- what is read


class Truth:
    """A simulated robot's truth file (``[sim] truth_out``): its pose per simulation step
    with the stamps its frames carry."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._all: list[tuple[int, float, float, float]] | None = None
        self._stamps: list[int] = []

    def samples(self, tail_bytes: int | None = None) -> list[tuple[int, float, float, float]]:
        if not self.path.exists():
            return []
        with self.path.open("rb") as f:
            if tail_bytes is not None:
                f.seek(max(0, self.path.stat().st_size - tail_bytes))
            lines = f.read().decode(errors="replace").splitlines()
        out = []
        for line in lines:
            try:
                d = json.loads(line)
                out.append((int(d["stamp_ns"]), float(d["x"]), float(d["y"]), float(d["yaw"])))
            except (json.JSONDecodeError, KeyError, ValueError):
                continue  # the line being written, or cut by the tail
        return out

    def at(self, stamp_ns: int) -> SE2:
        """The true pose at the step nearest ``stamp_ns`` (read once the run is over)."""
        if self._all is None:
            self._all = self.samples()
            self._stamps = [p[0] for p in self._all]
        k = bisect.bisect_left(self._stamps, stamp_ns)
        near = min((i for i in (k - 1, k) if 0 <= i < len(self._all)),
                   key=lambda i: abs(self._stamps[i] - stamp_ns))
        return SE2(*self._all[near][1:])

    def stopped_at(self, goal: Point, still_s: float, near_m: float = 0.2) -> bool:
        """The robot has stood within ``near_m`` of ``goal`` for the last ``still_s``."""
        s = self.samples(tail_bytes=200_000)
        if not s or s[-1][0] - s[0][0] < still_s * 1e9:
            return False
        recent = [p for p in s if p[0] >= s[-1][0] - still_s * 1e9]
        return all(math.dist(p[1:3], goal) <= near_m for p in recent) and max(
            math.dist(recent[0][1:3], p[1:3]) for p in recent) < 1e-4


# ----------------------------------------------------------------- the robots


@dataclass
class Robot:
    """One daemon, its files and its followers."""

    name: str
    folder: Path
    waypoints: list[Point]
    connect: list[str]
    seed: int
    world: str
    speed: float
    proc: subprocess.Popen[str] | None = None

    @property
    def config(self) -> Path:
        return self.folder / "placecell.toml"

    @functools.cached_property
    def truth(self) -> Truth:
        return Truth(self.folder / "truth.jsonl")

    @property
    def events(self) -> list[dict[str, Any]]:
        return read_json_lines(self.folder / "events.jsonl")

    @property
    def poses(self) -> list[dict[str, Any]]:
        return read_json_lines(self.folder / "poses.jsonl")

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e.get("event") == kind]

    def write(self, start_s: float) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        (x0, y0), (x1, y1) = self.waypoints[0], self.waypoints[1]
        scenario = self.folder / "scenario.toml"
        scenario.write_text("\n".join([
            f'name = "{self.name}"', f'world = "{self.world}"',
            f"start_pose = [{x0!r}, {y0!r}, {math.atan2(y1 - y0, x1 - x0)!r}]",
            "frame_rate_hz = 10.0", "[trajectory]", 'kind = "waypoints"',
            f"speed = {self.speed!r}", "face_travel = true", "start_after_s = 3.0",
            "resume_after_s = 3.0",
            f"waypoints = {json.dumps([list(p) for p in self.waypoints[1:]])}"]) + "\n")
        write_daemon_config(self.config, {
            "robot": {"name": self.name},
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"], "connect": self.connect},
            "map": {"path": str(self.folder / "map.db")},
            "mapping": {"mode": "mapping", "acquisition": {"enabled": True}},
            "fleet": {"enabled": True, "fetch_timeout_s": start_s},
            "sim": {"world": self.world, "scenario": str(scenario), "seed": self.seed,
                    "truth_out": str(self.folder / "truth.jsonl")}})

    @contextmanager
    def running(self, stack_timeout_s: float) -> Iterator[Robot]:
        ctl = str(Path(sys.executable).with_name("placecellctl"))
        with (self.folder / "daemon.log").open("a") as log:
            self.proc = subprocess.Popen([sys.executable, "-m", "daemon", "--config",
                                          str(self.config)], cwd=REPO, stdout=log,
                                         stderr=subprocess.STDOUT, text=True)
        followers = [subprocess.Popen(
            [ctl, "--config", str(self.config), leaf, "--follow", "--json", "--duration",
             str(int(stack_timeout_s))], cwd=REPO, stdout=(self.folder / out).open("w"),
            stderr=subprocess.DEVNULL, text=True)
            for leaf, out in (("events", "events.jsonl"), ("pose", "poses.jsonl"))]
        try:
            yield self
        finally:
            for p in followers:
                p.terminate()
            self.proc.terminate()  # the daemon stops cleanly: its map file closed
            try:
                self.proc.wait(stack_timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
            for p in followers:
                p.wait(10)

    def alive(self) -> None:
        if self.proc is not None and self.proc.poll() is not None:
            raise RuntimeError(f"{self.name}'s daemon exited ({self.proc.returncode}): "
                               f"{(self.folder / 'daemon.log').read_text()[-3000:]}")

    def done(self) -> bool:
        """Stopped at its last waypoint (its autopilot and learns over)."""
        self.alive()
        return self.truth.stopped_at(self.waypoints[-1], still_s=6.0)


def wait_until(what: str, done: Callable[[], bool], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > end:
            raise RuntimeError(f"fleet: {what} did not happen within {timeout_s:.0f} s")
        time.sleep(0.5)


# ----------------------------------------------------------------- the run


def _world(args: argparse.Namespace) -> str:
    return f"generate:{args.world_kind}:{args.world_seed}"


def run(args: argparse.Namespace) -> dict[str, Any]:
    world_spec = _world(args)
    tour = [tuple(p) for p in plan_tour(load_world(world_spec))]
    a_way = stretch(tour, 0.0, args.stretch_m)  # type: ignore[arg-type]
    b_way = stretch(tour, args.stretch_m - args.overlap_m,  # type: ignore[arg-type]
                    2 * args.stretch_m - args.overlap_m)
    c_way = stretch(b_way[::-1], 0.0, args.c_drive_m)
    kept = contextlib.nullcontext(args.keep) if args.keep else \
        tempfile.TemporaryDirectory(prefix="placecell-fleet-")
    with kept as where:  # the files outlive the processes: the report reads them
        folder = Path(where)
        folder.mkdir(parents=True, exist_ok=True)
        with ExitStack() as stack:  # left: the daemons stop, their map files closed
            out = _run(args, folder, stack, a_way, b_way, c_way, world_spec)
        return _report(args, *out, folder)


def _run(args: argparse.Namespace, folder: Path, stack: ExitStack, a_way: list[Point],
         b_way: list[Point], c_way: list[Point], world_spec: str
         ) -> tuple[Robot, Robot, Robot, dict[str, dict[str, str]], bool, bool, float]:
    """The routers and the robots in ``stack``, the tours driven; what the report needs."""
    ports = [free_port(), free_port()]
    r1, r2 = stack.enter_context(fleet_routers(ports, folder, args.start_s))
    both = [r1.endpoint, r2.endpoint]
    a = Robot("fleet-a", folder / "a", a_way, both, args.seed, world_spec, args.speed)
    b = Robot("fleet-b", folder / "b", b_way, both[::-1], args.seed + 1, world_spec,
              args.speed)
    c = Robot("fleet-c", folder / "c", c_way, both, args.seed + 2, world_spec, args.speed)
    for robot in (a, b, c):
        robot.write(args.start_s)
    started = time.monotonic()
    stack.enter_context(a.running(args.timeout_s))
    time.sleep(args.b_after_s)
    stack.enter_context(b.running(args.timeout_s))
    killed = _kill_during_tour(args, a, b, r2)
    wait_until("A's and B's tours", lambda: a.done() and b.done(),
               args.timeout_s - (time.monotonic() - started))
    tours_s = time.monotonic() - started
    stack.enter_context(c.running(args.timeout_s))
    wait_until("C's drive", c.done, args.timeout_s)
    with contextlib.suppress(RuntimeError):  # a C that never tracks is a result
        wait_until("C's tracking", lambda: len(
            [p for p in c.poses if p.get("state") == "tracking"]) >= 30, args.start_s)
    watcher = client_session(r1.endpoint)
    try:
        caught_up = _caught_up(watcher, [r1, r2], args.start_s)
        storages = stored(watcher, f"{PREFIX}/**")
    finally:
        watcher.close()
    return a, b, c, storages, caught_up, killed, tours_s


def _kill_during_tour(args: argparse.Namespace, a: Robot, b: Robot, router: FleetRouter
                      ) -> bool:
    """Router 2 killed once A has learned ``--kill-after-places`` places, and restarted
    empty ``--router-down-s`` later (the tours drive on meanwhile)."""
    wait_until(f"A's {args.kill_after_places} places",
               lambda: len(a.of("place_learned")) >= args.kill_after_places or a.done(),
               args.timeout_s)
    if a.done():
        return False
    router.stop()
    end = time.monotonic() + args.router_down_s
    while time.monotonic() < end:
        a.alive()
        b.alive()
        time.sleep(0.5)
    router.start(args.start_s)
    return True


def _caught_up(session: zenoh.Session, routers: list[FleetRouter], timeout_s: float) -> bool:
    """Both storages hold the same samples (within ``timeout_s``: the replicas align every
    few seconds)."""
    end = time.monotonic() + timeout_s
    while True:
        held = stored(session, f"{PREFIX}/**")
        same = len(held) == len(routers) and len({json.dumps(v, sort_keys=True)
                                                  for v in held.values()}) == 1
        if same or time.monotonic() > end:
            return same
        time.sleep(1.0)


def _references(robot: Robot) -> dict[int, SE2]:
    """The true reference pose of each place ``robot`` learned (its id there)."""
    return {e["place"]: robot.truth.at(e["reference_stamp_ns"])
            for e in robot.of("place_learned")}


def _own_and_taken(robot: Robot) -> tuple[int, int]:
    """How many places of ``robot``'s map it learned itself, and how many it took."""
    with MapStore.open(robot.folder / "map.db", None, readonly=True) as store:
        taken = len(store.origins())
        return store.place_count() - taken, taken


def segments_in(path: Path) -> int:
    """The segments of the map file at ``path`` (read only)."""
    with MapStore.open(path, None, readonly=True) as store:
        return len(set(store.load().segments().values()))


def _places(robot: Robot, refs: dict[str, dict[int, SE2]]) -> dict[int, tuple[str, SE2]]:
    """Each place of ``robot``'s map (its id there): the robot that learned it and its
    true reference pose."""
    with MapStore.open(robot.folder / "map.db", None, readonly=True) as store:
        origins = store.origins()
        ids = [p.id for p in store.summaries()]
    out = {}
    for place_id in ids:
        learner, origin_id = origins.get(place_id, (robot.name, place_id))
        if origin_id in refs.get(learner, {}):
            out[place_id] = (learner, refs[learner][origin_id])
    return out


def _error_m(robot: Robot, pose: dict[str, Any], places: dict[int, tuple[str, SE2]]
             ) -> float | None:
    """How far a ``tracking`` pose lies from the truth, in the place it names."""
    if pose["place"]["id"] not in places:
        return None
    estimate = places[pose["place"]["id"]][1].compose(SE2(pose["x"], pose["y"], pose["yaw"]))
    true = robot.truth.at(pose["stamp_ns"])
    return math.hypot(estimate.x - true.x, estimate.y - true.y)


@dataclass(frozen=True)
class Tracked:
    """What a robot's poses say, judged against its truth."""

    frames: int  # poses published
    right: int  # tracking within RIGHT_M of the truth in the place named
    wrong: int  # tracking farther off
    in_others_places: int  # right, in a place another robot learned
    first_error_m: float | None  # of the first tracking pose


def _tracked(robot: Robot, refs: dict[str, dict[int, SE2]]) -> Tracked:
    places = _places(robot, refs)
    errors = [(p, _error_m(robot, p, places)) for p in robot.poses
              if p.get("state") == "tracking"]
    right = [p for p, e in errors if e is not None and e <= RIGHT_M]
    return Tracked(len(robot.poses), len(right), len(errors) - len(right),
                   sum(1 for p in right if places[p["place"]["id"]][0] != robot.name),
                   errors[0][1] if errors else None)


def _report(args: argparse.Namespace, a: Robot, b: Robot, c: Robot,
            storages: dict[str, dict[str, str]], caught_up: bool, killed: bool,
            tours_s: float, folder: Path) -> dict[str, Any]:
    refs = {r.name: _references(r) for r in (a, b, c)}
    took = propagation_s({r.name: r.of("place_learned") for r in (a, b)},
                         {r.name: r.of("place_adopted") for r in (a, b)})
    learned_keys = {f"{PREFIX}/{r.name}/place/{e['place']}" for r in (a, b)
                    for e in r.of("place_learned")}
    held = set().union(*(set(s) for s in storages.values())) if storages else set()
    tracked = {r.name: _tracked(r, refs) for r in (a, b, c)}
    first_error = tracked[c.name].first_error_m
    found = c.of("relocalised")
    frames = found[0]["frames"] if found and first_error is not None and \
        first_error <= RIGHT_M else None
    every = [(ref.x, ref.y) for by_robot in refs.values() for ref in by_robot.values()]
    across = [math.dist((p.x, p.y), (q.x, q.y)) for p in refs[a.name].values()
              for q in refs[b.name].values()]
    return {
        "world": {"spec": _world(args)},
        "config": {"stretch_m": args.stretch_m, "overlap_m": args.overlap_m,
                   "speed_m_s": args.speed, "c_drive_m": args.c_drive_m,
                   "kill_after_places": args.kill_after_places,
                   "router_down_s": args.router_down_s, "b_after_s": args.b_after_s,
                   "folder": str(folder)},
        "metrics": {
            "robot_c_frames_to_tracking": frames,
            "robot_c_first_tracking_error_m": (None if first_error is None
                                               else round(first_error, 3)),
            # from C's map file: the events of its first seconds (every place taken at
            # start) may be more than its event publisher keeps for a late follower
            **dict(zip(("robot_c_places_learned", "robot_c_places_taken"),
                       _own_and_taken(c), strict=True)),
            "place_propagation_s_median": round(statistics.median(took), 3) if took else None,
            "place_propagation_s_max": round(max(took), 3) if took else None,
            "places_propagated": len(took),
            "places_learned_a": len(a.of("place_learned")),
            "places_learned_b": len(b.of("place_learned")),
            "fleet_segments": segments_in(c.folder / "map.db"),
            "segments_a": segments_in(a.folder / "map.db"),
            "segments_b": segments_in(b.folder / "map.db"),
            "duplicate_places": duplicate_pairs(every),
            "nearest_a_b_places_m": round(min(across), 3) if across else None,
            "router_killed": killed,
            "router_kill_places_lost": len(learned_keys - held),
            "router_caught_up": caught_up,
            "learn_failures": sum(e.get("code") != "refused" for r in (a, b, c)
                                  for e in r.of("learning_ended")),
            "learns_refused": sum(e.get("code") == "refused" for r in (a, b, c)
                                  for e in r.of("learning_ended")),
            "tours_s": round(tours_s, 1),
            **{f"{key}_{r.name[-1]}": value for r in (a, b, c)
               for key, value in (("tracking_right_fraction",
                                   round(tracked[r.name].right / max(1, tracked[r.name].frames),
                                         3)),
                                  ("tracking_wrong_frames", tracked[r.name].wrong),
                                  ("frames_right_in_others_places",
                                   tracked[r.name].in_others_places))},
        },
    }
