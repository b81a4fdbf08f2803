"""The simulated robot: one holonomic base and one mirror camera in a simulated world.

Shared by the `sim` camera and `sim` base backends (through ``HalContext``). Time is
simulated in fixed odometry steps (50 Hz by default) and runs either on the wall clock
(``realtime``: the daemon) or in lock-step with the readers (evaluation and tests: each
camera read advances to the next frame time, so runs are fast and deterministic).

Motion: relative moves (trapezoidal speed profile under speed and acceleration limits) and
velocity commands, in the robot frame; a scenario's autopilot drives the robot until a
command arrives. Odometry integrates the true motion distorted by drift (design §10): a scale
error, a heading bias per metre, and random walks per square-root metre.
"""

from __future__ import annotations

import bisect
import collections
import math
import threading
import time
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from hal.base.base import BaseStatus, Odometry
from hal.base.settings import SimBaseSettings
from hal.camera.base import Frame
from hal.camera.settings import SimCameraSettings
from hal.sim.render import Renderer
from hal.sim.scenario import Scenario
from kernel.angles import wrap_angle
from kernel.errors import CommandRejectedError, DeviceInitError
from kernel.se2 import SE2


@dataclass
class _Move:
    """A relative move in progress, as a straight world-frame line plus a rotation."""

    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    speed: float
    yaw_rate: float
    progress: float = 0.0  # metres along the line
    v: float = 0.0  # current speed along the line
    turned: float = 0.0  # radians turned so far
    w: float = 0.0


def _braking_speed(remaining: float, decel: float, dt: float) -> float:
    """The highest speed from which steps of ``dt`` slowing by ``decel * dt`` each cover
    ``remaining`` exactly: v = a dt (sqrt(1/4 + 2 d / (a dt²)) − 1/2)."""
    step = decel * dt
    return step * (math.sqrt(0.25 + 2.0 * remaining / (step * dt)) - 0.5)


class SimRobot:
    def __init__(self, renderer: Renderer | None, camera: SimCameraSettings, base: SimBaseSettings,
                 *, seed: int, realtime: bool, start_pose: tuple[float, float, float],
                 scenario: Scenario | None = None,
                 camera_mount: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """``camera_mount``: where the camera truly sits on the robot (x, y, yaw in the
        robot's frame): frames are rendered from there."""
        self.renderer = renderer
        self.camera_mount = SE2(*camera_mount)
        self.camera = camera
        self.base = base
        self.realtime = realtime
        self.scenario = scenario
        self._lock = threading.RLock()
        self._dt_ns = int(round(1e9 / base.odometry_rate_hz))
        self._frame_ns = int(round(1e9 / camera.rate_hz))
        self.reseed(seed)
        self._t_ns = 0  # simulated time since start
        self._mono0 = time.monotonic_ns()
        self._pose = start_pose  # true pose, world frame
        self._odo = (0.0, 0.0, 0.0)  # odometry pose, odometry frame
        self._vel = (0.0, 0.0, 0.0)  # velocity command (robot frame)
        self._current = (0.0, 0.0, 0.0)  # body velocity of the last step
        self._move: _Move | None = None
        self._commanded = False  # a daemon command took over from the autopilot
        self._move_done = False
        self._move_done_at_ns: int | None = None  # when the last commanded move ended
        self._autopilot_released = False  # resumed after a command: no start delay
        self._truth_out: TextIO | None = None
        # (stamp, true pose, odometry pose) of the last steps, for truth_at (keep_truth).
        self._history: collections.deque[tuple[int, tuple[float, float, float],
                                               tuple[float, float, float]]] | None = None
        self._samples: list[Odometry] = []
        self._odo_seq = 0
        self._frame_seq = 0
        self._next_frame_ns = 0
        self._kidnaps_done = 0
        self._waypoint = 0  # the scenario autopilot's next waypoint

    def write_truth_to(self, path: str) -> None:
        """Append the true pose at every simulation step to ``path`` (JSON lines with the
        stamps odometry and frames carry): for evaluators and tests, never the method."""
        self._truth_out = open(path, "a", encoding="utf-8", buffering=1)  # noqa: SIM115

    def keep_truth(self, seconds: float) -> None:
        """Keep the true and odometry poses of the last ``seconds`` of steps, for
        ``truth_at`` (an evaluator in another process judging a frame it received late)."""
        with self._lock:
            self._history = collections.deque(
                maxlen=max(2, int(seconds * 1e9 / self._dt_ns)))

    def truth_at(self, stamp_ns: int) -> tuple[int, tuple[float, float, float],
                                               tuple[float, float, float]] | None:
        """(stamp, true pose, odometry pose) of the kept step nearest ``stamp_ns`` (a stamp
        frames and odometry carry); None when nothing is kept or it is older than that."""
        with self._lock:
            if not self._history or stamp_ns < self._history[0][0] - self._dt_ns:
                return None
            stamps = [h[0] for h in self._history]
            k = bisect.bisect_left(stamps, stamp_ns)
            near = min((i for i in (k - 1, k) if 0 <= i < len(stamps)),
                       key=lambda i: abs(stamps[i] - stamp_ns))
            return self._history[near]

    # ------------------------------------------------------------------ time
    def now_ns(self) -> int:
        """Stamp of the current simulated time on the clock frames and odometry share."""
        return self._stamp(self._t_ns)

    def _stamp(self, t_ns: int) -> int:
        return self._mono0 + t_ns if self.realtime else t_ns

    def elapsed_ns(self, stamp_ns: int) -> int:
        """Simulated time since the start of a stamp (the controller's own clock)."""
        return stamp_ns - self._mono0 if self.realtime else stamp_ns

    def wall_time_ns(self) -> int:
        """Simulated time that corresponds to now (realtime mode)."""
        return time.monotonic_ns() - self._mono0

    def advance_to(self, t_ns: int) -> None:
        """Step the simulation until simulated time ``t_ns``."""
        with self._lock:
            while self._t_ns + self._dt_ns <= t_ns:
                self._step()

    def _step(self) -> None:
        dt = self._dt_ns / 1e9
        self._t_ns += self._dt_ns
        if self.scenario is not None:
            kidnap = self.scenario.kidnap_due(self._t_ns / 1e9, self._kidnaps_done)
            if kidnap is not None:
                self._kidnaps_done += 1
                self._pose = kidnap  # teleport: odometry knows nothing of it
        vx, vy, w = self._velocity(dt)
        x, y, yaw = self._pose
        # Exact integration for constant body velocity over dt (midpoint heading).
        mid = yaw + 0.5 * w * dt
        dx_w = (vx * math.cos(mid) - vy * math.sin(mid)) * dt
        dy_w = (vx * math.sin(mid) + vy * math.cos(mid)) * dt
        self._pose = (x + dx_w, y + dy_w, float(wrap_angle(yaw + w * dt)))
        self._integrate_odometry(vx * dt, vy * dt, w * dt, mid - yaw)
        self._odo_seq += 1
        ox, oy, oyaw = self._odo
        self._samples.append(Odometry(ox, oy, oyaw, self._stamp(self._t_ns), self._odo_seq))
        if self._history is not None:
            self._history.append((self._stamp(self._t_ns), self._pose, self._odo))
        if self._truth_out is not None:
            x, y, yaw = self._pose
            self._truth_out.write(f'{{"stamp_ns": {self._stamp(self._t_ns)}, "x": {x!r}, '
                                  f'"y": {y!r}, "yaw": {yaw!r}}}\n')
        if len(self._samples) > 10_000:  # nobody reads: keep memory bounded
            del self._samples[:5_000]

    def _integrate_odometry(self, dx: float, dy: float, dyaw: float, half: float) -> None:
        """Odometry = true body motion with drift (docs/design.md §10)."""
        b = self.base
        ds = math.hypot(dx, dy)
        if ds > 0:
            noise = self._rng.normal(0.0, 1.0, 3)
            scale = 1.0 + b.scale_error
            dx = dx * scale + b.random_walk_m_per_sqrt_m * math.sqrt(ds) * noise[0]
            dy = dy * scale + b.random_walk_m_per_sqrt_m * math.sqrt(ds) * noise[1]
            dyaw = dyaw + b.heading_bias_rad_per_m * ds + (
                b.random_walk_rad_per_sqrt_m * math.sqrt(ds) * noise[2])
        ox, oy, oyaw = self._odo
        mid = oyaw + half
        self._odo = (ox + dx * math.cos(mid) - dy * math.sin(mid),
                     oy + dx * math.sin(mid) + dy * math.cos(mid),
                     float(wrap_angle(oyaw + dyaw)))

    def _velocity(self, dt: float) -> tuple[float, float, float]:
        """Body velocity for the next step: a move in progress, a velocity command, or the
        scenario's autopilot (after its start delay; once a command took over, again only
        if the scenario resumes it a while after the last commanded move ended)."""
        if self._move is not None:
            return self._move_velocity(self._move, dt)
        sc = self.scenario
        if self._commanded and sc is not None and sc.resume_after_s is not None \
                and self._move_done_at_ns is not None \
                and self._t_ns - self._move_done_at_ns >= sc.resume_after_s * 1e9:
            self._commanded = False  # the robot's own driver takes over again...
            self._autopilot_released = True  # ...start delay or not
        if self._commanded or sc is None or (
                not self._autopilot_released and self._t_ns < sc.start_after_s * 1e9):
            return self._limit(self._vel, dt)
        target, self._waypoint = sc.autopilot(self._pose, self._waypoint)
        return self._limit(target, dt)

    def _limit(self, target: tuple[float, float, float], dt: float
               ) -> tuple[float, float, float]:
        """Accelerate the current velocity toward ``target`` under the base's limits."""
        b = self.base
        vx, vy, w = self._current
        tx, ty, tw = target
        speed = math.hypot(tx, ty)
        if speed > b.max_speed_m_s:
            tx, ty = tx * b.max_speed_m_s / speed, ty * b.max_speed_m_s / speed
        tw = max(-b.max_yaw_rate_rad_s, min(b.max_yaw_rate_rad_s, tw))
        ex, ey = tx - vx, ty - vy
        e = math.hypot(ex, ey)
        step = b.max_accel_m_s2 * dt
        if e > step:
            ex, ey = ex * step / e, ey * step / e
        dw = max(-b.max_yaw_accel_rad_s2 * dt, min(b.max_yaw_accel_rad_s2 * dt, tw - w))
        self._current = (vx + ex, vy + ey, w + dw)
        return self._current

    def _move_velocity(self, m: _Move, dt: float) -> tuple[float, float, float]:
        """Trapezoidal profile along the move's straight line and its rotation; the last
        step lands exactly on the goal."""
        b = self.base
        sx, sy, syaw = m.start
        gx, gy, gyaw = m.goal
        length = math.hypot(gx - sx, gy - sy)
        turn = float(wrap_angle(gyaw - syaw))
        rem = length - m.progress
        m.v = min(m.speed, m.v + b.max_accel_m_s2 * dt, _braking_speed(rem, b.max_accel_m_s2, dt))
        adv = min(rem, m.v * dt)
        rem_turn = abs(turn) - m.turned
        m.w = min(m.yaw_rate, m.w + b.max_yaw_accel_rad_s2 * dt,
                  _braking_speed(max(rem_turn, 0.0), b.max_yaw_accel_rad_s2, dt))
        adv_turn = min(rem_turn, m.w * dt)
        if rem - adv < 1e-9 and m.v * dt >= rem:
            adv = rem
        m.progress += adv
        m.turned += adv_turn
        # Body velocity that moves the true pose along the line (world -> body at midpoint).
        x, y, yaw = self._pose
        f = m.progress / length if length > 0 else 1.0
        tx, ty = sx + f * (gx - sx), sy + f * (gy - sy)
        w = math.copysign(adv_turn, turn) / dt
        mid = yaw + 0.5 * w * dt
        wx, wy = (tx - x) / dt, (ty - y) / dt
        vx = wx * math.cos(mid) + wy * math.sin(mid)
        vy = -wx * math.sin(mid) + wy * math.cos(mid)
        if m.progress >= length - 1e-12 and m.turned >= abs(turn) - 1e-12:
            self._move = None
            self._move_done = True
            self._move_done_at_ns = self._t_ns
            self._current = (0.0, 0.0, 0.0)
        else:
            self._current = (vx, vy, w)
        return vx, vy, w

    # ------------------------------------------------------------------ base side
    def odometry_samples(self) -> list[Odometry]:
        """Samples produced since the last call (drained)."""
        with self._lock:
            out, self._samples = self._samples, []
            return out

    def wait_odometry(self, timeout: float) -> list[Odometry]:
        """Base read: realtime waits for the wall clock; lock-step advances one sample."""
        with self._lock:
            if not self.realtime and not self._samples:
                self.advance_to(self._t_ns + self._dt_ns)
        if self.realtime:
            end = time.monotonic() + timeout
            while True:
                self.advance_to(self.wall_time_ns())
                with self._lock:
                    if self._samples:
                        break
                if time.monotonic() >= end:
                    break
                time.sleep(min(self._dt_ns / 1e9 / 2, max(0.0, end - time.monotonic())))
        return self.odometry_samples()

    def status(self) -> BaseStatus:
        with self._lock:
            moving = self._move is not None or math.hypot(*self._current[:2]) > 1e-6 or abs(
                self._current[2]) > 1e-6
            return BaseStatus(moving=moving, move_done=self._move_done)

    def move_relative(self, dx: float, dy: float, dyaw: float, speed: float) -> None:
        if not self.base.can_move:
            raise CommandRejectedError("the simulated base is configured with can_move = false")
        if speed <= 0 or not all(map(math.isfinite, (dx, dy, dyaw, speed))):
            raise CommandRejectedError(f"invalid move ({dx}, {dy}, {dyaw}) at {speed} m/s")
        if self.base.kinematics == "differential" and (dy != 0.0 or (dx != 0.0 and dyaw != 0.0)):
            raise CommandRejectedError(
                f"move ({dx}, {dy}, {dyaw}): a differential base drives along its heading "
                "or turns in place, one at a time")
        with self._lock:
            x, y, yaw = self._pose
            goal = (x + dx * math.cos(yaw) - dy * math.sin(yaw),
                    y + dx * math.sin(yaw) + dy * math.cos(yaw), float(wrap_angle(yaw + dyaw)))
            self._commanded = True
            self._move_done = False
            self._move_done_at_ns = None
            self._move = _Move(self._pose, goal, min(speed, self.base.max_speed_m_s),
                               self.base.max_yaw_rate_rad_s)

    def velocity(self, vx: float, vy: float, w: float) -> None:
        if not self.base.can_move:
            raise CommandRejectedError("the simulated base is configured with can_move = false")
        if self.base.kinematics == "differential" and vy != 0.0:
            raise CommandRejectedError(f"velocity vy = {vy}: a differential base has no "
                                       "sideways motion")
        with self._lock:
            self._commanded = True
            self._move_done_at_ns = None
            self._move = None
            self._move_done = False
            self._vel = (vx, vy, w)

    def stop(self) -> None:
        """Stop; a scenario that resumes its autopilot after commands does so after this
        too (its driver plans again), else the robot stays stopped."""
        with self._lock:
            self._commanded = True
            self._move_done_at_ns = self._t_ns
            self._move = None
            self._vel = (0.0, 0.0, 0.0)

    def kidnap(self, x: float, y: float, yaw: float, waypoint: int | None = None) -> None:
        """Teleport the robot; odometry does not notice (docs/design.md §9). ``waypoint``:
        the scenario's autopilot goes on towards that waypoint from here (an evaluator
        carrying the robot along its tour)."""
        with self._lock:
            self._pose = (x, y, float(wrap_angle(yaw)))
            self._move = None
            self._current = (0.0, 0.0, 0.0)
            if waypoint is not None:
                self._waypoint = waypoint

    def reseed(self, seed: int) -> None:
        """Draw the odometry's and the camera's noise afresh from ``seed``, as a new robot
        built with it would: an evaluator running one trial twice (with and without a
        method's part) gives both runs the same noise, so the difference is the part's."""
        with self._lock:
            self._rng = np.random.default_rng([seed, 17])
            self._camera_rng = np.random.default_rng([seed, 23])

    @property
    def waypoint(self) -> int:
        """The scenario autopilot's next waypoint (truth interface)."""
        return self._waypoint

    def autopilot_done(self) -> bool:
        """The scenario's autopilot has passed its last waypoint (truth interface)."""
        return self.scenario is None or self._waypoint >= len(self.scenario.waypoints)

    def true_pose(self) -> tuple[float, float, float]:
        return self._pose

    def odometry_pose(self) -> tuple[float, float, float]:
        return self._odo

    def ground_truth(self) -> tuple[int, tuple[float, float, float]]:
        """(stamp_ns, true pose): for recordings and evaluation, never for the method."""
        with self._lock:
            return self.now_ns(), self._pose

    # ------------------------------------------------------------------ camera side
    def next_frame(self, timeout: float) -> Frame | None:
        """Camera read: realtime waits for the next frame time (None after ``timeout``);
        lock-step advances the simulation to it at once."""
        with self._lock:
            due = max(self._next_frame_ns, self._t_ns)
        if self.scenario is not None and self.realtime:
            # A stalled camera (scenario fault): frames due in the stall never come.
            while self.scenario.camera_stalled(due / 1e9):
                due += self._frame_ns
        if self.realtime:
            wait = (due - self.wall_time_ns()) / 1e9
            if wait > timeout:
                time.sleep(timeout)
                return None
            if wait > 0:
                time.sleep(wait)
            due = max(due, self.wall_time_ns())
        self.advance_to(due)
        with self._lock:
            self._next_frame_ns = (self._t_ns // self._frame_ns + 1) * self._frame_ns
        return self.render_frame()

    def render_frame(self) -> Frame:
        """The raw donut at the current simulated time."""
        if self.renderer is None:
            raise DeviceInitError("this simulated robot was built without a camera")
        with self._lock:
            t_s = self._t_ns / 1e9
            people = self.scenario.people_at(t_s) if self.scenario else ()
            gain = self.camera.gain * (self.scenario.gain_at(t_s) if self.scenario else 1.0)
            noise = self.camera.noise_sigma
            blur = self.camera.blur_sigma_px
            if self.scenario is not None:
                noise = self.scenario.noise_sigma if self.scenario.noise_sigma is not None \
                    else noise
                blur = self.scenario.blur_sigma_px if self.scenario.blur_sigma_px is not None \
                    else blur
            pose, stamp_ns = self._pose, self.now_ns()
            self._frame_seq += 1
            seq = self._frame_seq
        if self.camera_mount != SE2():
            pose = SE2(*pose).compose(self.camera_mount).as_tuple()
        # Rendered outside the lock: odometry goes on while the camera renders.
        image = self.renderer.donut(pose, people=people, gain=gain, noise_sigma=noise,
                                    blur_sigma_px=blur, rng=self._camera_rng)
        return Frame(image=image, stamp_ns=stamp_ns, seq=seq)
