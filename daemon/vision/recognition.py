"""Recognising a landmark set in a panorama (docs/design.md §3, thesis §4.4).

LRP_p(i) = mean over the landmarks of place p of the best NCC of each template anywhere
in panorama i. ``lrp_bruteforce`` is the reference: ``cv2.matchTemplate`` (normalised) of
every template over the whole panorama. ``FastMatcher`` finds the same maxima coarse to
fine, with the work shared across every template of every place:

1. Coarse (once per frame): the panorama at half resolution (Gaussian pyramid level 1,
   cv2.pyrDown: smoothed before it is subsampled, so peaks survive); every 8 x 8
   window is a column of one matrix, its norm about its mean kept aside.
2. Coarse (per place): one matrix product of that matrix with the half-resolution
   templates (zero-mean, unit-norm) gives each template's NCC at every even position.
3. Candidates: the local maxima of that coarse map within ``CANDIDATE_MARGIN`` x (the
   template's share of detail finer than half resolution) of its best. The coarse NCC
   misses that detail and is off from the full one by up to ~0.3 either way, so every
   peak that could still be the best is kept, not just the top one.
4. Fine: from each candidate, a climb on the exact full-resolution NCC (as OpenCV's):
   the 3 x 3 positions around the current one, moving to the best until it is the centre.

The answer is exact wherever the best window's peak is reached from a candidate; when it
is not, that template's best NCC is underestimated (never over). ``placecell-bench``
measures speed and agreement with brute force on a path through a 50-place map (same best
place, largest LRP difference); raising ``CANDIDATE_MARGIN`` trades speed for agreement.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from daemon.vision.landmarks import TEMPLATE, LandmarkSet
from daemon.vision.ncc import FLAT_RMS, inverse_norms, ncc_map, window_norms
from kernel.panorama import add_wrap_margin, core_of


def best_ncc_bruteforce(panorama_grey: np.ndarray, templates: np.ndarray) -> np.ndarray:
    """(N,) best NCC of each (16, 16) template anywhere in the panorama."""
    return np.array([float(ncc_map(panorama_grey, t).max()) for t in templates])


def lrp_bruteforce(panorama_grey: np.ndarray, landmarks: LandmarkSet) -> float:
    """LRP (§4.4): mean of the best NCC of each template over the whole panorama."""
    return float(best_ncc_bruteforce(panorama_grey, landmarks.templates()).mean())


def best_ncc_elsewhere(panorama_grey: np.ndarray, margin: int, templates: np.ndarray,
                       cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(N,) best NCC of each template in the panorama (with wrap ``margin``) away from
    where it was found (core column ``cols``, top row ``rows``): every window overlapping
    that spot is left out, across the seam. How well the landmark's best look-alike
    matches; the landmark stands out by its own NCC minus this."""
    core = core_of(panorama_grey, margin)
    width = core.shape[1]
    wrapped = add_wrap_margin(core, TEMPLATE)  # every window start, the seam included
    out = np.empty(len(templates))
    for i, (template, col, row) in enumerate(zip(templates, cols, rows, strict=True)):
        scores = ncc_map(wrapped, template)
        starts = (np.arange(scores.shape[1]) - TEMPLATE) % width  # core column of each
        apart = np.abs(starts - col)
        overlaps_cols = np.minimum(apart, width - apart) < TEMPLATE
        overlaps_rows = np.abs(np.arange(scores.shape[0]) - row) < TEMPLATE
        scores[np.ix_(overlaps_rows, overlaps_cols)] = -1.0
        out[i] = float(scores.max())
    return out


COARSE = TEMPLATE // 2  # side of a template at half resolution


@dataclass
class PreparedPanorama:
    """A panorama prepared once per frame for matching many 16 x 16 templates."""

    image: np.ndarray  # (H, W) float32 grey
    window_norm: np.ndarray  # (H - 15, W - 15) sqrt(Σ I² − (Σ I)² / n) of every window
    coarse: np.ndarray  # (64, h * w) every 8 x 8 window of the half-resolution panorama
    coarse_inverse_norm: np.ndarray  # (h * w,) 1 / its norm about its mean (0 if flat)
    coarse_shape: tuple[int, int]  # (h, w): even full-resolution positions per axis

    @classmethod
    def of(cls, panorama_grey: np.ndarray) -> PreparedPanorama:
        image = panorama_grey.astype(np.float32)
        small = cv2.pyrDown(image)[: image.shape[0] // 2, : image.shape[1] // 2]
        h, w = small.shape[0] - COARSE + 1, small.shape[1] - COARSE + 1
        # Row (u, v) holds pixel (u, v) of every window: 64 contiguous slices, far faster
        # than reshaping a sliding-window view. Windows need not be zero-mean here: the
        # templates are (Σ T0 I = Σ T0 (I − Ī)).
        coarse = np.empty((COARSE * COARSE, h * w), np.float32)
        for u in range(COARSE):
            for v in range(COARSE):
                coarse[u * COARSE + v] = small[u:u + h, v:v + w].ravel()
        return cls(image, window_norms(image, TEMPLATE), coarse,
                   inverse_norms(window_norms(small, COARSE).ravel(), FLAT_RMS * COARSE),
                   (h, w))


@dataclass(frozen=True)
class PreparedTemplates:
    """Templates prepared once per place (not per frame)."""

    zero_mean: np.ndarray  # (N, 16, 16) float32
    norms: np.ndarray  # (N,) float32
    coarse: np.ndarray  # (N, 64) half resolution, zero-mean, unit-norm (0 if flat)
    detail: np.ndarray  # (N,) the share of each template's norm the coarse one misses

    @classmethod
    def of(cls, templates: np.ndarray) -> PreparedTemplates:
        t = templates.astype(np.float32)
        t = t - t.mean(axis=(1, 2), keepdims=True)
        norms = np.sqrt((t.astype(np.float64) ** 2).sum(axis=(1, 2))).astype(np.float32)
        small = np.stack([cv2.pyrDown(x) for x in t]).reshape(len(t), -1)
        small -= small.mean(axis=1, keepdims=True)
        small_norms = np.sqrt((small * small).sum(axis=1, keepdims=True))
        # The share of the template's norm the half-resolution one misses:
        # sqrt(1 − 4 ||small||² / ||T||²) (4 pixels per half-resolution pixel).
        detail = np.sqrt(np.clip(1.0 - 4.0 * small_norms[:, 0] ** 2
                                 / np.maximum(norms.astype(np.float64) ** 2, 1e-12), 0.0, 1.0))
        small *= np.where(small_norms > FLAT_RMS * COARSE, 1.0 / np.maximum(small_norms, 1e-9),
                          0.0).astype(np.float32)
        return cls(t, norms, np.ascontiguousarray(small, dtype=np.float32),
                   detail.astype(np.float32))

    @classmethod
    def joined(cls, parts: list[PreparedTemplates]) -> PreparedTemplates:
        """Many places' templates as one set."""
        return cls(*(np.concatenate([getattr(p, f) for p in parts])
                     for f in ("zero_mean", "norms", "coarse", "detail")))


class FastMatcher:
    """Best NCC of many templates in one panorama, coarse to fine (module docstring)."""

    # A coarse peak is refined when within this x the template's detail of its coarse best.
    CANDIDATE_MARGIN = 0.25
    _PEAK = np.ones((3, 3), np.uint8)

    def best_ncc(self, pano: PreparedPanorama, templates: PreparedTemplates) -> np.ndarray:
        n = len(templates.norms)
        h, w = pano.coarse_shape
        coarse = templates.coarse @ pano.coarse
        coarse *= pano.coarse_inverse_norm
        coarse = coarse.reshape(n, h, w)  # NCC at the even positions
        best = coarse.reshape(n, -1).max(axis=1)
        margin = self.CANDIDATE_MARGIN * templates.detail
        keep = coarse >= (best - margin)[:, None, None]
        for i in range(n):
            keep[i] &= coarse[i] >= cv2.dilate(coarse[i], self._PEAK)  # local maxima
        found = np.flatnonzero(keep)
        which, at = found // (h * w), found % (h * w)
        out = np.full(n, -2.0, np.float32)  # below any NCC: "no window looked at"
        floor = FLAT_RMS * TEMPLATE
        usable = templates.norms > floor  # a flat template matches nothing (NCC 0)
        chosen = usable[which]
        _refine(pano.image, pano.window_norm, templates.zero_mean, templates.norms,
                which[chosen].astype(np.int64), 2 * (at[chosen] // w).astype(np.int64),
                2 * (at[chosen] % w).astype(np.int64), floor,
                TEMPLATE, out)  # the side from Python, not a constant inside: see _block
        found_any = np.where(out < -1.5, 0.0, out).astype(np.float64)
        return np.clip(found_any, -1.0, 1.0)  # float32 rounding can pass 1 by 1e-7

    def lrp(self, pano: PreparedPanorama, templates: PreparedTemplates) -> float:
        return float(self.best_ncc(pano, templates).mean())

    def lrps(self, pano: PreparedPanorama, places: list[PreparedTemplates]) -> list[float]:
        """The LRP of each of many places: one coarse matrix product for all their
        templates (a global search scores dozens of places in one frame)."""
        if not places:
            return []
        best = self.best_ncc(pano, PreparedTemplates.joined(places))
        ends = np.cumsum([len(p.norms) for p in places])
        return [float(part.mean()) for part in np.split(best, ends[:-1])]


@numba.njit(cache=True, nogil=True, fastmath=True)
def _block(pixels: np.ndarray, width: int, window_norm: np.ndarray, weights: np.ndarray,
           norm: float, r0: int, c0: int, floor: float, side: int, acc: np.ndarray
           ) -> None:  # pragma: no cover (compiled)
    """Exact NCC = Σ (T − T̄) I / (||T − T̄|| · ||I − Ī||) at the 3 x 3 positions from
    (r0, c0) into ``acc`` (as OpenCV's; a window flatter than ``floor`` counts as 0).

    ``side`` (the template's, 16) comes in at run time on purpose: LLVM then vectorises
    the inner loop's three running sums; with a compile-time 16 it unrolls the loop into
    scalar code 2.5x slower."""
    for dr in range(3):
        s0, s1, s2 = np.float32(0.0), np.float32(0.0), np.float32(0.0)
        for u in range(side):  # the 3 positions of a row share one 18-pixel line
            start = (r0 + dr + u) * width + c0
            row = weights[u * side:(u + 1) * side]
            p0 = pixels[start:start + side]
            p1 = pixels[start + 1:start + 1 + side]
            p2 = pixels[start + 2:start + 2 + side]
            for v in range(side):
                s0 += row[v] * p0[v]
                s1 += row[v] * p1[v]
                s2 += row[v] * p2[v]
        for dc, s in enumerate((s0, s1, s2)):
            energy = window_norm[r0 + dr, c0 + dc]
            acc[dr, dc] = s / (energy * norm) if energy > floor else 0.0


@numba.njit(cache=True, nogil=True, fastmath=True)
def _refine(image: np.ndarray, window_norm: np.ndarray, templates: np.ndarray,
            norms: np.ndarray, which: np.ndarray, rows: np.ndarray, cols: np.ndarray,
            floor: float, side: int, out: np.ndarray) -> None:  # pragma: no cover (compiled)
    """From each coarse candidate k (template ``which[k]`` at the even position
    (rows[k], cols[k])), climb the exact NCC at full resolution: evaluate the 3 x 3
    positions around the current one and move to the best until it is the centre (a
    coarse peak can sit a half-resolution pixel off the full one). ``out`` keeps each
    template's best."""
    h, w = window_norm.shape
    width = image.shape[1]
    pixels = image.ravel()  # flat indexing: twice as fast as 2-D in numba
    weights = templates.reshape(templates.shape[0], TEMPLATE * TEMPLATE)
    acc = np.empty((3, 3), np.float32)
    for k in range(which.shape[0]):
        i = which[k]
        r, c = rows[k], cols[k]
        for _ in range(8):  # a few steps reach the local maximum
            r0, c0 = min(max(r - 1, 0), h - 3), min(max(c - 1, 0), w - 3)
            _block(pixels, width, window_norm, weights[i], norms[i], r0, c0, floor, side, acc)
            best = np.argmax(acc)
            br, bc = r0 + best // 3, c0 + best % 3
            out[i] = max(out[i], acc[best // 3, best % 3])
            if br == r and bc == c:
                break
            if (br == r0 + 1 or r0 in (0, h - 3)) and (bc == c0 + 1 or c0 in (0, w - 3)):
                break  # the centre of a block pushed against the border
            r, c = br, bc
