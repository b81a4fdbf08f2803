"""Landmark speed figures (issue: visual landmarks), on rendered 720 x 120 panoramas.

track16_ms: tracking 16 templates in their search windows, per frame.
lrp_bruteforce_ms_per_place / lrp_fast_ms_per_place: LRP of one 16-landmark place in one
panorama, brute force (every template over the whole panorama) and the fast matcher (its
per-frame preparation shared by the map's places), measured on the same frames in the same
run; lrp_speedup is their ratio. Over a path of ``FRAMES`` frames through a ``PLACES``-place
map: lrp_agreement, the fraction of frames on which both pick the same best place;
lrp_max_difference, the largest LRP difference between them over every place and frame.
"""

from __future__ import annotations

import math
import time

import numpy as np

from daemon.config import load
from daemon.vision.landmarks import LandmarkSet
from daemon.vision.recognition import (
    FastMatcher,
    PreparedPanorama,
    PreparedTemplates,
    lrp_bruteforce,
)
from daemon.vision.selection import select_static
from daemon.vision.tracking import track
from daemon.vision.unwarp import Unwarper
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.panorama import to_grey
from tools.bench.timing import median_seconds

PLACES = 50
FRAMES = 100


def map_and_path() -> tuple[list[LandmarkSet], list[np.ndarray], np.ndarray, int]:
    """The ``PLACES`` places (static selection, the 16 best), the ``FRAMES`` grey
    panoramas of the path, a frame near place 0, and the panorama's wrap margin."""
    config = load(None)
    renderer = Renderer(load_world("generate:office:1"), config.projection, config.panorama,
                        (640, 480))
    unwarper = Unwarper(config.projection, config.panorama)
    margin = config.panorama.wrap_margin
    rng = np.random.default_rng(0)

    def pano(pose: tuple[float, float, float]) -> np.ndarray:
        return unwarper.unwarp(renderer.donut(pose, noise_sigma=2.0, rng=rng))

    places = []  # along the office's corridor, about 0.5 m apart
    for x in np.linspace(2.0, 28.0, PLACES):
        pose = (float(x), 10.0, 0.0)
        places.append(select_static(pano(pose), pano(pose), margin).best(16))
    # The path: down the corridor, weaving 0.2 m sideways and turning up to ±0.4 rad.
    xs = np.linspace(2.1, 27.9, FRAMES)
    frames = [to_grey(pano((float(x), 10.0 + 0.2 * math.sin(1.3 * x), 0.4 * math.sin(0.7 * x))))
              for x in xs]
    near = to_grey(pano((2.1, 10.05, 0.02)))
    return places, frames, near, margin


def run(repeats: int) -> dict[str, float]:
    places, frames, near, margin = map_and_path()
    # Tracking 16 templates of place 0 in a frame near it.
    lms = places[0]
    templates, cols, rows = lms.templates(), lms.cols().astype(float), lms.rows().astype(float)
    track_s = median_seconds(lambda: track(near, margin, templates, cols, rows), repeats,
                             inner=20)

    matcher = FastMatcher()
    prepared_places = [PreparedTemplates.of(p.templates()) for p in places]  # once per map
    matcher.lrp(PreparedPanorama.of(frames[0]), prepared_places[0])  # compile before timing
    brute_t, fast_t, same, diffs = [], [], 0, []
    for frame in frames:
        t0 = time.perf_counter()
        brute = [lrp_bruteforce(frame, p) for p in places]
        t1 = time.perf_counter()
        prepared = PreparedPanorama.of(frame)
        fast = [matcher.lrp(prepared, p) for p in prepared_places]
        t2 = time.perf_counter()
        brute_t.append((t1 - t0) / PLACES)
        fast_t.append((t2 - t1) / PLACES)
        same += int(np.argmax(brute) == np.argmax(fast))
        diffs.append(float(np.max(np.abs(np.array(brute) - np.array(fast)))))
    brute_ms = float(np.median(brute_t)) * 1e3
    fast_ms = float(np.median(fast_t)) * 1e3
    return {
        "track16_ms": round(track_s * 1e3, 3),
        "lrp_bruteforce_ms_per_place": round(brute_ms, 3),
        "lrp_fast_ms_per_place": round(fast_ms, 3),
        "lrp_speedup": round(brute_ms / fast_ms, 2),
        "lrp_agreement": round(same / len(frames), 3),
        "lrp_max_difference": round(max(diffs), 4),
    }
