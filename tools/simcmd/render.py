"""``placecell-sim render --world SPEC [--pose x,y,yaw] --out DIR``: pictures for people.

Writes ``plan.png`` (the floor plan from above, walls coloured by texture, the pose as an
arrow), ``donut.png`` (the raw mirror-camera image), ``panorama.png`` (the daemon's
unwarping of that image) and ``floor.png`` (the ground-truth floor mask).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np

from daemon.vision.unwarp import Unwarper
from hal.sim.render import Renderer
from hal.sim.world import World, load_world
from kernel.errors import PlacecellError
from tools.simcmd import load_config


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", required=True, help="world TOML or generate:<kind>:<seed>")
    p.add_argument("--pose", help="x,y,yaw (default: the world's start pose)")
    p.add_argument("--out", required=True, help="directory for the PNG files")
    p.add_argument("--config", help="daemon configuration for mirror/panorama settings")
    p.add_argument("--noise", type=float, default=2.0, help="pixel noise sigma")


def plan_view(world: World, pose: tuple[float, float, float], px_per_m: float = 30.0
              ) -> np.ndarray:
    x0, y0, x1, y1 = world.bounds()
    margin = 0.5
    w = int((x1 - x0 + 2 * margin) * px_per_m)
    h = int((y1 - y0 + 2 * margin) * px_per_m)
    img = np.full((h, w, 3), 255, np.uint8)
    img[:] = world.floor_colour

    def to_px(p: tuple[float, float]) -> tuple[int, int]:
        return (int((p[0] - x0 + margin) * px_per_m), int((y1 + margin - p[1]) * px_per_m))

    for wall in world.walls:
        colour = tuple(int(c) for c in wall.colour)
        thick = 2 if wall.height_m is not None else 4
        for a, b in wall.segments():
            cv2.line(img, to_px(a), to_px(b), (40, 40, 40), thick + 2)
            cv2.line(img, to_px(a), to_px(b), colour, thick)
    x, y, yaw = pose
    tip = (x + 0.6 * math.cos(yaw), y + 0.6 * math.sin(yaw))
    cv2.circle(img, to_px((x, y)), int(0.25 * px_per_m), (0, 0, 220), 2)
    cv2.arrowedLine(img, to_px((x, y)), to_px(tip), (0, 0, 220), 2, tipLength=0.3)
    cv2.putText(img, f"{world.name}  ({x1 - x0:.0f} x {y1 - y0:.0f} m)", (8, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def run(args: argparse.Namespace) -> int:
    config = load_config(args.config)
    world = load_world(args.world)
    pose = world.start_pose
    if args.pose:
        try:
            x, y, yaw = (float(v) for v in args.pose.split(","))
        except ValueError as e:
            raise PlacecellError(f"--pose {args.pose!r}: expected x,y,yaw") from e
        pose = (x, y, yaw)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cam = config.camera.sim
    renderer = Renderer(world, config.projection, config.panorama, (cam.image_width,
                                                                cam.image_height))
    donut = renderer.donut(pose, noise_sigma=args.noise, rng=np.random.default_rng(0))
    panorama = Unwarper(config.projection, config.panorama).unwarp(donut)
    floor = renderer.floor_mask(pose).astype(np.uint8) * 255
    for name, image in (("plan.png", plan_view(world, pose)), ("donut.png", donut),
                        ("panorama.png", panorama), ("floor.png", floor)):
        cv2.imwrite(str(out / name), image)
    print(f"wrote plan.png, donut.png, panorama.png, floor.png to {out}")
    return 0
