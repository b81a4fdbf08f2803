"""Floor ("carpet") detection in the panorama (docs/design.md §4, thesis §5.1).

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
_LOG1P = np.log1p(np.arange(256, dtype=np.float32))  # log intensity of a grey level


def chromaticity(bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r, g) bin indices 0..255 of every pixel of a (..., 3) BGR array."""
    b, g, r = (bgr[..., k].astype(np.float32) for k in range(3))
    scale = (BINS - 1) / (b + g + r + 1e-6)  # r, g <= 1: no bin above 255
    return (r * scale).astype(np.int32), (g * scale).astype(np.int32)


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
        return self.levels(bgr).astype(np.float32) / 255.0

    def levels(self, bgr: np.ndarray) -> np.ndarray:
        """(H, W) uint8: the histogram's value at each pixel's chromaticity."""
        r, g = chromaticity(bgr)
        return self.histogram.ravel().take(r * BINS + g)


@dataclass(frozen=True)
class FloorModel:
    """What the robot learns about the floor (stored with the map, docs/design.md §4): its colour
    and the vertical step its texture does not make (:func:`texture_threshold`)."""

    colour: ColourModel
    gradient_threshold: float

    def __post_init__(self) -> None:
        h = self.colour.histogram
        if h.shape != (BINS, BINS) or h.dtype != np.uint8:
            raise ValueError(f"a floor colour histogram is {BINS} x {BINS} uint8, got "
                             f"{h.shape} {h.dtype}")
        if not (np.isfinite(self.gradient_threshold) and self.gradient_threshold > 0):
            raise ValueError(f"a floor's gradient threshold is positive, got "
                             f"{self.gradient_threshold}")


def vertical_steps(grey: np.ndarray, rows: int = 3, columns: int = 5) -> np.ndarray:
    """(H, W) float32: at row r, |mean of log intensity over rows r..r + rows − 1 − that
    over rows r − rows..r − 1|, after averaging ``columns`` columns across (0 where the
    rows do not fit; ``rows`` odd). On the log intensity a change of light scales
    nothing."""
    if rows % 2 == 0:
        raise ValueError(f"vertical_steps: rows must be odd, got {rows}")
    g = (_LOG1P[grey] if grey.dtype == np.uint8
         else np.log1p(grey.astype(np.float32)))
    box = np.asarray(cv2.blur(g, (columns, rows), borderType=cv2.BORDER_WRAP))
    h, half = g.shape[0], rows // 2  # box[c]: the mean over rows c − half..c + half
    step = np.zeros_like(g)
    r0, r1 = rows, h - rows + 1  # rows r with r − rows >= 0 and r + rows − 1 < h
    np.abs(box[r0 + half:r1 + half] - box[r0 - half - 1:r1 - half - 1], out=step[r0:r1])
    return step


MIN_TEXTURE_STEP = 0.02  # log intensity: 2 % in brightness


def texture_threshold(floor_grey: np.ndarray, rows: int = 3, columns: int = 5) -> float:
    """A step the floor's own texture does not make: 1.5 x the 99th percentile of the
    steps within a patch known to be floor (e.g. the one the colour model learns from)."""
    step = vertical_steps(floor_grey, rows, columns)[rows:floor_grey.shape[0] - rows + 1]
    if step.size == 0:
        raise ValueError(f"a floor patch needs more than {2 * rows} rows")
    # A floor without texture (or with no noise) still has a step it does not make.
    return max(1.5 * float(np.percentile(step, 99)), MIN_TEXTURE_STEP)


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
        s = self.settings = settings or FloorSettings()
        self.gradient_threshold = (s.gradient_threshold
                                   if gradient_threshold is None else gradient_threshold)
        self.horizon_row = horizon_row
        self.log_odds = np.full(shape, -s.saturation, np.float32)  # the sky: never floor
        self.log_odds[horizon_row + 1:] = 0.0
        self._ground = horizon_row + 1  # the rows that can be floor
        # Each method's log-odds as a table: by histogram value (colour), by below /
        # above / no boundary (gradient).
        level = np.minimum(np.arange(256) / 255.0 / s.colour_level, 1.0)
        self._colour_lut = _log_odds(0.5 + s.colour_weight * (level - 0.5))
        self._gradient_lo = float(_log_odds(np.array(s.gradient_p)))

    def _evidence(self, bgr: np.ndarray, colour: ColourModel | None
                  ) -> dict[str, np.ndarray]:
        """Each method's log-odds of floor in this frame, rows below the horizon."""
        grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        boundary = gradient_boundary(grey, self.horizon_row, self.gradient_threshold)
        rows = np.arange(self._ground, grey.shape[0])[:, None]
        # A column without a boundary says nothing: the floor may be too like the wall
        # for a step, or not in view.
        lo = np.where(rows >= boundary[None, :], self._gradient_lo, -self._gradient_lo)
        lo[:, boundary >= grey.shape[0]] = 0.0
        out = {"gradient": lo.astype(np.float32)}
        if colour is not None:
            # A colour seen on the floor a tenth as often as its commonest one is still a
            # floor colour: the likelihood is read relative to ``colour_level``.
            out["colour"] = self._colour_lut[colour.levels(bgr[self._ground:])]
        return out

    def update(self, bgr: np.ndarray, colour: ColourModel | None,
               methods: tuple[str, ...] = ("colour", "gradient")) -> None:
        """One frame (the panorama's core, BGR): the chosen methods' evidence added."""
        limit = self.settings.saturation
        ground = self.log_odds[self._ground:]
        for name, lo in self._evidence(bgr, colour).items():
            if name in methods:
                ground += lo
        np.clip(ground, -limit, limit, out=ground)

    def probability(self) -> np.ndarray:
        return (1.0 / (1.0 + np.exp(-self.log_odds))).astype(np.float32)

    def mask(self) -> np.ndarray:
        """(H, W) bool: floor where the grid says more likely than not."""
        return self.log_odds > 0.0
