"""Floor ("carpet") detection in the panorama (SPEC §4, thesis §5.1).

Two detectors, each a per-pixel probability of floor, fused with the Bayes rule in a
per-pixel log-odds grid over methods and over time (§5.1.4):

- :class:`ColourModel` — normalised rg chromaticity (r = R/(R+G+B), g = G/(R+G+B), so a
  change of illumination intensity cancels): a 256 x 256 histogram of floor samples,
  smoothed with a 3 x 3 box kernel and scaled to 0..255, read per pixel.
- :func:`gradient_floor` — per column, scanning up from the bottom row to the horizon,
  the first |I(r, c) − I(r − 1, c)| above a threshold marks the floor's boundary;
  nothing at or above the horizon is ever floor.
- :class:`FloorGrid` — L ← clip(L + Σ_methods log(p / (1 − p)), ±L_max): a person
  walking past must outweigh the evidence gathered before it shows in the grid, while a
  lasting change (the robot's own motion) shows after a few frames; the saturation
  ``L_max`` bounds how long that takes (the thesis's proposed remedy, §5.1.4).

Arrays are the panorama's core (no wrap margin), rows top to bottom.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

BINS = 256


def chromaticity(bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r, g) bin indices 0..255 of every pixel of a (..., 3) BGR array."""
    f = bgr.astype(np.float32)
    total = f.sum(axis=-1) + 1e-6
    r = np.clip(f[..., 2] / total * (BINS - 1), 0, BINS - 1).astype(np.intp)
    g = np.clip(f[..., 1] / total * (BINS - 1), 0, BINS - 1).astype(np.intp)
    return r, g


@dataclass(frozen=True)
class ColourModel:
    """The floor's colour in rg chromaticity (stored with the map)."""

    histogram: np.ndarray  # (256, 256) uint8, 255 at the commonest floor colour

    @classmethod
    def learn(cls, samples_bgr: np.ndarray) -> ColourModel:
        """From floor pixels (any shape ending in 3): e.g. the region in front of the
        robot at start-up, or pixels an operator marked."""
        r, g = chromaticity(samples_bgr.reshape(-1, 3))
        counts = np.zeros((BINS, BINS), np.float32)
        np.add.at(counts, (r, g), 1.0)
        smooth = np.asarray(cv2.blur(counts, (3, 3)))
        peak = float(smooth.max())
        if peak <= 0:
            raise ValueError("a floor colour model needs at least one sample")
        return cls(np.round(smooth / peak * 255.0).astype(np.uint8))

    def likelihood(self, bgr: np.ndarray) -> np.ndarray:
        """(H, W) float32 in [0, 1]: how floor-coloured each pixel is."""
        r, g = chromaticity(bgr)
        return self.histogram[r, g].astype(np.float32) / 255.0


def vertical_steps(grey: np.ndarray, rows: int = 3, columns: int = 5) -> np.ndarray:
    """(H, W) float32: at row r, |mean of log intensity over rows r..r + rows − 1 − that
    over rows r − rows..r − 1|, after averaging ``columns`` columns across (0 where the
    rows do not fit). On the log intensity a change of light scales nothing."""
    g = np.asarray(cv2.blur(np.log1p(grey.astype(np.float32)), (columns, 1),
                            borderType=cv2.BORDER_WRAP))
    h = g.shape[0]
    cum = np.vstack([np.zeros((1, g.shape[1]), np.float32), np.cumsum(g, axis=0)])
    r = np.arange(rows, h - rows + 1)
    step = np.zeros_like(g)
    step[r] = np.abs((cum[r + rows] - cum[r]) - (cum[r] - cum[r - rows])) / rows
    return step


def texture_threshold(floor_grey: np.ndarray, rows: int = 3, columns: int = 5) -> float:
    """A step the floor's own texture does not make: 1.5 x the 99th percentile of the
    steps within a patch known to be floor (e.g. the one the colour model learns from)."""
    step = vertical_steps(floor_grey, rows, columns)[rows:floor_grey.shape[0] - rows + 1]
    if step.size == 0:
        raise ValueError(f"a floor patch needs more than {2 * rows} rows")
    return 1.5 * float(np.percentile(step, 99))


def gradient_boundary(grey: np.ndarray, horizon_row: int, threshold: float, rows: int = 3,
                      columns: int = 5) -> np.ndarray:
    """(W,) each column's floor boundary: the row of the first strong vertical step found
    scanning up from the bottom, H where there is none below the horizon (§5.1.2).

    A step (:func:`vertical_steps`) counts where it exceeds ``threshold`` and is the
    largest of its neighbours up and down. The boundary is then the median over
    ``columns`` neighbouring columns (a carpet's motif or a tile's grout passes one column
    where the wall's foot runs across all). The thesis compared adjacent pixels; on a
    patterned carpet the first such step is the pattern's."""
    step = vertical_steps(grey, rows, columns)
    h = step.shape[0]
    peak = (step >= np.roll(step, 1, axis=0)) & (step >= np.roll(step, -1, axis=0))
    strong = (step > threshold) & peak & (np.arange(h)[:, None] > horizon_row)
    lowest = h - 1 - np.argmax(strong[::-1], axis=0)  # the boundary: row of the step
    boundary = np.where(strong.any(axis=0), lowest, h)
    half = columns // 2
    return np.median(np.stack([np.roll(boundary, k) for k in range(-half, half + 1)]),
                     axis=0)


def gradient_floor(grey: np.ndarray, horizon_row: int, threshold: float) -> np.ndarray:
    """(H, W) bool: the pixels below each column's :func:`gradient_boundary`; a column
    with none has no floor."""
    boundary = gradient_boundary(grey, horizon_row, threshold)
    return np.arange(grey.shape[0])[:, None] >= boundary[None, :]


@dataclass(frozen=True)
class FloorSettings:
    """Each frame adds at most log(0.75/0.25) + log(0.7/0.3) ≈ 1.95 to a pixel's log-odds
    and the grid saturates at 8: evidence gathered over 4-5 frames outweighs two frames
    of a person in front, and a lasting change shows after 4-5 frames. Not yet tuned on
    textured floors (the ``floor`` experiment is to come)."""

    colour_weight: float = 0.5  # p = 0.5 + w (level − 0.5): how far the colour is trusted
    colour_level: float = 0.1  # level = min(likelihood / this, 1)
    gradient_p: float = 0.75  # p(floor) below the gradient boundary (1 − it above)
    gradient_threshold: float = 0.25  # log intensity: a 13 % step in brightness
    saturation: float = 8.0  # |log-odds| at most this (thesis §5.1.4)


def _log_odds(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-3, 1 - 1e-3)
    return np.log(p / (1.0 - p)).astype(np.float32)


class FloorGrid:
    """The per-pixel log-odds of floor, fused over methods and frames (§5.1.4)."""

    def __init__(self, shape: tuple[int, int], horizon_row: int,
                 settings: FloorSettings | None = None,
                 gradient_threshold: float | None = None) -> None:
        """``gradient_threshold``: learned from the floor (:func:`texture_threshold`);
        the settings' fixed one without."""
        self.settings = settings or FloorSettings()
        self.gradient_threshold = (self.settings.gradient_threshold
                                   if gradient_threshold is None else gradient_threshold)
        self.horizon_row = horizon_row
        self.log_odds = np.zeros(shape, np.float32)
        self._sky = slice(0, horizon_row + 1)  # rows never floor

    def observations(self, bgr: np.ndarray, colour: ColourModel | None
                     ) -> dict[str, np.ndarray]:
        """Each method's p(floor) for this frame ("colour" only with a model)."""
        s = self.settings
        grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        boundary = gradient_boundary(grey, self.horizon_row, self.gradient_threshold)
        below = np.arange(grey.shape[0])[:, None] >= boundary[None, :]
        # A column without a boundary says nothing: the floor may be too like the wall
        # for a step, or not in view.
        p = np.where(below, s.gradient_p, 1.0 - s.gradient_p)
        p[:, boundary >= grey.shape[0]] = 0.5
        out = {"gradient": p}
        if colour is not None:
            # A colour seen on the floor a tenth as often as its commonest one is still a
            # floor colour: the likelihood is read relative to ``colour_level``.
            level = np.minimum(colour.likelihood(bgr) / s.colour_level, 1.0)
            out["colour"] = 0.5 + s.colour_weight * (level - 0.5)
        return out

    def update(self, bgr: np.ndarray, colour: ColourModel | None,
               methods: tuple[str, ...] = ("colour", "gradient")) -> None:
        """One frame (the panorama's core, BGR): the chosen methods' evidence added."""
        limit = self.settings.saturation
        for name, p in self.observations(bgr, colour).items():
            if name in methods:
                self.log_odds += _log_odds(p)
        np.clip(self.log_odds, -limit, limit, out=self.log_odds)
        self.log_odds[self._sky] = -limit

    def probability(self) -> np.ndarray:
        return (1.0 / (1.0 + np.exp(-self.log_odds))).astype(np.float32)

    def mask(self) -> np.ndarray:
        """(H, W) bool: floor where the grid says more likely than not."""
        return self.log_odds > 0.0
