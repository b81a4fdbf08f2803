"""Static landmark selection (docs/design.md §3, thesis §4.2).

For every candidate 16 x 16 template T at (x, y) of panorama 1, T is slid over the 32 x 32
window centred on (x, y) of panorama 2 with SAD (deliberately not normalised), giving a
17 x 17 distortion matrix D. g = D at the centre (the self match); g' = the minimum over the
ring of 16 cells at distance 2 from the centre. The local uniqueness r = 1 − g/g' is high
for a steep, distinctive valley. The 32 best templates are chosen, 8 from each 90° sector
(front, left, back, right), not overlapping; templates with too little texture are
rejected.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from daemon.vision.landmarks import TEMPLATE, Landmark, LandmarkSet, centre_bearing
from kernel.panorama import add_wrap_margin, core_of, to_grey

SHIFT = 8  # a 32 x 32 window around a 16 x 16 template: shifts of -8..8
MIN_TEXTURE = 6.0  # grey-level std below which a window is too flat to be a landmark
RING = [(dy, dx) for dy in range(-2, 3) for dx in range(-2, 3) if max(abs(dy), abs(dx)) == 2]


def sad_maps(p1: np.ndarray, p2: np.ndarray, shifts: list[tuple[int, int]]) -> np.ndarray:
    """D[k](y, x): SAD of the template at top-left (x, y) in p1 against p2 shifted by
    shifts[k] = (dy, dx). p1/p2 are grey core panoramas (wrapped horizontally)."""
    H, W = p1.shape
    a = p1.astype(np.int16)
    b_wrapped = add_wrap_margin(p2.astype(np.int16), SHIFT)
    b_pad = cv2.copyMakeBorder(b_wrapped, SHIFT, SHIFT, 0, 0, cv2.BORDER_REPLICATE)
    out = np.empty((len(shifts), H - TEMPLATE + 1, W), np.float32)
    for k, (dy, dx) in enumerate(shifts):
        b = b_pad[SHIFT + dy: SHIFT + dy + H, SHIFT + dx: SHIFT + dx + W]
        diff = np.abs(a - b).astype(np.float32)
        # Sum over the 16 x 16 window whose top-left is (x, y), wrapping in x.
        wrapped = np.concatenate([diff, diff[:, : TEMPLATE - 1]], axis=1)
        box = cv2.boxFilter(wrapped, -1, (TEMPLATE, TEMPLATE), anchor=(0, 0),
                            normalize=False, borderType=cv2.BORDER_CONSTANT)
        out[k] = box[: H - TEMPLATE + 1, :W]
    return out


def valley_measure(p1: np.ndarray, p2: np.ndarray, variant: str = "ring"
                   ) -> tuple[np.ndarray, np.ndarray]:
    """r = 1 − g/g' for every template position (top-left row, core column), and g'.

    variant "ring": g' = min over the 16 cells at distance 2 (the thesis's sixteen
    surrounding values); "outside": min over everything outside the central 3 x 3."""
    if variant == "ring":
        shifts = [(0, 0), *RING]
    elif variant == "outside":
        shifts = [(0, 0)] + [(dy, dx) for dy in range(-SHIFT, SHIFT + 1)
                             for dx in range(-SHIFT, SHIFT + 1) if max(abs(dy), abs(dx)) >= 2]
    else:
        raise ValueError(f"unknown valley variant {variant!r}")
    d = sad_maps(p1, p2, shifts)
    g = d[0]
    g2 = d[1:].min(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(g2 > 0, 1.0 - g / g2, 0.0)
    return r.astype(np.float32), g2


def texture(p: np.ndarray) -> np.ndarray:
    """Standard deviation of every 16 x 16 window (top-left indexed, wrapping in x)."""
    f = p.astype(np.float32)
    wrapped = np.concatenate([f, f[:, : TEMPLATE - 1]], axis=1)
    n = TEMPLATE * TEMPLATE
    s1 = cv2.boxFilter(wrapped, -1, (TEMPLATE, TEMPLATE), anchor=(0, 0), normalize=False,
                       borderType=cv2.BORDER_CONSTANT)
    s2 = cv2.boxFilter(wrapped * wrapped, -1, (TEMPLATE, TEMPLATE), anchor=(0, 0),
                       normalize=False, borderType=cv2.BORDER_CONSTANT)
    var = np.maximum(s2 / n - (s1 / n) ** 2, 0.0)
    H, W = p.shape
    return np.sqrt(var[: H - TEMPLATE + 1, :W])


def select_static(pano1: np.ndarray, pano2: np.ndarray, margin: int, *, count: int = 32,
                  per_sector: int = 8, min_texture: float = MIN_TEXTURE, variant: str = "ring",
                  exclude_rows: tuple[int, int] | None = None) -> LandmarkSet:
    """The ``count`` best landmarks, ``per_sector`` from each 90° sector (docs/design.md §3).

    pano1/pano2: two panoramas (with wrap margin ``margin``) at the reference pose."""
    g1 = core_of(to_grey(pano1), margin)
    g2 = core_of(to_grey(pano2), margin)
    H, W = g1.shape
    r, _ = valley_measure(g1, g2, variant)
    r[texture(g1) < min_texture] = -np.inf  # flat regions have no valley worth the name
    if exclude_rows is not None:
        r[exclude_rows[0]: exclude_rows[1]] = -np.inf
    order = np.argsort(r, axis=None)[::-1]
    chosen: list[tuple[int, int, float]] = []
    sectors = [0, 0, 0, 0]
    for flat in order:
        score = float(r.flat[flat])
        if not math.isfinite(score) or len(chosen) == count:
            break
        y, x = divmod(int(flat), W)
        bearing = centre_bearing(x, W)
        # Sectors centred on front (0), left (+π/2), back (π), right (−π/2).
        sector = int(((bearing + math.pi / 4) % (2 * math.pi)) // (math.pi / 2))
        if sectors[sector] >= per_sector:
            continue
        if any(abs(y - cy) < TEMPLATE and min(abs(x - cx), W - abs(x - cx)) < TEMPLATE
               for cy, cx, _ in chosen):
            continue  # non-overlapping
        chosen.append((y, x, score))
        sectors[sector] += 1
    landmarks = []
    wrapped = add_wrap_margin(g1, TEMPLATE)
    for y, x, score in chosen:
        tpl = wrapped[y: y + TEMPLATE, x + TEMPLATE: x + 2 * TEMPLATE].copy()
        landmarks.append(Landmark(template=tpl, row=y, col=x, bearing=centre_bearing(x, W),
                                  score=score))
    return LandmarkSet(tuple(landmarks), W, margin)
