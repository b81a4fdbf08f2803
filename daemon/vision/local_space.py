"""Local space profiles (SPEC §4, thesis §5.2): how far the free floor reaches around the
robot, in 16 directions, and a rotation-invariant comparison of two of them.

The profile's bin k is the mean, over the k-th sixteenth of the panorama's columns, of
the free-space extent of each column: the rows of floor counted up from the bottom row
until the floor grid first says "not floor" (daemon/vision/floor.py). Two profiles match
by c = 1 − min over the 16 circular shifts of SAD(H1, shift(H2, k)) / (MAX · 16), MAX the
largest possible bin value (§5.2.2): 1 for the same spot turned by a multiple of
22.5°; the thesis found 0.91 for the same spot turned 180° and 0.78 three metres away.
"""

from __future__ import annotations

import numpy as np

BINS = 16


def profile(floor_mask: np.ndarray, bins: int = BINS) -> np.ndarray:
    """(bins,) float64 free-space extents, in rows, of a (H, W) floor mask (core
    columns, W a multiple of ``bins``)."""
    h, w = floor_mask.shape
    if w % bins:
        raise ValueError(f"a panorama {w} columns wide cannot be cut into {bins} bins")
    not_floor = ~floor_mask[::-1]  # bottom row first
    extent = np.where(not_floor.any(axis=0), np.argmax(not_floor, axis=0), h)
    return extent.reshape(bins, w // bins).mean(axis=1).astype(np.float64)


def profile_m(floor_mask: np.ndarray, distance_of_rows: np.ndarray, cap_m: float = 5.0,
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
    """(P,) the match of ``h`` (bins,) with each row of ``profiles`` (P, bins)."""
    bins = h.shape[0]
    shifts = np.stack([np.roll(h, k) for k in range(bins)])  # (bins, bins)
    sad = np.abs(profiles[:, None, :] - shifts[None, :, :]).sum(axis=2)  # (P, bins)
    return np.asarray(1.0 - sad.min(axis=1) / (max_value * bins))


def local_space_set(h: np.ndarray, profiles: np.ndarray, max_value: float,
                    margin: float) -> np.ndarray:
    """Indices of the profiles whose match is within ``margin`` of the best (§9.4.1:
    B = 0.075 kept the true place in the set on 98 % of frames)."""
    c = match_many(h, profiles, max_value)
    return np.flatnonzero(c >= c.max() - margin)
