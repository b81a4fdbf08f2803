"""Ground truth for evaluations, computed from the world by the evaluator only; nothing
here ever reaches the method."""

from __future__ import annotations

import math

import numpy as np

from daemon.vision.landmarks import TEMPLATE
from hal.sim.render import Renderer
from kernel.panorama import elevation_of_row


def landmark_depth(renderer: Renderer, pose: tuple[float, float, float], bearing: float,
                   row: float) -> float:
    """Horizontal distance from ``pose`` to the surface seen at the centre of a template
    at (``bearing``, top ``row``): the wall, a low obstacle, or the floor."""
    p = renderer.pano
    phi = float(elevation_of_row(row + (TEMPLATE - 1) / 2.0, p.height,
                                 math.radians(p.elevation_top_deg),
                                 math.radians(p.elevation_bottom_deg)))
    hit = renderer._cast(pose[0], pose[1], np.array([pose[2] + bearing]), ())
    h = p.camera_height_m
    depth = float(hit["t_full"][0])
    if "t_low" in hit and hit["t_low"][0] < depth:
        z = h + float(hit["t_low"][0]) * math.tan(phi)
        if 0.0 <= z <= float(renderer._height[hit["i_low"][0]]):
            depth = float(hit["t_low"][0])
    if phi < 0:
        depth = min(depth, h / math.tan(-phi))
    return depth
