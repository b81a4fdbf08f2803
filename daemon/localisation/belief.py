"""What the localiser believes after a frame (published as ``pose`` and ``belief``), and
beside it what the frame found that changes the map (``MapUpdates``, for its owner, the
service's MappingSession)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from daemon.mapping.acquisition import AcquisitionDecision
from daemon.mapping.transition import Transition
from daemon.vision.floor import FloorModel
from kernel.mount import Mount
from kernel.se2 import SE2
from kernel.types import Odometry

BeliefState = Literal["uninitialised", "tracking", "lost", "relocalising"]


@dataclass(frozen=True)
class PlaceScore:
    """One place's recognition in a frame: its LRP and how far that stands above its
    background LRP (§9.2)."""

    place_id: int
    lrp: float
    lead: float


@dataclass(frozen=True)
class LocalisationEvent:
    """A loss declared, or the pose found again (published on ``events``, design §9)."""

    kind: Literal["lost", "relocalised"]
    place_id: int | None  # lost: the place the estimate was in; relocalised: found in
    how: str  # lost: why; relocalised: "local" | "place" | "global" (the recovery step)
    took_s: float = 0.0  # relocalised: from the loss (or the search's start), by stamps
    frames: int = 0  # ...and in frames
    # lost: the view contradicted the estimate (the output rule, or another place leading
    # the search) — maybe a robot carried off; False: no evidence either way (blind travel)
    contradicted: bool = False


@dataclass(frozen=True)
class Disambiguation:
    """Two look-alike places told apart by their features in this frame (design §5)."""

    place_id: int  # chosen
    other_id: int
    ncc_place: float  # the chosen place's feature's best NCC in the view
    ncc_other: float  # the other's
    vote: float  # the weighed vote for the chosen place (> 0)
    elapsed_ms: float = 0.0  # the decision's time (the features matched in the view)
    pairs: int = 1  # look-alike pairs whose features took part


@dataclass(frozen=True)
class Belief:
    stamp_ns: int
    state: BeliefState
    reason: str
    odometry_ok: bool
    place_id: int | None = None
    place_label: str = ""
    pose_in_place: tuple[float, float, float] | None = None  # (x, y, θ) in the place frame
    covariance: tuple[float, ...] | None = None  # 3 x 3 of (x, y, θ), row-major
    confidence: float = 0.0  # raw sensor-model output at the estimate, [0, 1]
    # The same over every landmark usable from the estimate, seen or not (the loss rule's
    # input, §9.3.1); None without a tracker's frame or with too few usable (no evidence).
    support: float | None = None
    particles: int = 0
    motion_since_last: tuple[float, float, float] | None = None
    scores: tuple[PlaceScore, ...] = ()  # places recognised in this frame (not every frame)
    switched_from: int | None = None  # the estimate moved into place_id from this place
    timings_ms: dict[str, float] = field(default_factory=dict)
    recent_place: int | None = None  # the place autonomous acquisition watches...
    recent_place_lrp: float | None = None  # ...its LRP in this frame
    acquisition: AcquisitionDecision | None = None  # learn a new place here (design §6)
    event: LocalisationEvent | None = None  # a loss or a relocalisation in this frame
    disambiguation: Disambiguation | None = None  # look-alikes told apart in this frame
    odometry: Odometry | None = None  # the base's odometry at the frame's stamp

    def of_robot(self, mount: Mount) -> Belief:
        """This belief about the camera (the method's, kernel/mount.py) as one about the
        robot: its pose and covariance in the place's frame and its odometry, as the
        service gives them out."""
        if mount.centred:
            return self
        pose, cov = self.pose_in_place, self.covariance
        if pose is not None:
            robot, covariance = mount.robot_estimate(
                SE2.of(pose), np.zeros((3, 3)) if cov is None else np.reshape(cov, (3, 3)))
            pose = robot.as_tuple()
            cov = None if cov is None else tuple(float(v) for v in covariance.ravel())
        odometry = None if self.odometry is None else mount.robot_odometry(self.odometry)
        return dataclasses.replace(self, pose_in_place=pose, covariance=cov, odometry=odometry)


@dataclass(frozen=True)
class MapUpdates:
    """What a frame found that changes the map (design §6): the localiser only reads the
    map; its owner stores these (daemon/service/mapping_session.py)."""

    closed_transition: Transition | None = None  # a cycle closed in this frame (§7.1.3)
    backgrounds: tuple[tuple[int, float], ...] = ()  # (place, background LRP) measured now
    floor_learned: FloorModel | None = None  # the floor learned from this frame (design §4)
