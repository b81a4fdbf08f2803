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
