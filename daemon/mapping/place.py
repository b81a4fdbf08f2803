"""A place of the topological map (design §6, thesis §7.1): what the robot remembers of a spot.

Pure data. The map file (daemon/store) persists it; the service stamps the creation time
(the method reads no clock).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from daemon.vision.landmarks import LandmarkSet
from daemon.vision.recognition import best_ncc_elsewhere
from daemon.vision.signature import signature
from kernel.panorama import to_grey


@dataclass(frozen=True)
class Place:
    """A learned place: its landmark set (templates, reference bearings, depths and their
    covariances, §4.3-4.6), the reference panorama it was cut from (with wrap margin,
    ``(H, W + 2m, 3)`` BGR or ``(H, W + 2m)`` grey uint8; None in the map the localiser
    holds in memory — a thousand of them would be 270 MB — and read from the map file
    when needed), and what is known about it.

    ``id`` is 0 until the map file assigns one. ``background_lrp`` is the LRP the place's
    landmark set settles at away from it (§7.1), None until measured;
    ``background_estimate`` the same level estimated when the place is learned
    (:func:`estimate_background`), used until it is measured; ``background_cross`` the
    mean LRP of its landmarks in other places' reference views (daemon/mapping/
    backgrounds.py; None until the map holds another place); ``signature`` the
    reference panorama's rotation-invariant signature (daemon/vision/signature.py), the
    cheap cue that orders the global search (None in maps made before it); ``local_space``
    holds the 16-bin local space profile of chapter 5 once it is measured (None before).
    """

    landmarks: LandmarkSet
    reference_panorama: np.ndarray | None
    label: str = ""
    created_unix_s: float = 0.0
    background_lrp: float | None = None
    background_estimate: float | None = None
    background_cross: float | None = None
    signature: np.ndarray | None = None  # the reference panorama's azimuth signature
    local_space: np.ndarray | None = None
    id: int = 0

    def __post_init__(self) -> None:
        pano = self.reference_panorama
        if pano is not None and (pano.dtype != np.uint8 or pano.ndim not in (2, 3)):
            raise ValueError(f"a reference panorama is uint8 (H, W) or (H, W, 3), got "
                             f"{pano.dtype} {pano.shape}")
        if pano is not None and pano.shape[1] != self.landmarks.width + 2 * self.landmarks.margin:
            raise ValueError(f"reference panorama has {pano.shape[1]} columns, the landmark "
                             f"set lives in {self.landmarks.width} + 2 x "
                             f"{self.landmarks.margin}")
        if len(self.label) > 200:
            raise ValueError("a place label is at most 200 characters")

    @property
    def landmark_count(self) -> int:
        return len(self.landmarks.landmarks)


def with_cues(place: Place) -> Place:
    """The place with what its reference panorama gives the global search (design §9):
    the background estimate and the signature."""
    pano = place.reference_panorama
    assert pano is not None, "cues come from the reference panorama"
    return dataclasses.replace(
        place, background_estimate=estimate_background(place.landmarks, pano),
        signature=signature(to_grey(pano), place.landmarks.margin))


def estimate_background(landmarks: LandmarkSet, reference_panorama: np.ndarray) -> float:
    """The background LRP (§7.1) foreseen from the place's own reference panorama: the
    mean over its landmarks of the best NCC of each away from where it was found (its
    best look-alike). Far from the place every template settles on some look-alike, so
    this is the level its LRP falls to; on the office corridor 0.80, 0.70, 0.67, 0.62
    against 0.79, 0.72, 0.67, 0.64 measured 2-5 m away (design §9)."""
    grey = to_grey(reference_panorama)
    return float(best_ncc_elsewhere(grey, landmarks.margin, landmarks.templates(),
                                    landmarks.cols(), landmarks.rows()).mean())
