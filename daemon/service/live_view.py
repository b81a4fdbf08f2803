"""What the daemon shows while it runs (design §11): each frame's pose, particles and
belief, the panorama at most every ``PANORAMA_PERIOD_S``, the map every ``MAP_PERIOD_S``
(a viewer that connects late sees it within that), to every sink — the Foxglove server
(daemon/service/foxglove_view.py) and the MCAP recording, under the same schemas."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from daemon.service import scene
from kernel.se2 import SE2

PANORAMA_PERIOD_S = 0.5
MAP_PERIOD_S = 2.0
PARTICLES_SHOWN = 300
PANORAMA_MAX_WIDTH = 720

TOPICS = {
    "/placecell/panorama": "foxglove.CompressedImage",
    "/placecell/pose_map": "foxglove.PoseInFrame",
    "/placecell/particles": "foxglove.PosesInFrame",
    "/placecell/map": "foxglove.SceneUpdate",
    "/placecell/belief": "placecell.Json",
}

DrawnMap = tuple[dict[int, tuple[SE2, str]], list[tuple[int, int]]]


class Sink(Protocol):
    def write_message(self, topic: str, schema: str, stamp_ns: int,
                      body: dict[str, Any]) -> None: ...


class LiveScene:
    def __init__(self, sinks: list[Sink]) -> None:
        self.sinks = sinks
        self._panorama_due_ns = 0
        self._map_due_ns = 0

    def _send(self, topic: str, stamp_ns: int, body: dict[str, Any]) -> None:
        for sink in self.sinks:
            sink.write_message(topic, TOPICS[topic], stamp_ns, body)

    def show(self, stamp_ns: int, belief: dict[str, Any], robot_in_map: SE2 | None,
             place_in_map: SE2 | None, particles: np.ndarray | None,
             panorama: np.ndarray | None, drawn: Callable[[], DrawnMap]) -> None:
        """One frame: ``stamp_ns`` its time (monotonic, as recordings keep it),
        ``belief`` the body published on ``belief``, the poses in the map frame when the
        place is embedded in it, the particles in the place's frame."""
        self._send("/placecell/belief", stamp_ns, belief)
        if robot_in_map is not None:
            self._send("/placecell/pose_map", stamp_ns, scene.pose_in_frame(stamp_ns,
                                                                            robot_in_map))
        if place_in_map is not None and particles is not None and len(particles):
            self._send("/placecell/particles", stamp_ns, scene.particles_in_frame(
                stamp_ns, place_in_map, particles, PARTICLES_SHOWN))
        if panorama is not None and stamp_ns >= self._panorama_due_ns:
            self._panorama_due_ns = stamp_ns + int(PANORAMA_PERIOD_S * 1e9)
            self._send("/placecell/panorama", stamp_ns, scene.panorama_image(
                stamp_ns, panorama, PANORAMA_MAX_WIDTH))
        if stamp_ns >= self._map_due_ns:
            self._map_due_ns = stamp_ns + int(MAP_PERIOD_S * 1e9)
            places, links = drawn()
            self._send("/placecell/map", stamp_ns, scene.map_scene(stamp_ns, places, links))
