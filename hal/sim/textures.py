"""Procedural wall, floor and decoration textures (deterministic from a seed).

Every texture is a ``uint8`` BGR image at ``PX_PER_M`` pixels per metre; row 0 is the top.
"""

from __future__ import annotations

import cv2
import numpy as np

PX_PER_M = 100

WALL_KINDS = ("plain", "noise", "stripes", "bricks")
DECORATION_KINDS = ("poster", "door", "window", "cabinet", "marker")
FLOOR_KINDS = ("fine", "carpet", "tiles")


def _bgr(colour: np.ndarray) -> tuple[int, int, int]:
    return int(colour[0]), int(colour[1]), int(colour[2])


def _rng(seed: int, *salt: int) -> np.random.Generator:
    return np.random.default_rng([seed, *salt])


def wall(kind: str, width_px: int, height_px: int, colour: tuple[int, int, int],
         seed: int) -> np.ndarray:
    """A wall surface of ``kind`` in base colour ``colour`` (BGR)."""
    rng = _rng(seed, 1)
    img = np.empty((height_px, width_px, 3), np.uint8)
    img[:] = colour
    if kind == "plain":
        grain = rng.normal(0.0, 3.0, (height_px, width_px, 1))
        return np.clip(img + grain, 0, 255).astype(np.uint8)
    if kind == "noise":
        small = rng.normal(0.0, 40.0, (max(1, height_px // 8), max(1, width_px // 8), 1))
        big = cv2.resize(small, (width_px, height_px), interpolation=cv2.INTER_CUBIC)
        return np.clip(img + big[..., None], 0, 255).astype(np.uint8)
    if kind == "stripes":
        period = int(rng.integers(12, 40))
        cols = (np.arange(width_px) // period) % 2
        dark = np.array(colour, float) * 0.55
        img[:, cols == 1] = dark.astype(np.uint8)
        return img
    if kind == "bricks":
        bh, bw = 8, 25  # 8 cm x 25 cm bricks
        img[:] = (150, 160, 170)  # mortar
        for r0 in range(0, height_px, bh):
            shift = (r0 // bh) % 2 * (bw // 2)
            for c0 in range(-shift, width_px, bw):
                tone = np.array(colour, float) * rng.uniform(0.75, 1.15)
                img[r0 + 1:r0 + bh, max(0, c0 + 1):max(0, c0 + bw)] = np.clip(tone, 0, 255)
        return img
    raise ValueError(f"unknown wall texture {kind!r} (known: {', '.join(WALL_KINDS)})")


def decoration(kind: str, width_px: int, height_px: int, seed: int) -> np.ndarray:
    """A decoration painted onto a wall: poster, door, window, filing cabinet, marker."""
    rng = _rng(seed, 2)
    w, h = max(width_px, 2), max(height_px, 2)
    if kind == "poster":
        img = np.full((h, w, 3), rng.integers(180, 255, 3), np.uint8)
        for _ in range(int(rng.integers(4, 9))):  # coloured blocks and discs
            colour = tuple(int(c) for c in rng.integers(0, 255, 3))
            x0, y0 = int(rng.integers(0, w)), int(rng.integers(0, h))
            if rng.random() < 0.5:
                x1, y1 = int(rng.integers(x0, w + 1)), int(rng.integers(y0, h + 1))
                cv2.rectangle(img, (x0, y0), (x1, y1), colour, -1)
            else:
                cv2.circle(img, (x0, y0), int(rng.integers(3, max(4, min(w, h) // 3))), colour, -1)
        cv2.rectangle(img, (0, 0), (w - 1, h - 1), (30, 30, 30), 2)
        return img
    if kind == "door":
        wood = np.array(rng.integers(40, 120, 3), float)
        img = np.full((h, w, 3), wood, np.uint8)
        cv2.rectangle(img, (0, 0), (w - 1, h - 1), (60, 60, 60), 4)
        cv2.rectangle(img, (w // 6, h // 10), (5 * w // 6, 4 * h // 10), _bgr(wood * 0.7), 2)
        cv2.rectangle(img, (w // 6, 5 * h // 10), (5 * w // 6, 9 * h // 10), _bgr(wood * 0.7), 2)
        cv2.circle(img, (int(w * 0.85), h // 2), max(2, w // 25), (200, 210, 220), -1)
        return img
    if kind == "window":
        img = np.full((h, w, 3), (235, 215, 190), np.uint8)  # bright sky
        img += rng.integers(0, 15, (h, w, 1), dtype=np.uint8)
        cv2.rectangle(img, (0, 0), (w - 1, h - 1), (90, 90, 90), 5)
        cv2.line(img, (w // 2, 0), (w // 2, h), (90, 90, 90), 4)
        cv2.line(img, (0, h // 2), (w, h // 2), (90, 90, 90), 4)
        return img
    if kind == "cabinet":
        metal = np.array(rng.integers(90, 200, 3), float)
        img = np.full((h, w, 3), metal, np.uint8)
        drawers = int(rng.integers(3, 5))
        for i in range(drawers):
            y0, y1 = i * h // drawers, (i + 1) * h // drawers
            cv2.rectangle(img, (2, y0 + 2), (w - 3, y1 - 2), _bgr(metal * 0.6), 2)
            cv2.rectangle(img, (w // 2 - w // 8, y0 + (y1 - y0) // 4),
                          (w // 2 + w // 8, y0 + (y1 - y0) // 4 + 4), (40, 40, 40), -1)
        return img
    if kind == "marker":  # flat high-contrast artificial landmark (thesis §4.6.4)
        img = np.full((h, w, 3), 255, np.uint8)
        cells = int(rng.integers(2, 4))
        pattern = rng.integers(0, 2, (cells, cells)) * 255
        pattern[0, 0], pattern[-1, -1] = 0, 0
        img[:] = cv2.resize(pattern.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST
                            )[..., None]
        return img
    raise ValueError(f"unknown decoration {kind!r} (known: {', '.join(DECORATION_KINDS)})")


def floor(kind: str, colour: tuple[int, int, int], seed: int) -> np.ndarray:
    """A tileable floor texture of ``kind`` around ``colour`` (BGR), 2.56 m (``fine``) or
    3 m square:

    - ``fine``: a fine grain (σ 6 grey levels), nearly one flat colour;
    - ``carpet``: a patterned carpet — a woven diamond motif 0.15 m across, blotches of
      wear 0.1-0.3 m across and the grain;
    - ``tiles``: 0.3 m square tiles of slightly differing tone with 1 cm dark grout.
    """
    rng = _rng(seed, 3)
    size_px = 256 if kind == "fine" else 300
    base = np.array(colour, float)
    fine = rng.normal(0.0, 6.0, (size_px, size_px, 1))
    if kind == "fine":
        return np.clip(base + fine, 0, 255).astype(np.uint8)
    if kind == "carpet":
        period = size_px // 20  # 15 cm at 100 px/m: the motif repeats across the tile
        u = np.arange(size_px) % period / period - 0.5
        diamond = (np.abs(u)[:, None] + np.abs(u)[None, :] < 0.3).astype(float)
        small = rng.normal(0.0, 1.0, (size_px // 15, size_px // 15))
        blotch = cv2.resize(np.vstack([np.hstack([small, small])] * 2),
                            (2 * size_px, 2 * size_px), interpolation=cv2.INTER_CUBIC)
        blotch = blotch[size_px // 2:size_px // 2 + size_px, size_px // 2:size_px // 2 + size_px]
        tone = 1.0 + 0.12 * blotch[..., None] - 0.22 * diamond[..., None]
        return np.clip(base * tone + fine, 0, 255).astype(np.uint8)
    if kind == "tiles":
        tile = size_px // 10  # 0.3 m at 100 px/m
        tones = rng.uniform(0.9, 1.1, (size_px // tile, size_px // tile))
        img = base * np.kron(tones, np.ones((tile, tile)))[..., None] + 0.5 * fine
        grout = (np.arange(size_px) % tile) == 0
        img[grout, :] = base * 0.45
        img[:, grout] = base * 0.45
        return np.clip(img, 0, 255).astype(np.uint8)
    raise ValueError(f"unknown floor texture {kind!r} (known: {', '.join(FLOOR_KINDS)})")
