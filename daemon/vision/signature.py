"""A rotation-invariant signature of a whole panorama: a cheap cue of where the robot is
(docs/design.md §4 "go beyond", design §9; in the role of thesis §9.4's local space cue).

The grey panorama's rows are averaged in ``BANDS`` horizontal bands; each band is a
periodic signal along azimuth, and the magnitudes of its first ``HARMONICS`` Fourier
coefficients do not change when the robot turns (a turn is a circular shift). Each
band's magnitudes are divided by their norm (an illumination gain cancels). Two
signatures compare by their mean cosine over the bands, in [0, 1]: a few microseconds
per place, against milliseconds for recognising its landmarks.
"""

from __future__ import annotations

import numpy as np

from kernel.panorama import core_of

BANDS = 6
HARMONICS = 24


def signature(panorama_grey: np.ndarray, margin: int) -> np.ndarray:
    """(BANDS * HARMONICS,) float64 of a grey panorama with wrap ``margin``."""
    core = core_of(panorama_grey, margin).astype(np.float64)
    edges = np.linspace(0, core.shape[0], BANDS + 1).astype(int)
    bands = np.stack([core[a:b].mean(axis=0) for a, b in zip(edges, edges[1:], strict=False)])
    magnitude = np.abs(np.fft.rfft(bands - bands.mean(axis=1, keepdims=True), axis=1))
    magnitude = magnitude[:, 1:HARMONICS + 1]
    norms = np.linalg.norm(magnitude, axis=1, keepdims=True)
    return (magnitude / np.maximum(norms, 1e-9)).ravel()


def similarity(frame: np.ndarray, places: np.ndarray) -> np.ndarray:
    """(P,) the mean cosine over the bands between ``frame`` (S,) and each row of
    ``places`` (P, S)."""
    a = frame.reshape(BANDS, HARMONICS)
    b = places.reshape(len(places), BANDS, HARMONICS)
    return np.asarray((b * a[None]).sum(axis=2).mean(axis=1))
