"""Zero-mean normalised cross-correlation (NCC, §4.5.2): robust to gain and offset."""

from __future__ import annotations

import cv2
import numpy as np


def ncc_map(image: np.ndarray, template: np.ndarray) -> np.ndarray:
    """NCC of ``template`` at every position of ``image`` (both grey); flat windows give 0.

    NCC = Σ (T − T̄)(I − Ī) / sqrt(Σ (T − T̄)² Σ (I − Ī)²)   (§4.5.2, zero-mean)
    """
    result = cv2.matchTemplate(image, template, cv2.TM_CCOEFF_NORMED)
    return np.nan_to_num(result, nan=0.0, posinf=0.0, neginf=0.0)


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    """NCC of two equal-size patches."""
    a = a.astype(np.float64) - a.mean()
    b = b.astype(np.float64) - b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 0 else 0.0


def ncc_under_light(template: np.ndarray, gains: tuple[float, ...]) -> float:
    """The lowest NCC of a grey ``template`` with itself under each light gain, its pixels
    clipped to 0..255 as a camera's would be. NCC is blind to gain alone (§4.5.2); what a
    brighter scene takes away is the pattern in the pixels that saturate."""
    t = template.astype(np.float64)
    return min(ncc(t, np.clip(np.round(t * g), 0.0, 255.0)) for g in gains)


def subpixel_peak(scores: np.ndarray) -> tuple[float, float, float]:
    """(score, x, y) of the maximum of a score map, refined by a parabola through the
    peak and its neighbours along each axis."""
    y, x = np.unravel_index(int(np.argmax(scores)), scores.shape)
    best = float(scores[y, x])

    def refine(m1: float, c: float, p1: float) -> float:
        den = m1 - 2.0 * c + p1
        return 0.0 if den >= 0 else 0.5 * (m1 - p1) / den

    fx = refine(scores[y, x - 1], best, scores[y, x + 1]) if 0 < x < scores.shape[1] - 1 else 0.0
    fy = refine(scores[y - 1, x], best, scores[y + 1, x]) if 0 < y < scores.shape[0] - 1 else 0.0
    return best, x + fx, y + fy


FLAT_RMS = 1e-3  # windows or templates flatter than this (grey levels RMS) match nothing


def window_norms(image: np.ndarray, side: int) -> np.ndarray:
    """sqrt(Σ I² − (Σ I)² / n) of every side x side window (top-left indexed)."""
    h, w = image.shape[0] - side + 1, image.shape[1] - side + 1
    s1 = cv2.boxFilter(image, cv2.CV_64F, (side, side), anchor=(0, 0), normalize=False,
                       borderType=cv2.BORDER_CONSTANT)[:h, :w]
    s2 = cv2.boxFilter(image.astype(np.float64) ** 2, cv2.CV_64F, (side, side),
                       anchor=(0, 0), normalize=False, borderType=cv2.BORDER_CONSTANT)[:h, :w]
    return np.sqrt(np.maximum(s2 - s1 * s1 / (side * side), 0.0)).astype(np.float32)


def inverse_norms(norms: np.ndarray, floor: float) -> np.ndarray:
    """1 / norm, and 0 for windows flatter than ``floor`` (they match nothing)."""
    return np.where(norms > floor, 1.0 / np.maximum(norms, floor), 0.0).astype(np.float32)


class PreparedImage:
    """A grey image prepared once for the best NCC of many square templates anywhere in
    it: the maximum of :func:`ncc_map` (OpenCV's TM_CCOEFF_NORMED), with what depends on
    the image alone — its pixels as float32 and, per template side, the inverse of every
    window's norm about its mean — computed once instead of in every call. A template is
    then one plain cross-correlation of the zero-mean template,
    Σ (T − T̄) I = Σ (T − T̄)(I − Ī), scaled by those inverses: 0.5 ms against 1.2 ms at
    752 x 120 (a feature search makes hundreds, design §5). Windows flatter than
    ``FLAT_RMS`` grey levels RMS match nothing (0), as OpenCV's flat windows do."""

    def __init__(self, image: np.ndarray) -> None:
        self.image = np.ascontiguousarray(image, dtype=np.float32)
        self._inverse_norms: dict[int, np.ndarray] = {}  # by template side
        self._half: PreparedImage | None = None  # at half resolution, for hints

    def best_ncc(self, template: np.ndarray) -> float:
        """max(ncc_map(image, template)), to float rounding (1e-4)."""
        t, t_norm = _zero_mean(template)
        if t_norm < np.finfo(float).eps:  # a flat template: OpenCV answers 1 everywhere
            return 1.0
        num = cv2.matchTemplate(self.image, t, cv2.TM_CCORR)
        num *= self._inverse(t.shape[0])
        return min(float(num.max()) / t_norm, 1.0)

    def ncc_near_coarse_peak(self, template: np.ndarray) -> float:
        """The template's NCC where a half-resolution search puts its best match (the
        best of the HINT_REACH x HINT_REACH positions there): one the template has in
        this image, so never above :meth:`best_ncc`, at a fraction of its cost. A
        search that only needs to know that a template matches at least so well
        somewhere (the feature search's exact pruning, design §5) asks this first."""
        t, t_norm = _zero_mean(template)
        if t_norm < np.finfo(float).eps:
            return 1.0
        side = t.shape[0]
        inverse = self._inverse(side)
        h, w = inverse.shape
        if h < HINT_REACH or w < HINT_REACH:
            return self.best_ncc(template)
        if self._half is None:
            self._half = PreparedImage(cv2.pyrDown(self.image))
        small, _ = _zero_mean(cv2.resize(template, (side // 2, side // 2),
                                         interpolation=cv2.INTER_AREA))
        coarse = cv2.matchTemplate(self._half.image, small, cv2.TM_CCORR)
        coarse *= self._half._inverse(side // 2)
        y, x = np.unravel_index(int(np.argmax(coarse)), coarse.shape)
        y0 = min(max(2 * int(y) - HINT_REACH // 2, 0), h - HINT_REACH)
        x0 = min(max(2 * int(x) - HINT_REACH // 2, 0), w - HINT_REACH)
        window = self.image[y0:y0 + side + HINT_REACH - 1, x0:x0 + side + HINT_REACH - 1]
        num = cv2.matchTemplate(window, t, cv2.TM_CCORR)
        num *= inverse[y0:y0 + HINT_REACH, x0:x0 + HINT_REACH]
        return min(float(num.max()) / t_norm, 1.0)

    def _inverse(self, side: int) -> np.ndarray:
        inverse = self._inverse_norms.get(side)
        if inverse is None:
            inverse = inverse_norms(window_norms(self.image, side), FLAT_RMS * side)
            self._inverse_norms[side] = inverse
        return inverse


HINT_REACH = 5  # side of the square of positions tried round a coarse peak (one coarse
# pixel is two full-resolution ones, so the peak's full-resolution place is within it)


def _zero_mean(template: np.ndarray) -> tuple[np.ndarray, float]:
    """A square template less its mean (float32) and its norm."""
    side = template.shape[0]
    assert template.shape == (side, side), "a square template"
    t = template.astype(np.float64)
    t -= t.mean()
    return t.astype(np.float32), float(np.sqrt((t * t).sum()))
