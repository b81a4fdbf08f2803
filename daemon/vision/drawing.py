"""Pictures for people: a place's reference panorama with its landmarks drawn on it
(map export, ``map/place/<id>/panorama``)."""

from __future__ import annotations

import cv2
import numpy as np

from daemon.vision.landmarks import TEMPLATE, LandmarkSet

LANDMARK_COLOUR = (0, 255, 255)  # BGR yellow: visible on walls, floors and ceilings alike


def draw_landmarks(panorama: np.ndarray, landmarks: LandmarkSet, scale: int = 2
                   ) -> np.ndarray:
    """The panorama's core (``(H, W[, 3])`` uint8), enlarged ``scale`` times, with each
    landmark's 16 x 16 template outlined and numbered in bearing order."""
    m = landmarks.margin
    core = panorama[:, m: panorama.shape[1] - m] if m else panorama
    image = cv2.cvtColor(core, cv2.COLOR_GRAY2BGR) if core.ndim == 2 else core.copy()
    image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    for i, lm in enumerate(landmarks.landmarks):
        x, y = lm.col * scale, lm.row * scale
        side = TEMPLATE * scale
        cv2.rectangle(image, (x, y), (x + side - 1, y + side - 1), LANDMARK_COLOUR, 1)
        cv2.putText(image, str(i), (x + 1, max(y - 2, 8)), cv2.FONT_HERSHEY_PLAIN, 0.8,
                    LANDMARK_COLOUR, 1, cv2.LINE_AA)
    return image
