"""Find the mirror's donut in a raw image: centre and inner/outer radii (docs/design.md §2).

A starting point for ``[mirror]`` on a new camera, real or rendered, that says how well
each radius was measured and refuses rather than print a wrong circle:

1. **rough**: the bright region against the dark surround (Otsu threshold, largest blob);
   a circle fitted robustly to its outline where the outline is not the image border
   gives a first centre and radius (a mirror cut by the frame is not a smaller mirror);
2. **the mirror's extent**: in a polar resampling around it, the outermost radius at which
   the picture still varies along the azimuth. The mirror shows the world, a lit mount or
   housing round it is uniform: its bright ring is not the mirror (thesis §4.1's mirror
   is the reflecting surface only);
3. **rim points**: on each of 360 rays the outermost strong fall in brightness up to just
   beyond that extent. Rays whose fall is the image border are dropped (the rim is out of
   the frame there); rays where something dark touches the rim give points further in;
4. **circles** fitted to the rim points and to the inner edge (the end of the first
   stretch, walking out from the centre, at the uniform dark level of the camera's own
   reflection: a highlight inside it comes before, dark things in the mirror after) by
   RANSAC, then least squares over the inliers; steps 2-4 once more around the refined
   centre.

Refused (:class:`MirrorNotFoundError`, with the reason): no bright region, a rim seen on
less than ``MIN_RIM_ARC_DEG`` of its circle, a fit whose inliers scatter more than
``MAX_RMS_PX``. The inner radius is reported as not measured when its edge is not found
round at least half the circle.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from kernel.errors import PlacecellError

RAYS = 360
INLIER_PX = 1.5  # a point within this of the circle supports it
MIN_RIM_ARC_DEG = 120.0  # rim points on less of the circle: refused
MAX_RMS_PX = 2.0
MIN_INNER_FRACTION = 0.5
DISC_CORE = 0.15  # the camera's reflection's level is measured within this share of the rim
DARK_RUN = 0.05  # ...and the disc is the first stretch at that level this long (of the rim)
GAP_PX = 3.0  # departures from the level shorter than this do not end the stretch
BORDER_PX = 2.0  # rim points this near the image border are the border, not the rim
RAY_ANGLES = np.radians(np.arange(RAYS) * 360.0 / RAYS)  # of the polar resampling's rows


class MirrorNotFoundError(PlacecellError):
    """No donut could be found in the image."""


@dataclass(frozen=True)
class MirrorGeometry:
    center_x_px: float
    center_y_px: float
    r_inner_px: float | None  # None: the camera's reflection was not found
    r_outer_px: float
    outer_residual_px: float  # RMS distance from the circle of the rim points within 1.5 px
    inner_residual_px: float | None
    rim_rays: int  # of RAYS, the rays whose rim point fits the circle
    rim_arc_deg: float  # the part of the circle those rays cover
    clipped: bool  # the fitted rim runs outside the image
    inner_rays: int
    ring_outside: bool  # a lit ring round the mirror was found and is not the rim


def fit_circle(x: np.ndarray, y: np.ndarray, iterations: int = 3
               ) -> tuple[float, float, float, float]:
    """Least-squares circle (Kasa fit) with outlier rejection: (cx, cy, r, rms residual)."""
    keep = np.ones(len(x), bool)
    cx = cy = r = rms = float("nan")
    for _ in range(iterations):
        if keep.sum() < 3:
            raise MirrorNotFoundError("too few edge points to fit a circle")
        xs, ys = x[keep], y[keep]
        # x² + y² = 2 cx x + 2 cy y + (r² − cx² − cy²): linear in the unknowns.
        A = np.column_stack([2 * xs, 2 * ys, np.ones_like(xs)])
        b = xs**2 + ys**2
        (cx, cy, k), *_ = np.linalg.lstsq(A, b, rcond=None)
        r = float(np.sqrt(max(k + cx**2 + cy**2, 0.0)))
        resid = np.abs(np.hypot(x - cx, y - cy) - r)
        rms = float(np.sqrt(np.mean(resid[keep] ** 2)))
        mad = float(np.median(resid[keep])) + 1e-6
        keep = resid < max(3.0 * 1.4826 * mad, 0.75)
    return float(cx), float(cy), r, rms


def ransac_circle(x: np.ndarray, y: np.ndarray, trials: int = 300, tol: float = INLIER_PX,
                  seed: int = 0) -> np.ndarray:
    """The inliers (mask) of the circle through three of the points that most points lie
    within ``tol`` of: a third of the points off the circle cannot pull it."""
    n = len(x)
    if n < 3:
        raise MirrorNotFoundError("too few edge points to fit a circle")
    rng = np.random.default_rng(seed)
    picks = np.stack([rng.choice(n, 3, replace=False) for _ in range(trials)])
    best = np.zeros(n, bool)
    for i, j, k in picks:
        # The circumcentre of three points, by the perpendicular bisectors.
        ax, ay, bx, by, qx, qy = x[i], y[i], x[j], y[j], x[k], y[k]
        d = 2.0 * (ax * (by - qy) + bx * (qy - ay) + qx * (ay - by))
        if abs(d) < 1e-6:
            continue
        a2, b2, q2 = ax * ax + ay * ay, bx * bx + by * by, qx * qx + qy * qy
        ux = (a2 * (by - qy) + b2 * (qy - ay) + q2 * (ay - by)) / d
        uy = (a2 * (qx - bx) + b2 * (ax - qx) + q2 * (bx - ax)) / d
        r = np.hypot(ax - ux, ay - uy)
        inliers = np.abs(np.hypot(x - ux, y - uy) - r) < tol
        if inliers.sum() > best.sum():
            best = inliers
    return best


def _fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float, np.ndarray]:
    """RANSAC, then least squares over its inliers: (cx, cy, r, rms, inlier mask)."""
    inliers = ransac_circle(x, y)
    cx, cy, r, _ = fit_circle(x[inliers], y[inliers])
    resid = np.abs(np.hypot(x - cx, y - cy) - r)
    near = resid < INLIER_PX
    rms = float(np.sqrt(np.mean(resid[near] ** 2))) if near.any() else float("inf")
    return cx, cy, r, rms, near


def _on_border(x: np.ndarray, y: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    h, w = shape[:2]
    return (x < BORDER_PX) | (y < BORDER_PX) | (x > w - 1 - BORDER_PX) | (y > h - 1 - BORDER_PX)


def _rough(grey: np.ndarray) -> tuple[float, float, float]:
    thresh, _ = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    bright = (grey > max(10.0, 0.5 * thresh)).astype(np.uint8)
    mask = np.asarray(cv2.morphologyEx(bright, cv2.MORPH_CLOSE, np.ones((9, 9), np.uint8)))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise MirrorNotFoundError("the image has no bright region that could be a mirror")
    biggest = max(contours, key=cv2.contourArea)
    (cx, cy), r = cv2.minEnclosingCircle(biggest)
    if r < 10:
        raise MirrorNotFoundError(f"the brightest region is too small for a mirror ({r:.0f} px)")
    points = biggest[:, 0, :].astype(float)
    points = points[~_on_border(points[:, 0], points[:, 1], grey.shape)]
    if len(points) >= 20:  # the outline's circle, unless the outline is mostly the border
        inliers = ransac_circle(points[:, 0], points[:, 1], tol=3.0)
        if inliers.sum() >= 0.3 * len(points):
            fx, fy, fr, _ = fit_circle(points[inliers, 0], points[inliers, 1])
            if 10 <= fr <= 2 * max(grey.shape):
                return fx, fy, fr
    return float(cx), float(cy), float(r)


def _polar(grey: np.ndarray, cx: float, cy: float, r_max: float) -> tuple[np.ndarray, float]:
    n_r = int(np.ceil(r_max))
    # WARP_FILL_OUTLIERS: rays leaving the image read 0 (dark surround); without it
    # OpenCV leaves those pixels uninitialised, which made results vary run to run.
    polar = cv2.warpPolar(grey.astype(np.float32), (n_r, RAYS), (cx, cy), r_max,
                          cv2.INTER_LINEAR + cv2.WARP_POLAR_LINEAR + cv2.WARP_FILL_OUTLIERS)
    return polar, r_max / n_r


def _edges(grey: np.ndarray, cx: float, cy: float, r_rough: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """Rim radius and inner radius on each ray of RAY_ANGLES."""
    polar, scale = _polar(grey, cx, cy, 1.35 * r_rough)
    n_r = polar.shape[1]
    smooth = cv2.GaussianBlur(polar, (1, 5), 0)  # along the angle only
    grad = np.gradient(smooth, axis=1)
    lo = int(0.6 * r_rough / scale)
    hi = min(n_r - 1, int(1.2 * r_rough / scale))
    # Rim: walking in from outside, the first strong fall in brightness (mirror -> dark
    # surround): among the falls steeper than half the ray's steepest, the outermost.
    # Dark things seen in the mirror, further in, cannot be taken for it; a lit ring
    # round the mirror can, and is looked for after the fit (_inside_ring).
    band = grad[:, lo:hi]
    steep = band <= 0.5 * band.min(axis=1, keepdims=True)
    outermost = band.shape[1] - 1 - np.argmax(steep[:, ::-1], axis=1)
    outer = (lo + outermost) * scale
    # Inner edge: where the camera's own dark reflection ends. Walking out from the centre,
    # the first stretch of DARK_RUN of the rim's radius (or more) at its uniform level,
    # gaps shorter than GAP_PX bridged (noise): its end is the edge. A highlight inside
    # the dark disc (the lens's own reflection, a lamp seen in it) comes before that
    # stretch and is walked through; dark things seen in the mirror further out come
    # after it and cannot be taken for it. The level is the disc's, not the highlight's:
    # the commonest grey level near the centre, of the image's pixels (the polar image
    # would over-count the centre).
    h, w = grey.shape[:2]
    yy, xx = np.ogrid[:h, :w]
    core = grey[(xx - cx) ** 2 + (yy - cy) ** 2 <= (DISC_CORE * r_rough) ** 2].astype(float)
    if core.size == 0:
        core = smooth[:, :2].ravel()
    counts, bins = np.histogram(core, bins=32, range=(0.0, 256.0))
    peak = int(np.argmax(counts))
    level = float(np.median(core[(core >= bins[peak] - 8.0) & (core < bins[peak + 1] + 8.0)]))
    near = core[np.abs(core - level) < 30.0]
    spread = float(np.std(near)) if near.size else 0.0
    at_level = np.abs(smooth - level) <= max(12.0, 4.0 * spread)
    at_level[:, hi:] = False
    gap = max(1, int(round(GAP_PX / scale)))
    bridged = cv2.morphologyEx(at_level.astype(np.uint8), cv2.MORPH_CLOSE,
                               np.ones((1, 2 * gap + 1), np.uint8)) > 0
    bridged |= at_level
    run = np.zeros(bridged.shape, np.int32)  # samples at the level from here outwards
    run[:, -1] = bridged[:, -1]
    for k in range(bridged.shape[1] - 2, -1, -1):
        run[:, k] = np.where(bridged[:, k], run[:, k + 1] + 1, 0)
    disc = run >= max(2, int(DARK_RUN * r_rough / scale))
    start = np.argmax(disc, axis=1)
    found = disc[np.arange(len(start)), start]
    inner = np.where(found, start + run[np.arange(len(start)), start], hi) * scale
    return outer, inner


def _inside_ring(grey: np.ndarray, cx: float, cy: float, r: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Rim points (angles, x, y) when the circle found is the outer edge of a lit ring
    round the mirror: walking in from it, through the ring, a dark gap (the mount) comes
    before the mirror on most rays, and the gap's inner edge lies on a circle of its own
    about the same centre. None when there is no such ring."""
    polar, scale = _polar(grey, cx, cy, 1.1 * r)
    n_r = polar.shape[1]
    rim = int(r / scale)
    beyond = polar[:, min(n_r - 1, rim + 3):]
    dark = float(np.median(beyond)) if beyond.size else 0.0
    mirror = float(np.median(polar[:, int(0.6 * rim):int(0.9 * rim)]))
    threshold = dark + 0.3 * max(mirror - dark, 1.0)
    lo = int(0.7 * rim)
    grad = np.gradient(polar, axis=1)
    angles, radii = [], []
    for ray in range(RAYS):
        walk = polar[ray, lo:rim - 2][::-1] < threshold  # walking in: dark here?
        if not walk.any():
            continue
        start = int(np.argmax(walk))
        bright = ~walk[start:]
        if not bright.any():
            continue
        column = rim - 3 - (start + int(np.argmax(bright)))  # the mirror's last bright one
        near = slice(max(0, column - 2), column + 3)
        radii.append((near.start + int(np.argmin(grad[ray, near]))) * scale)
        angles.append(RAY_ANGLES[ray])
    if len(radii) < 3:
        return None
    a, rr = np.array(angles), np.array(radii)
    x, y = cx + rr * np.cos(a), cy + rr * np.sin(a)
    keep = ~_on_border(x, y, grey.shape)
    a, x, y = a[keep], x[keep], y[keep]
    if len(x) < 3:
        return None
    inliers = ransac_circle(x, y)
    ix, iy, ir, _ = fit_circle(x[inliers], y[inliers]) if inliers.sum() >= 3 else (
        cx, cy, r, 0.0)
    visible = int((~_on_border(cx + r * np.cos(RAY_ANGLES), cy + r * np.sin(RAY_ANGLES),
                               grey.shape)).sum())
    if inliers.sum() < 0.6 * visible or ir >= r - 2.0 or np.hypot(ix - cx, iy - cy) > 3.0:
        return None
    return a[inliers], x[inliers], y[inliers]


def detect_mirror(image: np.ndarray) -> MirrorGeometry:
    """Centre and radii of the mirror donut in a raw ``uint8`` image (grey or BGR)."""
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or min(image.shape[:2]) < 32:
        raise MirrorNotFoundError(f"expected a uint8 image of at least 32 x 32 px, got "
                                  f"{image.dtype} {image.shape}")
    raw_grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    grey = np.asarray(cv2.GaussianBlur(raw_grey, (5, 5), 0))
    cx, cy, r = _rough(grey)
    for _ in range(2):
        outer, inner = _edges(grey, cx, cy, r)
        x, y = cx + outer * np.cos(RAY_ANGLES), cy + outer * np.sin(RAY_ANGLES)
        usable = ~_on_border(x, y, grey.shape)  # a fall at the border is the frame's edge
        if usable.sum() < 3:
            raise MirrorNotFoundError("no rim point inside the image")
        ocx, ocy, r, out_rms, fits = _fit(x[usable], y[usable])
        rim = np.flatnonzero(usable)[fits]
        ix, iy = cx + inner * np.cos(RAY_ANGLES), cy + inner * np.sin(RAY_ANGLES)
        cx, cy = ocx, ocy
    rim_angles = RAY_ANGLES[rim]
    ring = _inside_ring(grey, cx, cy, r)
    if ring is not None:  # that was a lit ring round the mirror: the rim is inside it
        rim_angles, x, y = ring
        cx, cy, r, out_rms, fits = _fit(x, y)
        rim_angles = rim_angles[fits]
    arc = _covered_arc_deg(rim_angles)
    if arc < MIN_RIM_ARC_DEG:
        raise MirrorNotFoundError(
            f"the rim is seen on only {arc:.0f} deg of its circle (at least "
            f"{MIN_RIM_ARC_DEG:.0f} needed): too little of the mirror's edge is visible")
    if out_rms > MAX_RMS_PX:
        raise MirrorNotFoundError(f"the rim points scatter {out_rms:.1f} px RMS about the "
                                  f"best circle (at most {MAX_RMS_PX}): no clear rim")
    h, w = grey.shape[:2]
    clipped = bool(cx - r < 0 or cy - r < 0 or cx + r > w - 1 or cy + r > h - 1)
    r_in: float | None = None
    in_rms: float | None = None
    inner_rays = 0
    try:
        _, _, fr_in, fin_rms, inner_fits = _fit(ix, iy)
        inner_rays = int(inner_fits.sum())
        if inner_rays >= MIN_INNER_FRACTION * RAYS and fin_rms <= MAX_RMS_PX \
                and 0 < fr_in < r:
            r_in, in_rms = round(fr_in, 2), round(fin_rms, 3)
    except MirrorNotFoundError:
        pass
    return MirrorGeometry(round(cx, 2), round(cy, 2), r_in, round(r, 2), round(out_rms, 3),
                          in_rms, len(rim_angles), round(arc, 1), clipped, inner_rays,
                          ring is not None)


def _covered_arc_deg(angles: np.ndarray, bin_deg: float = 5.0) -> float:
    """How much of the circle the angles cover, in ``bin_deg`` sectors."""
    bins = np.unique(np.floor(np.degrees(angles) % 360.0 / bin_deg))
    return float(len(bins) * bin_deg)
