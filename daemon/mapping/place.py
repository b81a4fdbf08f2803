"""A place of the topological map (SPEC §6, thesis §7.1): what the robot remembers of a spot.

Pure data. The map file (daemon/store) persists it; the service stamps the creation time
(the method reads no clock).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daemon.vision.landmarks import LandmarkSet


@dataclass(frozen=True)
class Place:
    """A learned place: its landmark set (templates, reference bearings, depths and their
    covariances, §4.3-4.6), the reference panorama it was cut from (with wrap margin,
    ``(H, W + 2m, 3)`` BGR or ``(H, W + 2m)`` grey uint8; None in the map the localiser
    holds in memory — a thousand of them would be 270 MB — and read from the map file
    when needed), and what is known about it.

    ``id`` is 0 until the map file assigns one. ``background_lrp`` is the LRP the place's
    landmark set settles at away from it (§7.1), None until measured; ``local_space``
    holds the 16-bin local space profile of chapter 5 once it is measured (None before).
    """

    landmarks: LandmarkSet
    reference_panorama: np.ndarray | None
    label: str = ""
    created_unix_s: float = 0.0
    background_lrp: float | None = None
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
