"""``placecell-eval cyclic``: tracking round a loop of places, lap after lap, against
odometry (design §6, §8; thesis §8.2: a 25 m path, 5 places, 4 laps).

The simulated robot (lock-step, the default odometry drift) learns a place at the start,
is told it stands there, and drives the loop once (``--loop-m`` round, a rectangle
``--width-m`` wide), stopping to learn ``--places`` − 1 more places evenly spaced along it;
the daemon's Localiser tracks it throughout, and as it comes back to the first place —
which has no transition from the last — it closes the cycle (§7.1.3). Then ``--laps``
laps follow, positioned by the same Localiser. Errors are against the simulator's truth
in the current place's frame; the robot is holonomic and keeps its heading, and each leg
is steered to its true end and heading (as the simulated base's exact moves are; the ros2
base closes its moves on odometry).

Metrics: ``mean_error_m``, ``p95_error_m``, ``final_error_m`` (over the laps after the
mapping lap), ``odometry_final_error_m`` (dead reckoning over those laps),
``last_lap_over_first`` (mean error of the last lap over the first's), ``cycle_error_m``
and ``cycle_error_deg`` (the closing transition measured by the localiser against the
truth), ``loop_sum_error_m`` and ``loop_sum_error_deg`` (the same transition as the sum of
the odometry transitions round the loop; None when ``transitions_missing`` says the
mapping lap left consecutive places unjoined, a loss between them), ``cycles_closed``,
``place_switches``, ``process_ms_median``; the one ``map`` frame (design §6,
daemon/mapping/embedding.py) the finished map embeds in: ``embedded_max_error_m`` and
``embedded_mean_error_m`` (each place's optimised position relative to the first place
against its true one) and ``map_error_m_mean`` / ``map_error_m_p95`` (the lap poses
composed into that frame against the truth relative to the first place; None when none of
them is in it, ``lap_poses_in_map`` says how many are).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from daemon.config import load
from daemon.localisation.belief import Belief
from daemon.mapping.embedding import embed
from daemon.mapping.transition import Transition
from hal.sim.world import load_world
from kernel.se2 import SE2
from tools.eval import plots
from tools.eval.lockstep import (
    add_backends_argument,
    add_localisation_arguments,
    add_mount_arguments,
    localisation_settings,
    lockstep_config,
    open_run,
)

DRAWS_PLOTS = True  # world-frame paths (estimate, truth, odometry), error per frame
CAMERA_MODELS = True  # --camera-model M: any of kernel/camera_models.py MODEL_NAMES


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--places", type=int, default=5)
    p.add_argument("--laps", type=int, default=4)
    p.add_argument("--loop-m", type=float, default=6.25, help="length of one lap")
    p.add_argument("--width-m", type=float, default=0.75, help="the loop's width")
    p.add_argument("--speed", type=float, default=0.3)
    p.add_argument("--start", type=float, nargs=3, metavar=("X", "Y", "YAW"),
                   help="where the loop starts (default: the world's start pose)")
    p.add_argument("--kinematics", choices=["holonomic", "differential"], default="holonomic",
                   help="the simulated base: a differential one turns to face each leg")
    add_mount_arguments(p)
    add_localisation_arguments(p)
    add_backends_argument(p)


def corners(loop_m: float, width_m: float) -> list[tuple[float, float]]:
    """The loop's corners from the start, counter-clockwise: along +x, up +y, back, down."""
    length = loop_m / 2 - width_m
    return [(length, 0.0), (length, width_m), (0.0, width_m), (0.0, 0.0)]


def legs(loop_m: float, width_m: float, stops: list[float]) -> Iterator[tuple[float, float,
                                                                             bool]]:
    """(dx, dy, stop_here) moves round the loop, split at the distances ``stops``."""
    pts = [(0.0, 0.0), *corners(loop_m, width_m)]
    travelled = 0.0
    pending = sorted(stops)
    for (x0, y0), (x1, y1) in zip(pts, pts[1:], strict=False):
        seg = math.dist((x0, y0), (x1, y1))
        ux, uy = (x1 - x0) / seg, (y1 - y0) / seg
        done = 0.0
        while pending and pending[0] < travelled + seg - 1e-9:
            cut = pending.pop(0) - travelled
            yield ux * (cut - done), uy * (cut - done), True
            done = cut
        yield ux * (seg - done), uy * (seg - done), False
        travelled += seg


def run(args: argparse.Namespace) -> dict[str, Any]:
    base = load(None)
    world = f"generate:{args.world_kind}:{args.world_seed}"
    settings = localisation_settings(base.localisation, args)
    start = tuple(args.start) if args.start else load_world(world).start_pose
    cfg = lockstep_config(args.seed, world=world, start_pose=start, localisation=settings,
                          camera_model=args.camera_model, kinematics=args.kinematics,
                          camera_ahead_m=args.camera_ahead, mount_known=not args.mount_left_out)
    spacing = args.loop_m / args.places
    stops = [spacing * k for k in range(1, args.places)]
    closed: list[Transition] = []
    switches = 0
    laps: list[list[float]] = []
    tracked: list[tuple[int, SE2, SE2]] = []  # (place, estimate in it, true pose) per frame
    paths: dict[str, list[tuple[float, float]]] = {"estimate": [], "truth": [],
                                                    "odometry": []}
    with open_run(cfg, args.backends) as r:
        r.learn("place 1")  # tracking starts at each place learned

        loop_origin = SE2.of(r.robot.true_pose())
        aim = [0.0, 0.0]  # where the legs so far end, in the loop's frame

        def frames(dx: float, dy: float) -> Iterator[Belief]:
            """One leg: the move from the true pose to the leg's end, the start's heading
            kept (the evaluator's teleop steers by the truth: a base that closes its moves
            on drifting odometry, such as the ros2 one, drives the same loop at the same
            heading as the exact simulated one)."""
            nonlocal switches
            aim[0], aim[1] = aim[0] + dx, aim[1] + dy
            goal = loop_origin.compose(SE2(aim[0], aim[1], 0.0))
            move = SE2.of(r.robot.true_pose()).between(goal)
            if args.kinematics == "differential":  # turn to face the leg, drive along it
                turn = math.atan2(move.y, move.x)
                moves = [(0.0, 0.0, turn), (math.hypot(move.x, move.y), 0.0, 0.0)]
            else:  # heading kept
                moves = [move.as_tuple()]
            for mx, my, myaw in moves:
                for belief in r.drive(mx, my, myaw, args.speed):
                    if r.updates.closed_transition is not None:  # Run.step stored it
                        closed.append(r.updates.closed_transition)
                    switches += belief.switched_from is not None
                    yield belief

        for dx, dy, stop in legs(args.loop_m, args.width_m, stops):  # the mapping lap
            for _ in frames(dx, dy):
                pass
            if stop:
                r.learn(f"place {len(r.references) + 1}")
        odo_start, true_start = SE2.of(r.robot.odometry_pose()), SE2.of(r.robot.true_pose())
        for _ in range(args.laps):
            errors: list[float] = []
            for dx, dy, _stop in legs(args.loop_m, args.width_m, []):
                for belief in frames(dx, dy):
                    error = r.error_m(belief)
                    if error is None or belief.place_id is None \
                            or belief.pose_in_place is None:
                        continue
                    errors.append(error)
                    robot = r.cfg.mount.robot_pose(SE2.of(belief.pose_in_place))
                    tracked.append((belief.place_id, robot, SE2.of(r.robot.true_pose())))
                    paths["estimate"].append(r.references[belief.place_id].compose(
                        robot).as_tuple()[:2])
                    paths["truth"].append(r.robot.true_pose()[:2])
                    paths["odometry"].append(true_start.compose(odo_start.between(
                        SE2.of(r.robot.odometry_pose()))).as_tuple()[:2])
            laps.append(errors)
        odo_end, true_end = SE2.of(r.robot.odometry_pose()), SE2.of(r.robot.true_pose())
        odo_move, true_move = odo_start.between(odo_end), true_start.between(true_end)
        ids = sorted(r.references)
        last, first_id = ids[-1], ids[0]
        truth_cycle = r.references[last].between(r.references[first_id])
        steps = [r.mapper.graph.transition(a, b)  # last -> ... -> first
                 for a, b in zip(ids[::-1], ids[::-1][1:], strict=False)]
        missing = sum(t is None for t in steps)  # places the mapping lap left unjoined
        loop_sum = None if missing else functools.reduce(
            SE2.compose, [t.T_from_to.mean for t in steps if t is not None], SE2())
        cycle = next((t for t in closed if {t.from_id, t.to_id} == {last, first_id}), None)
        process_ms = float(np.median(r.process_s)) * 1e3
        # The map frame the finished map embeds in, anchored at the first place.
        frame = embed(r.mapper.graph)
        origin = r.references[first_id]
        placed = [math.dist(frame[p].as_tuple()[:2], origin.between(r.references[p]
                                                                     ).as_tuple()[:2])
                  for p in ids if p in frame]
        in_map = [math.dist(frame[p].compose(est).as_tuple()[:2],
                            origin.between(true).as_tuple()[:2])
                  for p, est, true in tracked if p in frame]
    all_errors = np.concatenate([np.array(e) for e in laps])
    cycle_se2 = None if cycle is None else (cycle.T_from_to.mean if cycle.from_id == last
                                            else cycle.T_from_to.mean.inverse())
    cycle_m, cycle_deg = _error(cycle_se2, truth_cycle)
    loop_sum_m, loop_sum_deg = _error(loop_sum, truth_cycle)
    if args.plots:
        out = Path(args.plots)
        plots.paths(out / "cyclic-path.png", {k: np.array(v) for k, v in paths.items()},
                    title=f"cyclic: {args.laps} laps in {world}")
        plots.series(out / "cyclic-error.png", {"error (m)": all_errors},
                     title="position error per frame", x_label="frame", y_label="m")
    return {
        "world": {"kind": args.world_kind, "seed": args.world_seed},
        "config": {"places": args.places, "laps": args.laps, "loop_m": args.loop_m,
                   "width_m": args.width_m, "speed_m_s": args.speed,
                   "sensor_model": settings.sensor_model, "particles": settings.particles,
                   "drift": dataclasses.asdict(cfg.base.sim), "backends": args.backends,
                   "kinematics": args.kinematics, "camera_ahead_m": args.camera_ahead,
                   "mount_left_out": args.mount_left_out},
        "metrics": {
            "mean_error_m": round(float(all_errors.mean()), 4),
            "p95_error_m": round(float(np.percentile(all_errors, 95)), 4),
            "final_error_m": round(float(laps[-1][-1]), 4),
            "odometry_final_error_m": round(math.hypot(odo_move.x - true_move.x,
                                                       odo_move.y - true_move.y), 4),
            "last_lap_over_first": round(float(np.mean(laps[-1]) / np.mean(laps[0])), 3),
            "cycle_error_m": cycle_m,
            "cycle_error_deg": cycle_deg,
            "loop_sum_error_m": loop_sum_m,
            "loop_sum_error_deg": loop_sum_deg,
            "transitions_missing": missing,
            "embedded_max_error_m": round(max(placed), 4),
            "embedded_mean_error_m": round(float(np.mean(placed)), 4),
            # None when no lap pose lies in the map frame's segment (the mapping lap left
            # the loop unjoined: transitions_missing).
            "map_error_m_mean": round(float(np.mean(in_map)), 4) if in_map else None,
            "map_error_m_p95": round(float(np.percentile(in_map, 95)), 4)
            if in_map else None,
            "lap_poses_in_map": len(in_map),
            "cycles_closed": len(closed),
            "place_switches": switches,
            "frames": int(len(all_errors)),
            "process_ms_median": round(process_ms, 2),
        },
    }


def _error(measured: SE2 | None, truth: SE2) -> tuple[float | None, float | None]:
    """(metres, degrees) between a measured transition and the true one; None, None when
    there is no measurement."""
    if measured is None:
        return None, None
    return (round(math.hypot(measured.x - truth.x, measured.y - truth.y), 4),
            round(abs(math.degrees(math.remainder(measured.yaw - truth.yaw, 2 * math.pi))), 3))
