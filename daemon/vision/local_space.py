"""Local space profiles (docs/design.md §4, thesis §5.2): how far the free floor reaches around the
robot, in 16 directions, and a rotation-invariant comparison of two of them.

The profile's bin k is the mean, over the k-th sixteenth of the panorama's columns, of
the free-space extent of each column: the rows of floor counted up from the bottom row
until the floor grid first says "not floor" (daemon/vision/floor.py). Two profiles match
by c = 1 − min over the 16 circular shifts of SAD(H1, shift(H2, k)) / (MAX · 16), MAX the
largest possible bin value (§5.2.2): 1 for the same spot turned by a multiple of
22.5°; the thesis found 0.91 for the same spot turned 180° and 0.78 three metres away.
"""

from __future__ import annotations

import cv2
import numpy as np

from daemon.vision.floor import (
    ColourModel,
    FloorGrid,
    FloorModel,
    FloorSettings,
    texture_threshold,
)
from kernel.panorama import column_of_bearing

BINS = 16
CAP_M = 5.0  # a bin of profile_m at most this: its largest value
AHEAD_DEG = 20.0  # the floor sample: within this of straight ahead...
SAMPLE_ROWS = 12  # ...in the panorama's bottom rows
UNSEEN_SHARE = 0.5  # a floor patch more than half black (outside the camera's view) is not learned


def profile(floor_mask: np.ndarray, bins: int = BINS) -> np.ndarray:
    """(bins,) float64 free-space extents, in rows, of a (H, W) floor mask (core
    columns, W a multiple of ``bins``)."""
    h, w = floor_mask.shape
    if w % bins:
        raise ValueError(f"a panorama {w} columns wide cannot be cut into {bins} bins")
    not_floor = ~floor_mask[::-1]  # bottom row first
    extent = np.where(not_floor.any(axis=0), np.argmax(not_floor, axis=0), h)
    return extent.reshape(bins, w // bins).mean(axis=1).astype(np.float64)


def profile_m(floor_mask: np.ndarray, distance_of_rows: np.ndarray, cap_m: float = CAP_M,
              bins: int = BINS) -> np.ndarray:
    """(bins,) free-space extents in metres: per column the floor distance of the
    farthest floor row counted up from the bottom (0 where the bottom row is no floor),
    at most ``cap_m``, averaged per bin. ``distance_of_rows`` (H,) is the floor distance
    each row sees (``Unwarper.floor_distance_of_rows``). Rows crowd towards the horizon,
    so in rows a metre far off counts for little; in metres, capped, it counts as much as
    one nearby (design §4: a 1 m move drops the match by more than 0.1 at 0.92 of the
    poses, in rows at 0.67); compare with ``max_value = cap_m``."""
    h, w = floor_mask.shape
    if w % bins:
        raise ValueError(f"a panorama {w} columns wide cannot be cut into {bins} bins")
    not_floor = ~floor_mask[::-1]  # bottom row first
    extent = np.where(not_floor.any(axis=0), np.argmax(not_floor, axis=0), h)
    farthest = np.clip(h - extent, 0, h - 1)  # the top floor row of each column
    metres = np.where(extent > 0, np.minimum(distance_of_rows[farthest], cap_m), 0.0)
    return metres.reshape(bins, w // bins).mean(axis=1).astype(np.float64)


def match(h1: np.ndarray, h2: np.ndarray, max_value: float) -> float:
    """c = 1 − min_k SAD(h1, roll(h2, k)) / (max_value · bins) (§5.2.2), in [0, 1]."""
    return float(match_many(h1, h2[None, :], max_value)[0])


def match_many(h: np.ndarray, profiles: np.ndarray, max_value: float) -> np.ndarray:
    """(P,) the match of ``h`` (bins,) with each row of ``profiles`` (P, bins): for each
    row the nearest of ``h``'s circular shifts in L1 (OpenCV's brute-force nearest
    neighbour, ``batchDistance`` with K = 1)."""
    bins = h.shape[0]
    if len(profiles) == 0:
        return np.zeros(0)
    turn = (np.arange(bins)[None, :] - np.arange(bins)[:, None]) % bins
    shifts = np.ascontiguousarray(np.asarray(h, np.float32)[turn])  # row k: h rolled by k
    sad, _ = cv2.batchDistance(np.ascontiguousarray(profiles, np.float32), shifts,
                               cv2.CV_32F, normType=cv2.NORM_L1, K=1)
    return np.asarray(1.0 - sad[:, 0].astype(np.float64) / (max_value * bins))


class LocalSpace:
    """Local space as the robot sees it (design §4): the floor model learned from the
    floor in front of it, the floor grid fed every frame, the grid's profile in metres.
    Panoramas are colour cores (no wrap margin)."""

    def __init__(self, shape: tuple[int, int], horizon_row: int,
                 distance_of_rows: np.ndarray, settings: FloorSettings | None = None) -> None:
        self.shape, self.horizon_row = shape, horizon_row
        self.distance_of_rows = distance_of_rows
        self.settings = settings or FloorSettings()
        self.floor: FloorModel | None = None  # learned, or stored with the map
        self.grid = self._grid()

    def _grid(self) -> FloorGrid:
        return FloorGrid(self.shape, self.horizon_row, self.settings,
                         None if self.floor is None else self.floor.gradient_threshold)

    def learn_floor(self, core_bgr: np.ndarray) -> None:
        """The floor model from the bottom ``SAMPLE_ROWS`` rows within ``AHEAD_DEG`` of
        ahead (docs/design.md §4: the region right in front of the robot at start-up): its colour
        and the step its texture does not make. The grid starts again."""
        width = core_bgr.shape[1]
        centre = int(round(float(column_of_bearing(0.0, width))))
        half = int(round(width * AHEAD_DEG / 360.0))
        patch = core_bgr[-SAMPLE_ROWS:, np.arange(centre - half, centre + half + 1) % width]
        grey = cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY)
        if float(np.mean(grey == 0)) > UNSEEN_SHARE:
            return  # the camera does not see there (an upward fisheye, design §2): no floor
        self.know_floor(FloorModel(ColourModel.learn(patch), texture_threshold(grey)))

    def know_floor(self, floor: FloorModel) -> None:
        """The floor model to use (learned, or stored with the map); the grid starts
        again."""
        self.floor = floor
        self.grid = self._grid()

    def update(self, core_bgr: np.ndarray,
               methods: tuple[str, ...] = ("colour", "gradient")) -> None:
        """One frame into the grid (the floor learned from it first if not yet)."""
        if self.floor is None:
            self.learn_floor(core_bgr)
        if self.floor is not None:
            self.grid.update(core_bgr, self.floor.colour, methods)

    def profile(self) -> np.ndarray:
        return profile_m(self.grid.mask(), self.distance_of_rows)

    def profile_of(self, core_bgr: np.ndarray) -> np.ndarray:
        """The profile one panorama gives alone (e.g. a place's reference panorama)."""
        grid = self._grid()
        grid.update(core_bgr, None if self.floor is None else self.floor.colour)
        return profile_m(grid.mask(), self.distance_of_rows)
