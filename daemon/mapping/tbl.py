"""Turn Back and Look (docs/design.md §3, thesis §4.3, §4.6) as a pure state machine.

Given the two reference panoramas it selects the candidate landmarks statically (§4.2);
then, frame by frame, it is handed the panorama, the odometry at the frame's stamp and
whether the current move is done, and it tells which move to command next. It tracks
every candidate with NCC around the position predicted from the EKF's pose and the
candidate's depth, feeds the bearings to the depth EKF (§4.6), scores each candidate, and
in the end keeps the best ``keep`` with their depths and covariances.

The score is the candidate's recognition margin over the cross: on every
``margin_every``-th frame, its tracked NCC minus the best NCC of its best look-alike
anywhere else in the panorama, capped at ``margin_cap``, averaged. The thesis scores the
mean NCC alone (§4.3, docs/design.md §3), meant to keep the landmarks "recognisable over a large
area"; but a landmark is recognised only where it beats everything else in view, and in
cluttered rooms the generic corners that track best are the ones that look like much
else. ``placecell-eval recognition-range`` measures it: over the candidates, the rank
correlation with how useful each proved for recognition around the place is ~0 for the
mean NCC and ~0.7 for the margin. The set must also stay recognisable when the light
changes (``light_change``): NCC ignores gain, but a brighter scene saturates bright
pixels and takes their pattern away (``keep_in_light``).

A bearing feeds the EKF only while the landmark looks about as large as in the reference
(``ekf_max_zoom``): approaching a wall 3x closer, a template slides off its point yet still
matches well.
No device, no clock: the runner (daemon/service/learning.py) does the I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from daemon.mapping.settings import TblSettings
from daemon.vision.depth_ekf import BearingOnlyEKF
from daemon.vision.landmarks import LandmarkSet
from daemon.vision.ncc import ncc_under_light
from daemon.vision.recognition import best_ncc_elsewhere
from daemon.vision.selection import select_static
from daemon.vision.tracking import column_to_bearing_of_centre, predict_column, track
from kernel.errors import LearningError
from kernel.panorama import to_grey
from kernel.se2 import SE2
from kernel.types import Odometry


@dataclass(frozen=True)
class MoveCommand:
    """A relative move in the robot frame (m, m, rad) at ``speed`` m/s."""

    dx: float
    dy: float
    dyaw: float
    speed: float


@dataclass(frozen=True)
class Progress:
    phase: str  # "+x", "back", "-x", ..., "done"
    fraction: float  # 0..1 of the whole cross


@dataclass(frozen=True)
class Leg:
    """One move of the cross, in the robot's frame at its start: out along an arm, back
    to the reference, or a turn in place (a differential base's way to the side arms)."""

    name: str
    dx: float
    dy: float
    dyaw: float = 0.0

    @property
    def out(self) -> bool:
        return not self.name.startswith(("back", "turn", "align"))


def cross_legs(extent: float, kinematics: str = "holonomic",
               camera: tuple[float, float] = (0.0, 0.0)) -> list[Leg]:
    """The cross (§4.3): out and back along +x, −x, +y, −y of the reference pose. A
    holonomic base keeps its heading and moves sideways for ±y; a differential base turns
    a quarter left in place, drives the same arms along its new heading, and turns back,
    so the landmarks are seen from the same five points (the turns add no parallax: the
    bearings shift by the turn, which odometry predicts).

    ``camera``: where the camera sits on the robot (x, y; kernel/mount.py). The five
    points are the camera's: a turn in place swings a camera off the centre round it, so
    a differential base first drives ahead by x + y (its camera then turns onto the
    reference's x), drives the side arms to ±extent of the reference's y, and turns back
    and returns."""
    legs = []
    for name, dx, dy in (("+x", extent, 0.0), ("-x", -extent, 0.0)):
        legs += [Leg(name, dx, dy), Leg(f"back from {name}", -dx, -dy)]
    if kinematics == "differential":
        a, b = camera
        ahead = a + b  # the robot's x at which its turned camera sits on the reference's x
        if ahead:
            legs.append(Leg("align for the turn", ahead, 0.0))
        legs.append(Leg("turn to +y", 0.0, 0.0, math.pi / 2))
        for name, dx in (("+y", b + extent - a), ("-y", b - extent - a)):
            legs += [Leg(name, dx, 0.0), Leg(f"back from {name}", -dx, 0.0)]
        legs.append(Leg("turn back", 0.0, 0.0, -math.pi / 2))
        if ahead:
            legs.append(Leg("back to the reference", -ahead, 0.0))
    else:
        for name, dy in (("+y", extent), ("-y", -extent)):
            legs += [Leg(name, 0.0, dy), Leg(f"back from {name}", 0.0, -dy)]
    return legs


def cross_tips(extent: float, mount_yaw: float = 0.0) -> list[tuple[float, float]]:
    """The ends of the cross's arms (+x, −x, +y, −y of the robot at the reference, in the
    order :func:`cross_legs` drives them), in the frame of the camera at the reference
    (the EKF's; turned by the mount's yaw)."""
    c, s = math.cos(mount_yaw), math.sin(mount_yaw)
    return [(c * dx + s * dy, -s * dx + c * dy)
            for dx, dy in ((extent, 0.0), (-extent, 0.0), (0.0, extent), (0.0, -extent))]


def past_half_way(pose: tuple[float, float, float], tip: tuple[float, float],
                  extent: float) -> bool:
    """Whether the camera is in the outer half of the arm ending at ``tip``: within half
    the extent of its end. (Not "half the extent from the reference": a differential
    base's camera off the centre starts a side arm away from the reference, on the
    other arm's side when it is 0.25 m or more ahead.)"""
    return math.dist(pose[:2], tip) <= extent / 2


# Candidates from the two reference panoramas (with wrap margin ``margin``).
CandidateChooser = Callable[[np.ndarray, np.ndarray, int], LandmarkSet]


class TurnBackAndLook:
    def __init__(self, settings: TblSettings, reference_1: np.ndarray, reference_2: np.ndarray,
                 margin: int, start: Odometry, choose: CandidateChooser | None = None,
                 kinematics: str = "holonomic", mount: SE2 | None = None) -> None:
        """``choose``: the candidates to track; static selection (§4.2) unless given (the
        thesis identified its artificial markers by hand to measure depth, §4.6.4);
        ``kinematics``: the base's (cross_legs); ``mount``: T_robot_camera (kernel/mount.py):
        the odometry handed in is the camera's, the legs are commanded to the robot."""
        self.mount = mount or SE2()
        self.settings = settings
        self.margin = margin
        self.reference_panorama = reference_1  # the place's reference view (design §6)
        self.start = start  # odometry at the reference pose
        if choose is None:
            self.candidates = select_static(reference_1, reference_2, margin,
                                            count=settings.candidates)
            if len(self.candidates.landmarks) < settings.keep:
                raise LearningError(
                    f"only {len(self.candidates.landmarks)} textured landmark candidates in "
                    f"view (need {settings.keep}): the place is too plain to learn")
        else:
            self.candidates = choose(reference_1, reference_2, margin)
            if not self.candidates.landmarks:
                raise LearningError("no landmark candidates were given to track")
        n = len(self.candidates.landmarks)
        self.width = self.candidates.width
        bearings = np.array([lm.bearing for lm in self.candidates.landmarks])
        self.ekf = BearingOnlyEKF(bearings, initial_depth=settings.initial_depth_m,
                                  bearing_sigma=math.radians(settings.reference_bearing_sigma_deg),
                                  heading_noise_per_m=settings.heading_noise_per_m,
                                  observation_variance_scale=settings.observation_variance_scale,
                                  zoom_noise_rad=settings.zoom_noise_rad)
        self.templates = self.candidates.templates()
        gains = (1.0 - settings.light_change, 1.0 + settings.light_change)
        self.light_ncc = np.array([ncc_under_light(t, gains) for t in self.templates])
        self.cols = self.candidates.cols().astype(float)
        self.rows = self.candidates.rows().astype(float)
        self.recognition_margin_sum = np.zeros(n)
        self.recognition_margin_frames = 0
        self.frames = 0
        self.legs = cross_legs(settings.extent_m, kinematics, (self.mount.x, self.mount.y))
        self.tips = cross_tips(settings.extent_m, self.mount.yaw)
        self.leg = 0
        # Grey views half-way out along each arm of the cross: the place seen a little off
        # its reference (disambiguating features must survive that, design §5; from the
        # tips a small sign 1 m off has changed too much); memory only.
        self.views: list[np.ndarray] = []
        self._commanded = False
        self._last_odometry = start
        self._leg_start = start

    @property
    def done(self) -> bool:
        return self.leg >= len(self.legs)

    def progress(self) -> Progress:
        if self.done:
            return Progress("done", 1.0)
        return Progress(self.legs[self.leg].name, self.leg / len(self.legs))

    def next_command(self) -> MoveCommand | None:
        """The move to command now (once per leg), or None while one is under way."""
        if self.done or self._commanded:
            return None
        leg = self.legs[self.leg]
        self._commanded = True
        self._leg_start = self._last_odometry  # the robot at rest, before it moves
        return MoveCommand(leg.dx, leg.dy, leg.dyaw, self.settings.speed_m_s)

    def on_frame(self, panorama: np.ndarray, odometry: Odometry, move_done: bool) -> Progress:
        """One frame during the cross: odometry at the frame's stamp, and whether the move
        commanded last has finished (the leg then advances)."""
        self._predict(odometry)
        grey = to_grey(panorama)
        pose = self.ekf.pose
        estimates = [self.ekf.estimate(i) for i in range(len(self.templates))]
        predicted = np.array([predict_column(e.bearing, min(e.depth, 50.0), pose, self.width)
                              for e in estimates])
        zoom = np.array([_zoom(e.depth, e.bearing, pose) for e in estimates])
        result = track(grey, self.margin, self.templates, predicted, self.rows,
                       self.settings.window_cols, self.settings.window_rows)
        bearings = column_to_bearing_of_centre(result.cols, self.width)  # robot frame
        limit = math.log(self.settings.ekf_max_zoom)
        for i, (bearing, score) in enumerate(zip(bearings, result.scores, strict=True)):
            log_zoom = math.log(zoom[i])
            if abs(log_zoom) <= limit:
                self.ekf.update(i, float(bearing), float(score), log_zoom)
        if self.frames % self.settings.margin_every == 0:
            elsewhere = best_ncc_elsewhere(grey, self.margin, self.templates, result.cols,
                                           result.rows)
            lead = result.scores - elsewhere  # over the best look-alike, in NCC
            self.recognition_margin_sum += np.minimum(lead, self.settings.margin_cap)
            self.recognition_margin_frames += 1
        self.rows = result.rows
        self.frames += 1
        out = not self.done and self.legs[self.leg].out
        arm = sum(leg.out for leg in self.legs[:self.leg])  # this out leg's arm
        if out and self._commanded and len(self.views) == arm and \
                past_half_way(pose, self.tips[arm], self.settings.extent_m):
            self.views.append(grey)  # half-way out along this arm
        if move_done and self._commanded:
            self._check_leg(odometry)
            self.leg += 1
            self._commanded = False
        return self.progress()

    def _check_leg(self, odometry: Odometry) -> None:
        """The leg the base calls done was driven: its odometry since the command stands
        within ``path_tolerance_m`` (at most half the extent) of the commanded move. A
        move lost or cut short on the link, or a stale "done", would otherwise give a
        place learned from a path the robot did not drive (issue 32)."""
        leg = self.legs[self.leg]
        a = self._leg_start
        # The camera's motion, seen from the robot at the leg's start (M Δ M⁻¹).
        driven = self.mount.compose(SE2(a.x, a.y, a.yaw).between(
            SE2(odometry.x, odometry.y, odometry.yaw))).compose(self.mount.inverse())
        u, v, turned = driven.as_tuple()
        tolerance = min(self.settings.path_tolerance_m, self.settings.extent_m / 2)
        if math.hypot(u - leg.dx, v - leg.dy) > tolerance or \
                abs(math.remainder(turned - leg.dyaw, 2 * math.pi)) > \
                self.settings.turn_tolerance_rad:
            raise LearningError(
                f"leg {leg.name}: the base called the move done, but its odometry shows "
                f"({u:+.3f}, {v:+.3f}) m and {math.degrees(turned):+.1f} deg driven of "
                f"({leg.dx:+.3f}, {leg.dy:+.3f}) m and {math.degrees(leg.dyaw):+.1f} deg "
                "commanded: the cross was not driven as planned, so no place is learned "
                "from it")

    def _predict(self, odometry: Odometry) -> None:
        a, b = self._last_odometry, odometry
        c, s = math.cos(a.yaw), math.sin(a.yaw)
        gx, gy = b.x - a.x, b.y - a.y
        dyaw = math.remainder(b.yaw - a.yaw, 2 * math.pi)
        self.ekf.predict(c * gx + s * gy, -s * gx + c * gy, dyaw, self.mount.as_tuple())
        self._last_odometry = b

    def scored(self) -> LandmarkSet:
        """Every candidate, in selection order, scored by its recognition margin over the
        cross (module docstring) and carrying its depth estimate (§4.6)."""
        if not self.done or self.recognition_margin_frames == 0:
            raise LearningError("Turn Back and Look has not finished")
        recognition_margin = self.recognition_margin_sum / self.recognition_margin_frames
        landmarks = []
        for i, candidate in enumerate(self.candidates.landmarks):
            est = self.ekf.estimate(i)
            landmarks.append(replace(candidate, depth=est.depth, covariance=est.covariance,
                                     bearing=est.bearing,
                                     score=float(recognition_margin[i])))
        return LandmarkSet(tuple(landmarks), self.width, self.margin)

    @property
    def views_expected(self) -> int:
        """The views the cross takes: one half-way out along each arm."""
        return sum(leg.out for leg in self.legs)

    def kept_so_far(self) -> list[int]:
        """The candidates (indices, in selection order) :meth:`result` would keep were the
        cross to end now: what a learn's matching during the drive foresees
        (daemon/service/learn_ahead.py)."""
        frames = max(self.recognition_margin_frames, 1)
        return sorted(keep_in_light(self.recognition_margin_sum / frames, self.light_ncc,
                                    self.settings.keep, self.settings.light_ncc))

    def result(self) -> LandmarkSet:
        """The place's landmark set: the ``keep`` candidates that stood out best over the
        cross (§4.3, scored as in the module docstring) with their depths, in bearing
        order, as long as the set stays recognisable in brighter or dimmer light
        (``keep_in_light``)."""
        scored = self.scored()
        chosen = keep_in_light(np.array([lm.score for lm in scored.landmarks]),
                               self.light_ncc, self.settings.keep, self.settings.light_ncc)
        kept = [scored.landmarks[i] for i in chosen]
        return replace(scored, landmarks=tuple(sorted(kept, key=lambda lm: lm.bearing)))


def keep_in_light(scores: np.ndarray, light_ncc: np.ndarray, keep: int, floor: float
                  ) -> list[int]:
    """The ``keep`` best-scored candidates, but the set's mean NCC under the changed light
    (each template against itself, ``light_ncc``) must reach ``floor``, as the set's LRP
    would: while it does not, the kept one that suffers most is swapped for the best-scored
    spare that holds up to the floor on its own."""
    ranked = [int(i) for i in np.argsort(-scores, kind="stable")]
    kept, spares = ranked[:keep], ranked[keep:]
    while kept and float(np.mean(light_ncc[kept])) < floor:
        spare = next((j for j in spares if light_ncc[j] >= floor), None)
        if spare is None:
            break  # nothing better left: keep the best there is
        kept.remove(min(kept, key=lambda i: light_ncc[i]))
        kept.append(spare)
        spares.remove(spare)
    return kept


def _zoom(depth: float, bearing: float, pose: tuple[float, float, float]) -> float:
    """How much larger a landmark at (depth, bearing) of the reference appears from
    ``pose``: reference distance over current distance (1 for an unresolved one)."""
    if not math.isfinite(depth) or depth <= 0.0:
        return 1.0
    x, y, _ = pose
    now = math.hypot(depth * math.cos(bearing) - x, depth * math.sin(bearing) - y)
    return depth / max(now, 1e-3)
