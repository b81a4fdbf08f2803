"""Places to bytes and back, for the map file: landmark sets as ``.npz`` (no pickles), the
reference panorama as a lossless PNG, each place's bytes guarded by a SHA-256 digest."""

from __future__ import annotations

import hashlib
import io

import cv2
import numpy as np

from daemon.vision.landmarks import TEMPLATE, Landmark, LandmarkSet
from kernel.errors import MapStoreError

_LANDMARK_ARRAYS = ("templates", "rows", "cols", "bearings", "depths", "covariances", "scores",
                    "shape")


def encode_landmarks(landmarks: LandmarkSet) -> bytes:
    lms = landmarks.landmarks
    buf = io.BytesIO()
    np.savez(buf,
             templates=np.stack([lm.template for lm in lms]).astype(np.uint8)
             if lms else np.zeros((0, TEMPLATE, TEMPLATE), np.uint8),
             rows=np.array([lm.row for lm in lms], dtype=np.int64),
             cols=np.array([lm.col for lm in lms], dtype=np.int64),
             bearings=np.array([lm.bearing for lm in lms], dtype=np.float64),
             depths=np.array([lm.depth for lm in lms], dtype=np.float64),
             covariances=np.array([lm.covariance for lm in lms], dtype=np.float64
                                  ).reshape(len(lms), 2, 2),
             scores=np.array([lm.score for lm in lms], dtype=np.float64),
             shape=np.array([landmarks.width, landmarks.margin], dtype=np.int64))
    return buf.getvalue()


def decode_landmarks(blob: bytes, where: str) -> LandmarkSet:
    try:
        with np.load(io.BytesIO(blob), allow_pickle=False) as z:
            arrays = {k: z[k] for k in _LANDMARK_ARRAYS}
    except (OSError, ValueError, KeyError, EOFError) as e:
        raise MapStoreError(f"{where}: the landmark set cannot be read ({e})") from e
    n = len(arrays["templates"])
    if arrays["templates"].shape[1:] != (TEMPLATE, TEMPLATE) or any(
            len(arrays[k]) != n for k in _LANDMARK_ARRAYS[1:-1]):
        raise MapStoreError(f"{where}: the landmark set's arrays do not agree in shape")
    width, margin = (int(v) for v in arrays["shape"])
    lms = tuple(
        Landmark(template=arrays["templates"][i], row=int(arrays["rows"][i]),
                 col=int(arrays["cols"][i]), bearing=float(arrays["bearings"][i]),
                 depth=float(arrays["depths"][i]), covariance=arrays["covariances"][i],
                 score=float(arrays["scores"][i]))
        for i in range(n))
    return LandmarkSet(lms, width, margin)


def encode_image(image: np.ndarray) -> bytes:
    ok, png = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise MapStoreError(f"cannot encode an image of shape {image.shape} as PNG")
    return png.tobytes()


def decode_image(blob: bytes, where: str) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise MapStoreError(f"{where}: the image cannot be decoded")
    return image


def encode_vector(v: np.ndarray | None) -> bytes | None:
    return None if v is None else np.asarray(v, dtype="<f8").tobytes()


def decode_vector(blob: bytes | None) -> np.ndarray | None:
    return None if blob is None else np.frombuffer(blob, dtype="<f8").copy()


def digest(*blobs: bytes | None) -> str:
    h = hashlib.sha256()
    for b in blobs:
        h.update(b"\x00" if b is None else len(b).to_bytes(8, "little") + b)
    return h.hexdigest()
