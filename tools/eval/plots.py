"""PNG figures for ``placecell-eval --plots DIR``, drawn with OpenCV (no plotting library
on the robot): a scatter with error bars, and a grid of values around a place."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

SIZE = 560  # canvas side, pixels
PAD = 60  # room for the axes' labels
INK = (40, 40, 40)
GRID = (215, 215, 215)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def _canvas(title: str) -> np.ndarray:
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    cv2.putText(img, title, (PAD, 30), FONT, 0.55, INK, 1, cv2.LINE_AA)
    return img


def scatter(path: Path, x: np.ndarray, y: np.ndarray, y_err: np.ndarray, *, title: str,
            x_label: str, y_label: str, limit: float) -> None:
    """Points (x, y) with vertical bars ±y_err on square axes 0..limit and the diagonal
    y = x (for estimate-against-truth plots)."""
    img = _canvas(title)
    span = SIZE - 2 * PAD

    def px(vx: float, vy: float) -> tuple[int, int]:
        vx, vy = min(max(vx, 0.0), limit), min(max(vy, 0.0), limit)
        return int(PAD + vx / limit * span), int(SIZE - PAD - vy / limit * span)

    step = _tick_step(limit)
    for t in np.arange(0.0, limit + 1e-9, step):
        cv2.line(img, px(t, 0), px(t, limit), GRID, 1)
        cv2.line(img, px(0, t), px(limit, t), GRID, 1)
        cv2.putText(img, f"{t:g}", (px(t, 0)[0] - 8, SIZE - PAD + 18), FONT, 0.4, INK, 1)
        cv2.putText(img, f"{t:g}", (PAD - 34, px(0, t)[1] + 4), FONT, 0.4, INK, 1)
    cv2.line(img, px(0, 0), px(limit, limit), (160, 160, 160), 1, cv2.LINE_AA)
    cv2.rectangle(img, px(0, limit), px(limit, 0), INK, 1)
    for vx, vy, e in zip(x, y, y_err, strict=True):
        if np.isfinite(e):
            cv2.line(img, px(vx, vy - e), px(vx, vy + e), (200, 150, 90), 1, cv2.LINE_AA)
        cv2.circle(img, px(vx, vy), 3, (180, 70, 20), -1, cv2.LINE_AA)
    cv2.putText(img, x_label, (SIZE // 2 - 60, SIZE - 15), FONT, 0.5, INK, 1, cv2.LINE_AA)
    cv2.putText(img, y_label, (8, PAD - 8), FONT, 0.5, INK, 1, cv2.LINE_AA)
    _write(path, img)


def grid(path: Path, values: np.ndarray, marked: np.ndarray, *, title: str, lo: float,
         hi: float, cell_m: float) -> None:
    """A grid of values around a place (rows = y from top to bottom as +y .. −y, columns =
    x), grey where NaN (no robot can stand there), outlined where ``marked``, the place's
    reference at the centre."""
    img = _canvas(title)
    rows, cols = values.shape
    cell = (SIZE - 2 * PAD) // max(rows, cols)
    scaled = np.clip((values - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    colours = cv2.applyColorMap((np.nan_to_num(scaled) * 255).astype(np.uint8),
                                cv2.COLORMAP_VIRIDIS)
    for i in range(rows):
        for j in range(cols):
            top_left = (PAD + j * cell, PAD + (rows - 1 - i) * cell)
            bottom_right = (top_left[0] + cell - 1, top_left[1] + cell - 1)
            colour = (200, 200, 200) if np.isnan(values[i, j]) else tuple(
                int(c) for c in colours[i, j])
            cv2.rectangle(img, top_left, bottom_right, colour, -1)
            if marked[i, j]:
                cv2.rectangle(img, top_left, bottom_right, (255, 255, 255), 2)
    centre = (PAD + (cols // 2) * cell + cell // 2, PAD + (rows - 1 - rows // 2) * cell + cell // 2)
    cv2.drawMarker(img, centre, (0, 0, 255), cv2.MARKER_CROSS, cell, 2)
    cv2.putText(img, f"LRP {lo:.2f} (dark) .. {hi:.2f} (yellow); white: recognised; "
                f"cell {cell_m:g} m", (PAD, SIZE - 20), FONT, 0.4, INK, 1, cv2.LINE_AA)
    _write(path, img)


def _tick_step(limit: float) -> float:
    for step in (0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0):
        if limit / step <= 8:
            return step
    return limit / 8


def _write(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {path}")
