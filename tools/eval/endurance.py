"""``placecell-eval endurance``: the daemon left to its job in mapping mode (design §6,
issue 31 "never stuck"): a tour of every room, lap after lap, with autonomous acquisition,
kidnaps into mapped and into unmapped space, restarts and an operator's learns.

The simulated robot runs in lock-step (tools/eval/lockstep.py) through the daemon's own
pieces: every frame goes through the Localiser and its belief through the
MappingSession, which stores what it changes and decides when the autopilot learns
(``wants_place``), as the daemon's processing thread does; Turn Back and Look is the
daemon's loop. The evaluator (and only it) reads the truth:

- *kidnaps into mapped space* carry the robot to the true reference of a place learned
  earlier (a random heading), and its autopilot drives on along the tour from there;
- *kidnaps into unmapped space* carry it ahead along the tour to a point at least
  ``--unmapped-from`` m from every place learned, skipping a stretch the map has never
  seen (later laps come back through it and through the first area);
- a *restart* is a fresh daemon state on the same map file (a new Mapper, MappingSession
  and Localiser), resumed from the pose tracked last, as the daemon saves and resumes it;
- an *operator's learn* is a learn asked for by name (the operator pre-empting the
  autopilot, as the daemon lets it): from its time on, the next time the autopilot wants a
  place, the operator's learn is made there instead — or sooner, where the operator sees
  the robot stand ``OPERATOR_ROOM_M`` from every place (truth decides when the operator
  acts, never what the daemon does);
- a lap cut short (``--waypoints``) comes back to its start along the shortest way round
  the walls (hal/sim/tour.py ``close_lap``).

Metrics: ``tracking_fraction`` (of the frames the localiser sees, those ``tracking``
within 0.5 m of the truth in the place it names: the right place, or in a new segment
the place just learned), ``tracking_wrong_fraction`` (``tracking`` while off by more
than both 0.5 m and three times the published sigma), ``mapped_kidnap_recovered_within_10``
(fraction), ``unmapped_kidnap_tracking_within_s`` (worst, simulated seconds to the first
right ``tracking`` frame, the learn included), ``duplicate_places`` (pairs of places whose
true references stand within 0.3 m), ``segments_final``, ``coverage`` (a second pass
along one lap with the final map, as ``placecell-eval mapping`` measures it),
``learn_failures``, ``operator_learns`` and ``operator_learns_refused``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from daemon.config import PlacecellConfig, load
from daemon.localisation.belief import Belief
from daemon.store.sqlite_store import SavedPose
from hal.sim.scenario import Scenario, Waypoint, scenario_from_dict
from hal.sim.tour import close_lap
from hal.sim.world import load_world
from kernel.errors import LearningError, PlacecellError
from tools.eval import mapping
from tools.eval.lockstep import Run

RIGHT_M = 0.5  # a tracked pose this near the truth is right (design §9's slack)
DUPLICATE_M = 0.3  # two places whose references stand this near are one place twice
# An operator learns where no place stands this near (places along a path stand ~1.2 m
# apart, so the autopilot's min_distance_m, 0.75 m, is found nowhere on a mapped path).
OPERATOR_ROOM_M = 0.5


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--laps", type=int, default=2)
    p.add_argument("--speed", type=float, default=0.4, help="tour speed, m/s")
    p.add_argument("--frame-rate", type=float, default=5.0, help="camera frames per second")
    p.add_argument("--waypoints", type=int, default=0,
                   help="only the first N waypoints of each lap, then the shortest way "
                   "back to its start (0: the whole tour)")
    p.add_argument("--restarts", type=int, default=3)
    p.add_argument("--mapped-kidnaps", type=int, default=3)
    p.add_argument("--unmapped-kidnaps", type=int, default=1)
    p.add_argument("--operator-learns", type=int, default=2)
    p.add_argument("--unmapped-from", type=float, default=3.0,
                   help="an unmapped kidnap's release this far from every place, m")
    p.add_argument("--after", type=int, default=10,
                   help="a mapped kidnap is recovered within this many frames")
    p.add_argument("--max-sim-s", type=float, default=20000.0,
                   help="stop after this much simulated time")
    p.add_argument("--world", help="a world file or generate:<kind>:<seed> (default: from "
                   "--world-kind and --world-seed)")
    p.add_argument("--trace", help="write one JSON line per frame here (state, place, "
                   "error, sigma, confidence, event): where wrong frames come from")


@dataclass
class Tally:
    """What the evaluator counts, frame by frame (truth side)."""

    frames: int = 0
    right: int = 0
    wrong: int = 0
    wrong_after_kidnap: int = 0  # of those, within --after frames of a kidnap
    kidnap_frame: int = -10**9  # the frame of the last kidnap
    wrong_confidence: list[float] = field(default_factory=list)  # of the wrong frames
    learn_failures: int = 0
    operator_learns: int = 0
    operator_refused: int = 0
    mapped: list[bool] = field(default_factory=list)  # recovered within --after
    unmapped_s: list[float] = field(default_factory=list)
    # An open kidnap: (kind, frame it happened, simulated s it happened).
    open_kidnap: tuple[str, int, float] | None = None
    events: list[dict[str, Any]] = field(default_factory=list)


def _scenario(args: argparse.Namespace, laps: int) -> Scenario:
    scenario = scenario_from_dict({
        "name": "endurance-tour", "world": mapping.world_spec(args),
        "frame_rate_hz": args.frame_rate,
        "trajectory": {"kind": "tour", "speed": args.speed, "laps": 1,
                       "resume_after_s": 1.0}})
    lap = scenario.waypoints
    if args.waypoints and args.waypoints < len(lap):  # cut short, and back to the start
        speed = lap[0].speed                             # round the walls
        lap = tuple(Waypoint(x, y, speed) for x, y in close_lap(
            load_world(mapping.world_spec(args)), [(w.x, w.y) for w in lap[:args.waypoints]]))
    return dataclasses.replace(scenario, waypoints=tuple(lap) * laps)


def _config(args: argparse.Namespace) -> PlacecellConfig:
    base = load(None)
    return dataclasses.replace(
        base, sim=dataclasses.replace(base.sim, realtime=False, seed=args.seed, scenario=""),
        mapping=dataclasses.replace(base.mapping, acquisition=dataclasses.replace(
            base.mapping.acquisition, enabled=True)))


def _schedule(args: argparse.Namespace, waypoints: int) -> list[tuple[int, str]]:
    """(waypoint index, action), in the order they come: unmapped kidnaps in the first
    lap's first half (there is a stretch ahead to skip), the rest spread over the tour."""
    actions = ["restart"] * args.restarts + ["mapped"] * args.mapped_kidnaps \
        + ["operator"] * args.operator_learns
    lap = waypoints // max(args.laps, 1)
    out = [(max(1, int(lap * (k + 1) / (2 * args.unmapped_kidnaps + 2))), "unmapped")
           for k in range(args.unmapped_kidnaps)]
    for k, action in enumerate(actions):
        out.append((max(2, int(waypoints * (k + 1) / (len(actions) + 1))), action))
    return sorted(out)


def _error(r: Run, belief: Belief) -> float | None:
    return r.error_m(belief) if belief.place_id in r.references else None


def _yaw_error_deg(r: Run, belief: Belief) -> float | None:
    """The belief's heading against the truth in its place, degrees (trace only)."""
    if belief.place_id is None or belief.pose_in_place is None:
        return None
    yaw = belief.pose_in_place[2] - r.truth_in(belief.place_id).yaw
    return round(math.degrees(math.remainder(yaw, 2 * math.pi)), 1)


def _sigma(belief: Belief) -> float:
    if belief.covariance is None:
        return math.inf
    c = np.array(belief.covariance).reshape(3, 3)[:2, :2]
    return math.sqrt(max(float(np.linalg.eigvalsh(c).max()), 0.0))


class Endurance:
    """One endurance run (module docstring)."""

    def __init__(self, args: argparse.Namespace, r: Run, scenario: Scenario) -> None:
        self.args = args
        self.r = r
        self.waypoints = [(w.x, w.y) for w in scenario.waypoints]
        self.tally = Tally()
        self.learned_at: dict[int, int] = {}  # place -> the autopilot's waypoint then
        self.saved: SavedPose | None = None  # where a restart resumes
        self.operator_due = 0  # operator learns asked for and not yet made
        self.rng = np.random.default_rng(args.seed)
        self.trace = None if not getattr(args, "trace", None) else \
            open(args.trace, "w", encoding="utf-8")  # noqa: SIM115 (closed by run())

    def _trace(self, belief: Belief, error: float | None) -> None:
        r = self.r
        x, y, _ = r.robot.true_pose()
        nearest = min(r.references, default=None,
                      key=lambda p: math.dist((x, y),
                                              (r.references[p].x, r.references[p].y)))
        assert self.trace is not None
        self.trace.write(json.dumps({
            "frame": self.tally.frames, "t_s": round(r.robot.now_ns() / 1e9, 2),
            "state": belief.state, "place": belief.place_id, "nearest": nearest,
            "error_m": None if error is None else round(error, 3),
            "yaw_error_deg": _yaw_error_deg(r, belief) if error is not None else None,
            "sigma_m": round(_sigma(belief), 3) if belief.covariance else None,
            "confidence": belief.confidence,
            "event": None if belief.event is None else
            f"{belief.event.kind} {belief.event.place_id} {belief.event.how}",
            "switched_from": belief.switched_from, "reason": belief.reason,
            "low_frames": r.localiser.reloc.loss.low_frames,
            "support": belief.support}) + "\n")

    def run(self) -> None:
        r, args = self.r, self.args
        r.restart(r.cfg.mapping.acquisition)  # the localiser as the daemon runs it
        todo = _schedule(args, len(self.waypoints))
        while not r.robot.autopilot_done() and r.robot.now_ns() / 1e9 < args.max_sim_s:
            while todo and r.robot.waypoint >= todo[0][0]:
                self._act(todo.pop(0)[1])
            self._frame()
        if self.trace is not None:
            self.trace.close()

    def _frame(self) -> None:
        r, t = self.r, self.tally
        _, belief = r.step()
        t.frames += 1
        error = _error(r, belief)
        tracking = belief.state == "tracking" and error is not None
        right = tracking and error is not None and error <= RIGHT_M
        t.right += right
        if tracking and error is not None and error > max(RIGHT_M, 3 * _sigma(belief)):
            t.wrong += 1
            t.wrong_after_kidnap += t.frames - t.kidnap_frame <= self.args.after
            t.wrong_confidence.append(belief.confidence)
        if self.trace is not None:
            self._trace(belief, error)
        if belief.state == "tracking" and belief.place_id is not None \
                and belief.pose_in_place is not None and belief.covariance is not None:
            self.saved = SavedPose(belief.place_id, belief.pose_in_place,
                                   np.array(belief.covariance).reshape(3, 3), 0.0)
        if t.open_kidnap is not None:
            kind, frame, at_s = t.open_kidnap
            if kind == "mapped" and (right or t.frames - frame > self.args.after):
                t.mapped.append(right)
                t.open_kidnap = None
            elif kind == "unmapped" and right:
                t.unmapped_s.append(r.robot.now_ns() / 1e9 - at_s)
                t.open_kidnap = None
        why = r.session.wants_place(belief, r.localiser.odometry.latest, job_running=False)
        if self.operator_due and (why is not None or self._operator_sees_room()):
            self.operator_due -= 1
            t.operator_learns += 1
            try:
                if not self._learn("operator", f"the operator asked ({why or 'room'})"):
                    t.operator_refused += 1
            except PlacecellError:
                t.operator_refused += 1
        elif why is not None:
            self._learn("autopilot", why)
        elif belief.acquisition is not None:
            r.localiser.learning_not_started()  # not now: acquisition asks again

    def _learn(self, started_by: str, why: str) -> bool:
        r = self.r
        r.session.learning_started()
        waypoint = r.robot.waypoint
        try:
            place = r.learn(f"{started_by} {len(r.references) + 1}")
        except LearningError as e:
            self.tally.learn_failures += 1
            self.tally.events.append({"t_s": round(r.robot.now_ns() / 1e9, 1),
                                      "event": "learn_failed", "why": str(e)})
            return False
        self.learned_at[place.id] = waypoint
        self.tally.events.append({"t_s": round(r.robot.now_ns() / 1e9, 1),
                                  "event": "learned", "place": place.id, "by": started_by,
                                  "why": why})
        return True

    def _operator_sees_room(self) -> bool:
        """The operator, who sees the robot and the map's places, finds no place within
        ``OPERATOR_ROOM_M`` of it (truth decides when the operator acts, never what the
        daemon does)."""
        x, y, _ = self.r.robot.true_pose()
        return all(math.dist((x, y), (ref.x, ref.y)) >= OPERATOR_ROOM_M
                   for ref in self.r.references.values())

    def _act(self, action: str) -> None:
        r, t = self.r, self.tally
        now_s = r.robot.now_ns() / 1e9
        if action == "restart":
            r.restart(r.cfg.mapping.acquisition, self.saved)
        elif action == "operator":
            self.operator_due += 1
        elif action == "mapped" and self.learned_at:
            # A place learned earlier; the autopilot drives on from where it was heading
            # then, in this lap (at most a lap driven again).
            place = int(self.rng.choice(sorted(self.learned_at)))
            ref, here = r.references[place], r.robot.waypoint
            lap = max(1, len(self.waypoints) // max(self.args.laps, 1))
            heading = self.learned_at[place]
            r.robot.kidnap(ref.x, ref.y, float(self.rng.uniform(-math.pi, math.pi)),
                           waypoint=here - (here - heading) % lap if heading <= here
                           else heading)
            t.open_kidnap, t.kidnap_frame = ("mapped", t.frames, now_s), t.frames
        elif action == "unmapped":
            refs = [(ref.x, ref.y) for ref in r.references.values()]
            ahead = [k for k in range(r.robot.waypoint + 1, len(self.waypoints))
                     if all(math.dist(self.waypoints[k], p) >= self.args.unmapped_from
                            for p in refs)]
            if not ahead:
                return
            k = ahead[0]
            r.robot.kidnap(*self.waypoints[k], float(self.rng.uniform(-math.pi, math.pi)),
                           waypoint=min(k + 1, len(self.waypoints) - 1))
            t.open_kidnap, t.kidnap_frame = ("unmapped", t.frames, now_s), t.frames
        t.events.append({"t_s": round(now_s, 1), "event": action})


def run(args: argparse.Namespace) -> dict[str, Any]:
    cfg = _config(args)
    scenario = _scenario(args, args.laps)
    with Run(cfg, scenario) as r:
        run_ = Endurance(args, r, scenario)
        run_.run()
        t = run_.tally
        places = r.mapper.graph.places
        refs = {p: (ref.x, ref.y, ref.yaw) for p, ref in r.references.items()}
        segments = len(set(r.mapper.segment_of.values()))
        done = r.robot.autopilot_done()
        sim_s = r.robot.now_ns() / 1e9
    ids = sorted(refs)
    duplicates = sum(1 for i, a in enumerate(ids) for b in ids[i + 1:]
                     if math.dist(refs[a][:2], refs[b][:2]) < DUPLICATE_M)
    coverage_args = argparse.Namespace(seed=args.seed, every_m=0.25, near=5.0, margin=0.05)
    coverage, _ = mapping._second_pass(cfg, _scenario(args, 1),
                                       [p for p in places if p.id in refs],
                                       [refs[p.id] for p in places if p.id in refs],
                                       coverage_args)
    return {
        "world": {"spec": mapping.world_spec(args)},
        "config": {"laps": args.laps, "speed_m_s": args.speed, "frame_rate_hz": args.frame_rate,
                   "waypoints": args.waypoints, "restarts": args.restarts,
                   "mapped_kidnaps": args.mapped_kidnaps,
                   "unmapped_kidnaps": args.unmapped_kidnaps,
                   "operator_learns": args.operator_learns},
        "metrics": {
            "frames": t.frames,
            "tracking_fraction": round(t.right / max(t.frames, 1), 4),
            "tracking_wrong_fraction": round(t.wrong / max(t.frames, 1), 4),
            "tracking_wrong_frames": t.wrong,
            "tracking_wrong_after_kidnap": t.wrong_after_kidnap,
            "tracking_wrong_confidence_max": round(max(t.wrong_confidence), 3)
            if t.wrong_confidence else None,
            "mapped_kidnaps": len(t.mapped),
            "mapped_kidnap_recovered_within_10": round(sum(t.mapped) / len(t.mapped), 4)
            if t.mapped else None,
            "unmapped_kidnaps": len(t.unmapped_s) + (t.open_kidnap is not None
                                                     and t.open_kidnap[0] == "unmapped"),
            "unmapped_kidnap_tracking_within_s": round(max(t.unmapped_s), 1)
            if t.unmapped_s and not (t.open_kidnap and t.open_kidnap[0] == "unmapped")
            else None,
            "places": len(places),
            "duplicate_places": duplicates,
            "segments_final": segments,
            "coverage": round(coverage, 4),
            "learn_failures": t.learn_failures,
            "operator_learns": t.operator_learns,
            "operator_learns_refused": t.operator_refused,
            "tour_done": done,
            "sim_s": round(sim_s, 1),
        },
        "events": t.events,
    }
