"""The live view's messages (design §11): the panorama, the pose, the particles, the map
and the belief as JSON bodies under the schemas of ``kernel/message_schemas.py`` — the
ones recordings use, so one Foxglove layout (``config/foxglove-layout.json``) shows both.
Everything is in the ``map`` frame (design §6); pure functions, no I/O."""

from __future__ import annotations

import base64
import math
from typing import Any

import cv2
import numpy as np

from kernel.se2 import SE2

FRAME = "map"
PLACE_COLOUR = {"r": 0.2, "g": 0.6, "b": 1.0, "a": 0.9}
LINK_COLOUR = {"r": 0.8, "g": 0.8, "b": 0.8, "a": 0.8}
LABEL_COLOUR = {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}


def stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def pose(x: float, y: float, yaw: float, z: float = 0.0) -> dict[str, Any]:
    return {"position": {"x": x, "y": y, "z": z},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0),
                            "w": math.cos(yaw / 2.0)}}


def pose_in_frame(stamp_ns: int, at: SE2) -> dict[str, Any]:
    """``foxglove.PoseInFrame``: the robot in the map frame."""
    return {"timestamp": stamp(stamp_ns), "frame_id": FRAME, "pose": pose(at.x, at.y, at.yaw)}


def particles_in_frame(stamp_ns: int, place: SE2, particles: np.ndarray,
                       at_most: int) -> dict[str, Any]:
    """``foxglove.PosesInFrame``: up to ``at_most`` of the particles ((N, 3) in the place
    frame, evenly picked), composed into the map frame."""
    step = max(1, math.ceil(len(particles) / at_most))
    picked = np.asarray(particles)[::step]
    c, s = math.cos(place.yaw), math.sin(place.yaw)
    x = place.x + c * picked[:, 0] - s * picked[:, 1]
    y = place.y + s * picked[:, 0] + c * picked[:, 1]
    yaw = place.yaw + picked[:, 2]
    return {"timestamp": stamp(stamp_ns), "frame_id": FRAME,
            "poses": [pose(float(a), float(b), float(t)) for a, b, t in zip(x, y, yaw,
                                                                          strict=True)]}


def map_scene(stamp_ns: int, places: dict[int, tuple[SE2, str]],
              links: list[tuple[int, int]]) -> dict[str, Any]:
    """``foxglove.SceneUpdate``: a sphere and a label at each place's reference pose, one
    line per transition between places drawn."""
    t = stamp(stamp_ns)
    entities = []
    for place_id, (at, label) in sorted(places.items()):
        entities.append({
            "timestamp": t, "frame_id": FRAME, "id": f"place-{place_id}",
            "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
            "arrows": [], "cubes": [], "cylinders": [], "lines": [], "triangles": [],
            "models": [],
            "spheres": [{"pose": pose(at.x, at.y, at.yaw), "size": {"x": 0.25, "y": 0.25,
                                                                    "z": 0.25},
                         "color": PLACE_COLOUR}],
            "texts": [{"pose": pose(at.x, at.y, 0.0, z=0.35), "billboard": True,
                       "font_size": 14.0, "scale_invariant": True, "color": LABEL_COLOUR,
                       "text": f"{place_id} {label}".strip()}]})
    points = []
    for a, b in links:
        if a in places and b in places:
            points += [{"x": places[a][0].x, "y": places[a][0].y, "z": 0.0},
                       {"x": places[b][0].x, "y": places[b][0].y, "z": 0.0}]
    entities.append({
        "timestamp": t, "frame_id": FRAME, "id": "transitions",
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
        "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "triangles": [],
        "texts": [], "models": [],
        "lines": [{"type": 2, "pose": pose(0.0, 0.0, 0.0), "thickness": 2.0,
                   "scale_invariant": True, "points": points, "color": LINK_COLOUR,
                   "colors": [], "indices": []}]})
    return {"deletions": [], "entities": entities}


def panorama_image(stamp_ns: int, panorama: np.ndarray, max_width: int,
                   quality: int = 80) -> dict[str, Any]:
    """``foxglove.CompressedImage``: the panorama as JPEG, at most ``max_width`` wide."""
    h, w = panorama.shape[:2]
    if w > max_width:
        panorama = cv2.resize(panorama, (max_width, max(1, round(h * max_width / w))),
                              interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", panorama, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("the panorama could not be encoded as JPEG")
    return {"timestamp": stamp(stamp_ns), "frame_id": "panorama", "format": "jpeg",
            "data": base64.b64encode(buf.tobytes()).decode()}
