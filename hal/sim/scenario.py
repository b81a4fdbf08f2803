"""Scenarios: what happens in a simulated run (design §10). Format: config/scenarios/README.md.

A scenario names a world, a start pose, a trajectory for the autopilot (waypoints, a TBL
cross, laps of a loop, a tour), image noise and illumination over time, people walking
along paths, and kidnap events. It is pure data plus the autopilot's control law.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hal.sim.render import Person
from kernel.angles import wrap_angle
from kernel.errors import ConfigError
from kernel.settings import read_toml

Pose = tuple[float, float, float]


@dataclass(frozen=True)
class Waypoint:
    x: float
    y: float
    speed: float
    yaw: float | None = None  # None: keep the heading (holonomic) unless face_travel


@dataclass(frozen=True)
class Walker:
    """A person walking back and forth (or round) along a path at a speed."""

    path: tuple[tuple[float, float], ...]
    speed: float = 0.8
    loop: bool = False
    start_s: float = 0.0
    radius: float = 0.25
    height: float = 1.75

    def position(self, t: float) -> tuple[float, float] | None:
        if t < self.start_s:
            return None
        pts = list(self.path) + ([self.path[0]] if self.loop else [])
        legs = [math.dist(a, b) for a, b in zip(pts[:-1], pts[1:], strict=True)]
        total = sum(legs)
        if total == 0:
            return pts[0]
        s = (t - self.start_s) * self.speed
        s = s % total if self.loop else total - abs(s % (2 * total) - total)
        for (a, b), leg in zip(zip(pts[:-1], pts[1:], strict=True), legs, strict=True):
            if s <= leg or leg == legs[-1]:
                f = min(1.0, s / leg) if leg else 0.0
                return a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])
            s -= leg
        return pts[-1]


@dataclass(frozen=True)
class Scenario:
    name: str
    world: str
    start_pose: Pose | None
    waypoints: tuple[Waypoint, ...] = ()
    face_travel: bool = False
    start_after_s: float = 0.0  # the autopilot waits this long before it drives
    resume_after_s: float | None = None  # after a commanded move, the autopilot drives on
    duration_s: float | None = None
    frame_rate_hz: float | None = None
    noise_sigma: float | None = None
    blur_sigma_px: float | None = None
    gain_schedule: tuple[tuple[float, float], ...] = ((0.0, 1.0),)
    walkers: tuple[Walker, ...] = ()
    kidnaps: tuple[tuple[float, Pose], ...] = ()
    drift: dict[str, float] = field(default_factory=dict)
    camera_stalls: tuple[tuple[float, float], ...] = ()  # (start_s, duration_s): no frames

    # ------------------------------------------------------------ playback
    def gain_at(self, t: float) -> float:
        """Illumination gain, piecewise linear in time."""
        ts = [p[0] for p in self.gain_schedule]
        gs = [p[1] for p in self.gain_schedule]
        if t <= ts[0]:
            return gs[0]
        for (t0, g0), (t1, g1) in zip(self.gain_schedule[:-1], self.gain_schedule[1:],
                                      strict=True):
            if t <= t1:
                return g0 + (g1 - g0) * (t - t0) / (t1 - t0)
        return gs[-1]

    def people_at(self, t: float) -> tuple[Person, ...]:
        out = []
        for w in self.walkers:
            p = w.position(t)
            if p is not None:
                out.append(Person(p[0], p[1], w.radius, w.height))
        return tuple(out)

    def camera_stalled(self, t: float) -> bool:
        return any(start <= t < start + dur for start, dur in self.camera_stalls)

    def kidnap_due(self, t: float, done: int) -> Pose | None:
        if done < len(self.kidnaps) and t >= self.kidnaps[done][0]:
            return self.kidnaps[done][1]
        return None

    def end_time_s(self) -> float:
        """The duration, or the time the trajectory needs at its speeds (plus 2 s)."""
        if self.duration_s is not None:
            return self.duration_s
        t, pos = 0.0, self.start_pose[:2] if self.start_pose else None
        for wp in self.waypoints:
            if pos is not None:
                t += math.dist(pos, (wp.x, wp.y)) / wp.speed
            pos = (wp.x, wp.y)
        return t + 2.0

    def autopilot(self, pose: Pose, index: int) -> tuple[tuple[float, float, float], int]:
        """Body velocity toward waypoint ``index`` (advanced past the ones reached): a
        holonomic P-controller with a speed cap; the base's acceleration limits smooth it.
        Returns the velocity and the new waypoint index."""
        x, y, yaw = pose
        while index < len(self.waypoints):
            wp = self.waypoints[index]
            tol = 0.02 if index == len(self.waypoints) - 1 else 0.15
            if math.hypot(wp.x - x, wp.y - y) > tol:
                break
            index += 1
        if index >= len(self.waypoints):
            return (0.0, 0.0, 0.0), index
        wp = self.waypoints[index]
        ex, ey = wp.x - x, wp.y - y
        dist = math.hypot(ex, ey)
        last = index == len(self.waypoints) - 1
        speed = min(wp.speed, 1.5 * dist) if last else wp.speed
        vx_w, vy_w = (ex / dist * speed, ey / dist * speed) if dist > 1e-9 else (0.0, 0.0)
        c, s = math.cos(yaw), math.sin(yaw)
        target_yaw = wp.yaw
        if self.face_travel and dist > 0.05:
            target_yaw = math.atan2(ey, ex)
        w = 0.0 if target_yaw is None else 2.0 * float(wrap_angle(target_yaw - yaw))
        return (c * vx_w + s * vy_w, -s * vx_w + c * vy_w, w), index


# ---------------------------------------------------------------- loading
_TOP = {"name", "world", "start_pose", "duration_s", "frame_rate_hz", "camera", "trajectory",
        "illumination", "people", "kidnap", "drift", "camera_stall"}
_TRAJ = {"kind", "waypoints", "speed", "laps", "loop", "extent_m", "face_travel",
         "start_after_s", "resume_after_s", "clearance_m"}
_DRIFT = {"scale_error", "heading_bias_rad_per_m", "random_walk_m_per_sqrt_m",
          "random_walk_rad_per_sqrt_m"}


def _keys(table: Any, known: set[str], where: str) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table")
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known: "
                          f"{', '.join(sorted(known))})")
    return table


def _num(v: Any, where: str, lo: float | None = None) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}: expected a number, got {v!r}")
    if lo is not None and v < lo:
        raise ConfigError(f"{where}: {v} is out of range (must be >= {lo})")
    return float(v)


def _pose(v: Any, where: str) -> Pose:
    if not isinstance(v, list) or len(v) != 3:
        raise ConfigError(f"{where}: expected [x, y, yaw], got {v!r}")
    return (_num(v[0], where), _num(v[1], where), _num(v[2], where))


def _points(v: Any, where: str) -> list[tuple[float, float]]:
    if not isinstance(v, list) or not v:
        raise ConfigError(f"{where}: expected a list of [x, y] points")
    out = []
    for i, p in enumerate(v):
        if not isinstance(p, list) or len(p) not in (2, 3):
            raise ConfigError(f"{where}[{i}]: expected [x, y] (or [x, y, speed])")
        out.append((_num(p[0], f"{where}[{i}]"), _num(p[1], f"{where}[{i}]")))
    return out


def load_scenario(path: str | Path) -> Scenario:
    p = Path(path)
    data = read_toml(p, "scenario")
    try:
        return scenario_from_dict(data, base_dir=p.parent)
    except ConfigError as e:
        raise ConfigError(f"scenario {p}: {e}") from e


def scenario_from_dict(data: dict[str, Any], base_dir: Path = Path(".")) -> Scenario:
    _keys(data, _TOP, "scenario")
    world = data.get("world")
    if not isinstance(world, str) or not world:
        raise ConfigError("scenario.world: expected a world file or generate:<kind>:<seed>")
    if not world.startswith("generate:") and not Path(world).is_absolute():
        world = str((base_dir / world).resolve())
    start = _pose(data["start_pose"], "scenario.start_pose") if "start_pose" in data else None
    traj = _keys(data.get("trajectory", {"kind": "none"}), _TRAJ, "trajectory")
    waypoints = _trajectory(traj, start, world)
    cam = _keys(data.get("camera", {}), {"noise_sigma", "blur_sigma_px"}, "camera")
    ill = _keys(data.get("illumination", {}), {"gain", "schedule"}, "illumination")
    if "schedule" in ill:
        sched = ill["schedule"]
        if not isinstance(sched, list) or not sched or not all(
                isinstance(s, list) and len(s) == 2 for s in sched):
            raise ConfigError("illumination.schedule: expected [[t_s, gain], ...]")
        gains = tuple((_num(t, "illumination.schedule", 0.0),
                       _num(g, "illumination.schedule", 0.0)) for t, g in sched)
        if any(b[0] <= a[0] for a, b in zip(gains[:-1], gains[1:], strict=True)):
            raise ConfigError("illumination.schedule: times must increase")
    else:
        gains = ((0.0, _num(ill.get("gain", 1.0), "illumination.gain", 0.0)),)
    walkers = []
    for i, person in enumerate(data.get("people", [])):
        w = _keys(person, {"path", "speed", "loop", "start_s", "radius", "height"},
                  f"people[{i}]")
        walkers.append(Walker(tuple(_points(w.get("path"), f"people[{i}].path")),
                              _num(w.get("speed", 0.8), f"people[{i}].speed", 0.0),
                              bool(w.get("loop", False)),
                              _num(w.get("start_s", 0.0), f"people[{i}].start_s", 0.0),
                              _num(w.get("radius", 0.25), f"people[{i}].radius", 0.05),
                              _num(w.get("height", 1.75), f"people[{i}].height", 0.1)))
    kidnaps = []
    for i, k in enumerate(data.get("kidnap", [])):
        k = _keys(k, {"t_s", "pose"}, f"kidnap[{i}]")
        kidnaps.append((_num(k.get("t_s"), f"kidnap[{i}].t_s", 0.0),
                        _pose(k.get("pose"), f"kidnap[{i}].pose")))
    stalls = []
    for i, st in enumerate(data.get("camera_stall", [])):
        st = _keys(st, {"t_s", "duration_s"}, f"camera_stall[{i}]")
        stalls.append((_num(st.get("t_s"), f"camera_stall[{i}].t_s", 0.0),
                       _num(st.get("duration_s"), f"camera_stall[{i}].duration_s", 0.0)))
    drift = _keys(data.get("drift", {}), _DRIFT, "drift")
    return Scenario(
        name=str(data.get("name", "scenario")), world=world, start_pose=start,
        waypoints=tuple(waypoints), face_travel=bool(traj.get("face_travel", False)),
        start_after_s=_num(traj.get("start_after_s", 0.0), "trajectory.start_after_s", 0.0),
        resume_after_s=_num(traj["resume_after_s"], "trajectory.resume_after_s", 0.0)
        if "resume_after_s" in traj else None,
        duration_s=_num(data["duration_s"], "scenario.duration_s", 0.0)
        if "duration_s" in data else None,
        frame_rate_hz=_num(data["frame_rate_hz"], "scenario.frame_rate_hz", 0.1)
        if "frame_rate_hz" in data else None,
        noise_sigma=_num(cam["noise_sigma"], "camera.noise_sigma", 0.0)
        if "noise_sigma" in cam else None,
        blur_sigma_px=_num(cam["blur_sigma_px"], "camera.blur_sigma_px", 0.0)
        if "blur_sigma_px" in cam else None,
        gain_schedule=gains, walkers=tuple(walkers),
        kidnaps=tuple(sorted(kidnaps, key=lambda k: k[0])),
        drift={k: _num(v, f"drift.{k}") for k, v in drift.items()},
        camera_stalls=tuple(stalls))


def _trajectory(traj: dict[str, Any], start: Pose | None, world: str) -> list[Waypoint]:
    kind = traj.get("kind", "none")
    speed = _num(traj.get("speed", 0.3), "trajectory.speed", 0.01)
    if kind == "none":
        return []
    if kind == "tour":  # through every room of the world and back (hal/sim/tour.py)
        from hal.sim.tour import TourError, plan_tour
        from hal.sim.world import load_world

        laps = int(_num(traj.get("laps", 1), "trajectory.laps", 1))
        clearance = _num(traj.get("clearance_m", 0.4), "trajectory.clearance_m", 0.0)
        w = load_world(world)
        if start is not None:
            w = dataclasses.replace(w, start_pose=start)
        try:
            points = plan_tour(w, clearance, laps)
        except TourError as why:
            raise ConfigError(f"trajectory.kind 'tour': {why}") from why
        return [Waypoint(x, y, speed) for x, y in points]
    if kind == "waypoints":
        out = []
        for i, p in enumerate(traj.get("waypoints", [])):
            if not isinstance(p, list) or len(p) not in (2, 3):
                raise ConfigError(f"trajectory.waypoints[{i}]: expected [x, y] or [x, y, speed]")
            out.append(Waypoint(_num(p[0], f"trajectory.waypoints[{i}]"),
                                _num(p[1], f"trajectory.waypoints[{i}]"),
                                _num(p[2], f"trajectory.waypoints[{i}]", 0.01)
                                if len(p) == 3 else speed))
        if not out:
            raise ConfigError("trajectory.waypoints: at least one waypoint")
        return out
    if kind == "tbl":  # the Turn-Back-and-Look cross around the start pose (docs/design.md §3)
        if start is None:
            raise ConfigError("trajectory kind 'tbl' needs scenario.start_pose")
        e = _num(traj.get("extent_m", 0.5), "trajectory.extent_m", 0.01)
        x, y, yaw = start
        c, s = math.cos(yaw), math.sin(yaw)
        out = []
        for bx, by in ((e, 0), (0, 0), (-e, 0), (0, 0), (0, e), (0, 0), (0, -e), (0, 0)):
            out.append(Waypoint(x + c * bx - s * by, y + s * bx + c * by, speed))
        return out
    if kind == "loop":
        pts = _points(traj.get("loop"), "trajectory.loop")
        laps = int(_num(traj.get("laps", 1), "trajectory.laps", 1))
        out = [Waypoint(px, py, speed) for _ in range(laps) for px, py in pts]
        out.append(Waypoint(pts[0][0], pts[0][1], speed))
        return out
    raise ConfigError(f"trajectory.kind: {kind!r} is not one of none, waypoints, tbl, loop, "
                      "tour")
