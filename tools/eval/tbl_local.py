"""``placecell-eval tbl-local``: local positioning along the Turn Back and Look path
(design §7, thesis §8.1.5).

The simulated robot (lock-step) learns a place at the world's start pose with the daemon's
Turn Back and Look, is told it stands at the place's reference (``set_pose`` at (0, 0, 0),
σ 0.1 m as the thesis's 100 mm), and drives the cross again (``--crosses`` times) while the
Localiser — the daemon's pipeline — positions it in the place from every frame. The error
is the distance between the estimate and the simulator's true pose in the place's frame.

``--occlude-deg D`` replaces a D° sector of every raw image with noise (thesis: 180°).
``--misassociate K`` gives K landmarks a reference bearing 3-6° off in the map the
localiser holds (seeded), so they are tracked confidently where the map says they are
not: a landmark associated with the wrong point (thesis: 5 of 16).

Metrics: ``mean_error_m``, ``p95_error_m``, ``max_error_m``, ``final_error_m``,
``frames``, ``mean_confidence``, ``process_ms_median``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from daemon.config import load
from daemon.mapping.place import Place
from hal.sim.world import load_world
from tools.eval import plots
from tools.eval.lockstep import (
    Run,
    add_localisation_arguments,
    add_mount_arguments,
    localisation_settings,
    lockstep_config,
)

DRAWS_PLOTS = True  # path (estimate, truth, odometry, particles), error per frame
CAMERA_MODELS = True  # --camera-model M: any of kernel/camera_models.py MODEL_NAMES
SNAPSHOT_FRAMES = (1, 30, 120)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_localisation_arguments(p)
    p.add_argument("--occlude-deg", type=float, default=0.0,
                   help="replace this many degrees of every view with noise")
    p.add_argument("--misassociate", type=int, default=0,
                   help="landmarks whose map bearing is 3-6 degrees off")
    p.add_argument("--crosses", type=int, default=2, help="times the cross is driven")
    p.add_argument("--kinematics", choices=["holonomic", "differential"], default="holonomic",
                   help="the simulated base: a differential one drives the cross with turns")
    add_mount_arguments(p)


def occluder(width: int, height: int, cx: float, cy: float, degrees: float,
             rng: np.random.Generator) -> Any:
    """A frame filter replacing the sector [0, degrees) of image azimuth with noise."""
    yy, xx = np.mgrid[0:height, 0:width]
    azimuth = np.degrees(np.arctan2(yy - cy, xx - cx)) % 360.0
    mask = azimuth < degrees

    def apply(image: np.ndarray) -> np.ndarray:
        out = image.copy()
        noise = rng.integers(0, 256, size=out[mask].shape, dtype=np.uint8)
        out[mask] = noise
        return out

    return apply


def misassociated(place: Place, count: int, rng: np.random.Generator) -> Place:
    """The place with ``count`` landmarks' reference bearings moved 3-6° (random sign)."""
    lms = list(place.landmarks.landmarks)
    for i in rng.choice(len(lms), size=min(count, len(lms)), replace=False):
        off = math.radians(rng.uniform(3.0, 6.0)) * rng.choice([-1.0, 1.0])
        lms[i] = dataclasses.replace(lms[i], bearing=float(
            math.remainder(lms[i].bearing + off, 2 * math.pi)))
    return dataclasses.replace(place, landmarks=dataclasses.replace(place.landmarks,
                                                                    landmarks=tuple(lms)))


def run(args: argparse.Namespace) -> dict[str, Any]:
    world = f"generate:{args.world_kind}:{args.world_seed}"
    base = load(None)
    settings = localisation_settings(base.localisation, args)
    cfg = lockstep_config(args.seed, world=world, start_pose=load_world(world).start_pose,
                          localisation=settings, kinematics=args.kinematics,
                          camera_model=args.camera_model, camera_ahead_m=args.camera_ahead,
                          mount_known=not args.mount_left_out)
    rng = np.random.default_rng(args.seed + 1000)
    m, cam = cfg.mirror, cfg.camera.sim
    frame_filter = occluder(cam.image_width, cam.image_height, m.center_x_px, m.center_y_px,
                            args.occlude_deg, rng) if args.occlude_deg > 0 else None
    errors: list[float] = []
    confidence: list[float] = []
    track: list[tuple[float, float, float, float, float, float]] = []
    snapshots: dict[str, np.ndarray] = {}  # particles at chosen frames, for --plots
    with Run(cfg, frame_filter=frame_filter) as r:
        place = r.learn("tbl-local")
        if args.misassociate:
            wrong = misassociated(place, args.misassociate, rng)  # a fault put in the map
            r.localiser.known_map.replace(lambda m: m.with_places([wrong]))
        r.localiser.set_pose(place.id, (0.0, 0.0, 0.0), 0.1)
        odo0 = r.robot.odometry_pose()
        for _ in range(args.crosses):
            for belief in r.drive_cross(cfg.tbl.extent_m, cfg.tbl.speed_m_s):
                error = r.error_m(belief)
                if error is None or belief.pose_in_place is None:
                    continue
                errors.append(error)
                if len(errors) in SNAPSHOT_FRAMES and r.localiser.tracker is not None:
                    snapshots[f"particles, frame {len(errors)}"] = \
                        r.localiser.tracker.filter.particles[::10, :2].copy()
                confidence.append(belief.confidence)
                truth = r.truth_in(place.id)
                odo = r.robot.odometry_pose()
                track.append((*belief.pose_in_place[:2], truth.x, truth.y,
                              odo[0] - odo0[0], odo[1] - odo0[1]))
        process_ms = float(np.median(r.process_s)) * 1e3
    e = np.array(errors)
    if args.plots:
        t = np.array(track)
        plots.paths(Path(args.plots) / "tbl-local-path.png",
                    {"estimate": t[:, 0:2], "truth": t[:, 2:4], "odometry": t[:, 4:6]},
                    title=f"tbl-local ({args.sensor_model}) in {world}", points=snapshots)
        plots.series(Path(args.plots) / "tbl-local-error.png", {"error (m)": e},
                     title="position error per frame", x_label="frame", y_label="m")
    return {
        "world": {"kind": args.world_kind, "seed": args.world_seed},
        "config": {"sensor_model": args.sensor_model, "occlude_deg": args.occlude_deg,
                   "misassociate": args.misassociate, "crosses": args.crosses,
                   "particles": settings.particles, "kinematics": args.kinematics,
                   "camera_ahead_m": args.camera_ahead, "mount_left_out": args.mount_left_out},
        "metrics": {
            "mean_error_m": round(float(e.mean()), 4),
            "p95_error_m": round(float(np.percentile(e, 95)), 4),
            "max_error_m": round(float(e.max()), 4),
            "final_error_m": round(float(e[-1]), 4),
            "frames": len(e),
            "mean_confidence": round(float(np.mean(confidence)), 3),
            "process_ms_median": round(process_ms, 2),
        },
    }
