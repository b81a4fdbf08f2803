"""Landmarks and landmark sets: what a place is made of (docs/design.md §3, thesis chapter 4).

Positions are in panorama array coordinates (with wrap margin): ``col``/``row`` of the
template's top-left pixel. Bearings follow kernel/panorama.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kernel.panorama import bearing_of_column

TEMPLATE = 16  # template side, pixels (§4.2)


@dataclass(frozen=True)
class Landmark:
    """One 16 x 16 grey template with its reference bearing, row, depth and covariance."""

    template: np.ndarray  # (16, 16) uint8
    row: int  # top row in the reference panorama
    col: int  # left column in the reference panorama's core (0 <= col < W)
    bearing: float  # reference bearing of the template centre (rad)
    depth: float = float("nan")  # metres; NaN until estimated (TBL, §4.6)
    covariance: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))  # (d, γ)
    score: float = 0.0  # selection score: valley measure r (static) or margin (TBL)


@dataclass(frozen=True)
class LandmarkSet:
    """A place's landmarks (16 after TBL, docs/design.md §3) and the panorama width they live in."""

    landmarks: tuple[Landmark, ...]
    width: int  # panorama core columns (bearing per column)
    margin: int  # wrap margin of the panorama they were cut from

    def templates(self) -> np.ndarray:
        """(N, 16, 16) uint8."""
        return np.stack([lm.template for lm in self.landmarks])

    def rows(self) -> np.ndarray:
        return np.array([lm.row for lm in self.landmarks])

    def cols(self) -> np.ndarray:
        return np.array([lm.col for lm in self.landmarks])

    def best(self, count: int) -> LandmarkSet:
        """The ``count`` landmarks with the highest score (e.g. the 16 best of a static
        selection), best first."""
        ranked = sorted(self.landmarks, key=lambda lm: lm.score, reverse=True)
        return LandmarkSet(tuple(ranked[:count]), self.width, self.margin)


def centre_bearing(col: float, width: int) -> float:
    """Bearing of the centre of a template whose left core column is ``col``."""
    return float(bearing_of_column(col + (TEMPLATE - 1) / 2.0, width))
