"""The thesis's artificial landmarks, pointed at by hand (§4.6.4: "manually identified
in the reference panoramic image"): the evaluator, knowing the world, plays that person
and hands Turn Back and Look one template per flat marker near the place, on the window
of the marker that static selection's valley measure rates most distinctive (§4.2) — a
corner of its pattern rather than a flat cell. Evaluation only: the daemon never sees
the world."""

from __future__ import annotations

import math

import numpy as np

from daemon.mapping.tbl import CandidateChooser
from daemon.vision.landmarks import TEMPLATE, Landmark, LandmarkSet, centre_bearing
from daemon.vision.selection import MIN_TEXTURE, texture, valley_measure
from hal.sim.world import World
from kernel.panorama import (
    add_wrap_margin,
    column_of_bearing,
    core_of,
    row_of_elevation,
    to_grey,
)
from kernel.sensor_settings import PanoramaSettings


def _markers(world: World) -> list[tuple[tuple[float, float], tuple[float, float], float,
                                         float]]:
    """Every marker painted on the walls: its two ends (x, y) and its bottom and top z."""
    out = []
    for wall in world.walls:
        corners = list(wall.points) + ([wall.points[0]] if wall.closed else [])
        for deco in (d for d in wall.decorations if d.kind == "marker"):
            along = deco.at_m
            for (ax, ay), (bx, by) in zip(corners, corners[1:], strict=False):
                length = math.hypot(bx - ax, by - ay)
                if along + deco.width_m <= length:
                    ux, uy = (bx - ax) / length, (by - ay) / length
                    out.append(((ax + along * ux, ay + along * uy),
                                (ax + (along + deco.width_m) * ux,
                                 ay + (along + deco.width_m) * uy),
                                deco.bottom_m, deco.bottom_m + deco.height_m))
                    break
                along -= length
    return out


def markers_in_view(world: World, pose: tuple[float, float, float],
                    panorama: PanoramaSettings, reach_m: float) -> CandidateChooser:
    """Candidates for TBL: a template on each marker whose centre is within ``reach_m``
    of ``pose``, cut from the first reference panorama."""
    x0, y0, yaw = pose
    top = math.radians(panorama.elevation_top_deg)
    bottom = math.radians(panorama.elevation_bottom_deg)
    half = (TEMPLATE - 1) / 2.0

    def choose(reference: np.ndarray, second: np.ndarray, margin: int) -> LandmarkSet:
        core = core_of(to_grey(reference), margin)
        height, width = core.shape
        wrapped = add_wrap_margin(core, TEMPLATE)  # core column c starts at c + TEMPLATE
        distinct, _ = valley_measure(core, core_of(to_grey(second), margin))
        distinct[texture(core) < MIN_TEXTURE] = -np.inf

        def column(x: float, y: float) -> float:  # unwrapped around the marker's centre
            return float(column_of_bearing(math.atan2(y - y0, x - x0) - yaw, width))

        landmarks = []
        for (xa, ya), (xb, yb), z_low, z_high in _markers(world):
            xc, yc = (xa + xb) / 2.0, (ya + yb) / 2.0
            distance = math.hypot(xc - x0, yc - y0)
            if distance > reach_m:
                continue
            centre = column(xc, yc)
            ends = [centre + math.remainder(column(x, y) - centre, width)
                    for x, y in ((xa, ya), (xb, yb))]
            rows = [float(row_of_elevation(math.atan2(z - panorama.camera_height_m, distance),
                                           height, top, bottom)) for z in (z_high, z_low)]
            # Where on the marker: the window centred on it that static selection rates
            # most distinctive (§4.2's valley measure), as a person would pick a corner.
            windows = [(float(distinct[r, c % width]), r, c % width)
                       for r in range(math.ceil(rows[0] - half), math.floor(rows[1] - half) + 1)
                       for c in range(math.ceil(min(ends) - half), math.floor(max(ends) - half) + 1)
                       if 0 <= r <= height - TEMPLATE]
            distinctness, row, col = max(windows, default=(-np.inf, 0, 0))
            if distinctness > -np.inf:
                template = wrapped[row:row + TEMPLATE, col + TEMPLATE:col + 2 * TEMPLATE]
                landmarks.append(Landmark(template.copy(), row, col,
                                          centre_bearing(col, width)))
        return LandmarkSet(tuple(landmarks), width, margin)

    return choose
