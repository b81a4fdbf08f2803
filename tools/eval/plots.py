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
    # Axes in metres from the place's reference (the cross), ticks on whole steps.
    step = _tick_step(max(rows, cols) * cell_m / 2)
    for axis, n in (("x", cols), ("y", rows)):
        half = n // 2
        for k in range(-half, n - half):
            offset = k * cell_m
            if abs(offset / step - round(offset / step)) > 1e-6:
                continue
            if axis == "x":
                at = (PAD + (k + half) * cell + cell // 2 - 10, PAD + rows * cell + 16)
            else:
                at = (PAD - 38, PAD + (rows - 1 - (k + half)) * cell + cell // 2 + 4)
            cv2.putText(img, f"{offset:g}", at, FONT, 0.4, INK, 1, cv2.LINE_AA)
    cv2.putText(img, "x (m) from the place", (SIZE // 2 - 70, PAD + rows * cell + 32), FONT,
                0.45, INK, 1, cv2.LINE_AA)
    cv2.putText(img, "y (m)", (8, PAD - 8), FONT, 0.45, INK, 1, cv2.LINE_AA)
    cv2.putText(img, f"LRP {lo:.2f} (dark) .. {hi:.2f} (yellow); white: recognised; "
                f"cell {cell_m:g} m", (PAD, SIZE - 5), FONT, 0.4, INK, 1, cv2.LINE_AA)
    _write(path, img)


PALETTE = ((180, 70, 20), (40, 160, 40), (30, 30, 200), (140, 60, 160), (0, 150, 200),
           (0, 0, 0), (120, 120, 0))


def paths(path: Path, tracks: dict[str, np.ndarray], *, title: str,
          points: dict[str, np.ndarray] | None = None) -> None:
    """Paths ``(K, 2)`` (x, y in metres) on equal axes, one colour each, with a legend;
    ``points``: sets of ``(K, 2)`` drawn as dots (e.g. particles at chosen frames)."""
    img = _canvas(title)
    every = [t for t in tracks.values() if len(t)] + [p for p in (points or {}).values()
                                                       if len(p)]
    allxy = np.concatenate(every) if every else np.zeros((1, 2))
    lo, hi = allxy.min(axis=0), allxy.max(axis=0)
    span = float(max(hi[0] - lo[0], hi[1] - lo[1], 0.1)) * 1.1
    centre = (lo + hi) / 2
    scale = (SIZE - 2 * PAD) / span

    def px(x: float, y: float) -> tuple[int, int]:
        return (int(SIZE / 2 + (x - centre[0]) * scale), int(SIZE / 2 - (y - centre[1]) * scale))

    for k, (name, t) in enumerate((points or {}).items()):
        colour = PALETTE[(k + len(tracks)) % len(PALETTE)]
        for x, y in t:
            cv2.circle(img, px(x, y), 1, colour, -1)
        cv2.putText(img, name, (PAD + 6, PAD + 16 * (k + len(tracks) + 1)), FONT, 0.4, colour,
                    1)
    for k, (name, t) in enumerate(tracks.items()):
        colour = PALETTE[k % len(PALETTE)]
        pts = np.array([px(x, y) for x, y in t], np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], False, colour, 1, cv2.LINE_AA)
        cv2.putText(img, name, (PAD + 6, PAD + 16 * (k + 1)), FONT, 0.4, colour, 1,
                    cv2.LINE_AA)
    step = _tick_step(span)
    x_lo, x_hi = centre[0] - SIZE / 2 / scale, centre[0] + SIZE / 2 / scale
    y_lo, y_hi = centre[1] - SIZE / 2 / scale, centre[1] + SIZE / 2 / scale
    for t in np.arange(np.ceil(x_lo / step) * step, x_hi, step):
        if PAD <= px(t, 0)[0] <= SIZE - PAD:
            cv2.putText(img, f"{t:g}", (px(t, 0)[0] - 8, SIZE - PAD + 18), FONT, 0.4, INK, 1)
            cv2.line(img, (px(t, 0)[0], SIZE - PAD), (px(t, 0)[0], SIZE - PAD + 5), INK, 1)
    for t in np.arange(np.ceil(y_lo / step) * step, y_hi, step):
        if PAD <= px(0, t)[1] <= SIZE - PAD:
            cv2.putText(img, f"{t:g}", (PAD - 40, px(0, t)[1] + 4), FONT, 0.4, INK, 1)
            cv2.line(img, (PAD - 5, px(0, t)[1]), (PAD, px(0, t)[1]), INK, 1)
    cv2.rectangle(img, (PAD, PAD), (SIZE - PAD, SIZE - PAD), INK, 1)
    cv2.putText(img, "x (m)", (SIZE // 2 - 20, SIZE - 15), FONT, 0.5, INK, 1, cv2.LINE_AA)
    cv2.putText(img, "y (m)", (8, PAD - 8), FONT, 0.5, INK, 1, cv2.LINE_AA)
    _write(path, img)


def series(path: Path, values: dict[str, np.ndarray], *, title: str, x_label: str,
           y_label: str) -> None:
    """Curves over their index (e.g. error per frame), 0 at the bottom."""
    img = _canvas(title)
    n = max((len(v) for v in values.values()), default=1)
    top = max((float(np.nanmax(v)) for v in values.values() if len(v)), default=1.0) * 1.1
    top = top if top > 0 else 1.0
    span = SIZE - 2 * PAD

    def px(i: float, v: float) -> tuple[int, int]:
        return int(PAD + i / max(n - 1, 1) * span), int(SIZE - PAD - v / top * span)

    step = _tick_step(top)
    for t in np.arange(0.0, top + 1e-12, step):
        cv2.line(img, px(0, t), px(n - 1, t), GRID, 1)
        cv2.putText(img, f"{t:g}", (8, px(0, t)[1] + 4), FONT, 0.4, INK, 1)
    cv2.rectangle(img, px(0, top), px(n - 1, 0), INK, 1)
    for k, (name, v) in enumerate(values.items()):
        colour = PALETTE[k % len(PALETTE)]
        pts = np.array([px(i, float(x)) for i, x in enumerate(v)], np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [pts], False, colour, 1, cv2.LINE_AA)
        cv2.putText(img, name, (PAD + 5, PAD + 16 * (k + 1)), FONT, 0.4, colour, 1)
    cv2.putText(img, x_label, (SIZE // 2 - 30, SIZE - 15), FONT, 0.5, INK, 1, cv2.LINE_AA)
    cv2.putText(img, y_label, (8, PAD - 8), FONT, 0.5, INK, 1, cv2.LINE_AA)
    _write(path, img)


def _tick_step(limit: float) -> float:
    for step in (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0):
        if limit / step <= 8:
            return step
    return limit / 8


def _write(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {path}")
