"""Recognising a landmark set in a panorama (SPEC §3.4, thesis §4.4).

LRP_p(i) = mean over the landmarks of place p of the best NCC of each template anywhere
in panorama i. ``lrp_bruteforce`` is the reference: ``cv2.matchTemplate`` (normalised) of
every template over the whole panorama. ``FastMatcher`` computes the same numbers with
less work by sharing what does not depend on the template:

    NCC(x) = Σ (T − T̄) I(x) / ( ||T − T̄|| · sqrt(Σ I(x)² − (Σ I(x))² / n) )

The numerator is a plain correlation with the zero-mean template (Σ (T − T̄) Ī = 0), and
the window energies in the denominator are two box filters of the panorama, computed once
per frame and shared by every template of every place; each template's own norm is
computed once. The result equals brute force up to float rounding, over the whole
panorama, with no band or pyramid that could miss a peak.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from daemon.vision.landmarks import TEMPLATE, LandmarkSet
from daemon.vision.ncc import ncc_map


def best_ncc_bruteforce(panorama_grey: np.ndarray, templates: np.ndarray) -> np.ndarray:
    """(N,) best NCC of each (16, 16) template anywhere in the panorama."""
    return np.array([float(ncc_map(panorama_grey, t).max()) for t in templates])


def lrp_bruteforce(panorama_grey: np.ndarray, landmarks: LandmarkSet) -> float:
    """LRP (§4.4): mean of the best NCC of each template over the whole panorama."""
    return float(best_ncc_bruteforce(panorama_grey, landmarks.templates()).mean())


@dataclass
class PreparedPanorama:
    """A panorama prepared once per frame for matching many 16 x 16 templates: the float
    image and the root energy of every window about its mean."""

    image: np.ndarray  # (H, W) float32 grey
    window_norm: np.ndarray  # (H - 15, W - 15) sqrt(Σ I² − (Σ I)² / n) per window

    @classmethod
    def of(cls, panorama_grey: np.ndarray) -> PreparedPanorama:
        image = panorama_grey.astype(np.float32)
        n = TEMPLATE * TEMPLATE
        h, w = image.shape[0] - TEMPLATE + 1, image.shape[1] - TEMPLATE + 1
        s1 = cv2.boxFilter(image, cv2.CV_64F, (TEMPLATE, TEMPLATE), anchor=(0, 0),
                           normalize=False, borderType=cv2.BORDER_CONSTANT)[:h, :w]
        s2 = cv2.boxFilter(image.astype(np.float64) ** 2, cv2.CV_64F, (TEMPLATE, TEMPLATE),
                           anchor=(0, 0), normalize=False,
                           borderType=cv2.BORDER_CONSTANT)[:h, :w]
        energy = np.maximum(s2 - s1 * s1 / n, 0.0)
        return cls(image, np.sqrt(energy).astype(np.float32))


@dataclass(frozen=True)
class PreparedTemplates:
    """Zero-mean float templates and their norms (once per place, not per frame)."""

    zero_mean: np.ndarray  # (N, 16, 16) float32
    norms: np.ndarray  # (N,)

    @classmethod
    def of(cls, templates: np.ndarray) -> PreparedTemplates:
        t = templates.astype(np.float32)
        t = t - t.mean(axis=(1, 2), keepdims=True)
        return cls(t, np.sqrt((t.astype(np.float64) ** 2).sum(axis=(1, 2))))


class FastMatcher:
    """Best NCC of many templates in one panorama with the normalisation shared."""

    # Windows flatter than this (grey levels RMS) count as NCC 0, as OpenCV does.
    MIN_WINDOW_RMS = 1e-3

    def best_ncc(self, pano: PreparedPanorama, templates: PreparedTemplates) -> np.ndarray:
        out = np.zeros(len(templates.norms))
        floor = self.MIN_WINDOW_RMS * TEMPLATE
        denominator_ok = pano.window_norm > floor
        inv_window = np.where(denominator_ok, 1.0 / np.maximum(pano.window_norm, floor), 0.0)
        for i, (t, norm) in enumerate(zip(templates.zero_mean, templates.norms, strict=True)):
            if norm <= floor:
                continue  # a flat template matches nothing (NCC 0 everywhere)
            corr = cv2.matchTemplate(pano.image, t, cv2.TM_CCORR)  # Σ (T − T̄) I(x)
            out[i] = float((corr * inv_window).max()) / norm
        return out

    def lrp(self, pano: PreparedPanorama, templates: PreparedTemplates) -> float:
        return float(self.best_ncc(pano, templates).mean())
