"""Disambiguating features (docs/design.md §5, thesis chapter 6 and §9.5): the patch of one place's
view that a look-alike place lacks, and the decision between the two by it.

For a pair of places A and B that the lower levels cannot tell apart, A's feature is the
template of A's view — position and size from :data:`SIZES` — whose best NCC anywhere in
B's view is lowest (§6.1). The thesis scored one image and found the feature unreliable
when the robot stood a little off the reference; here a candidate is also matched in A's
other views (taken half-way out along the arms of the Turn Back and Look cross) near
where it was cut, and the score is its worst match there minus its best
match in B:

    score(t) = min_v∈A′ max_near NCC(v, t) − max_v∈B max_anywhere NCC(v, t)

Deciding for a current view (§9.5): both features are searched for in the whole view
(the robot may be turned); the place whose feature correlates higher wins — each
correlation first set against what its feature scores in either place (:func:`decide`).

Views are grey panoramas with their wrap margin; columns and rows are of the core.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from daemon.vision.ncc import PreparedImage, ncc_map, window_norms
from kernel.panorama import core_of

SIZES = (16, 24, 32)  # square template sides, pixels
GRID_STEP = 8  # candidates are cut every GRID_STEP columns and rows
CANDIDATES_PER_SIZE = 120  # the most textured candidates of each size are scored
MIN_STD = 8.0  # grey levels: flatter patches match anything (or nothing) by chance
NEAR_COLS, NEAR_ROWS = 48, 12  # how far a feature may move in its own place's other views
# (24° and 7°: a patch 1 m away seen from 0.25 m off the reference)


@dataclass(frozen=True)
class Feature:
    """A patch of one place's view that the other place of a pair lacks."""

    col: int  # core column of its left edge in the reference view
    row: int  # row of its top edge
    template: np.ndarray  # (size, size) uint8
    own_ncc: float  # its worst match in its own place's other views (1 with none)
    other_ncc: float  # its best match anywhere in the other place's views

    @property
    def size(self) -> int:
        return int(self.template.shape[0])

    @property
    def score(self) -> float:
        return self.own_ncc - self.other_ncc


@dataclass(frozen=True)
class PairFeatures:
    """The features of two look-alike places: ``a`` cut from A's view against B, ``b``
    from B's against A."""

    a_id: int
    b_id: int
    a: Feature
    b: Feature

    def __post_init__(self) -> None:
        if self.a_id == self.b_id:
            raise ValueError(f"a pair of places, not place {self.a_id} twice")


@dataclass(frozen=True)
class Decision:
    """Which of a pair the current view is, and the evidence: each feature's best NCC
    in it and the weighed vote (> 0 for A)."""

    winner: Literal["a", "b"]
    ncc_a: float
    ncc_b: float
    vote: float


def find_feature(own: list[np.ndarray], other: Sequence[np.ndarray | PreparedImage],
                 margin: int) -> Feature:
    """The feature of the place whose views are ``own`` (the reference first, then any
    others of the same place) against the place whose views are ``other`` (grey, or
    already prepared when the caller matches them against several places)."""
    if not own or not other:
        raise ValueError("a feature needs at least one view of each place")
    reference = core_of(own[0], margin)
    others = prepared(other)  # each matched by hundreds of candidates
    best: Feature | None = None
    # The largest patches first: they win most pairs (32 px on 16 of 27 pairs of the
    # bench's map, 16 px on none), and the sooner the best score is high the more
    # candidates the bound below puts out (13 % less time, the same features).
    for size in sorted(SIZES, reverse=True):
        for col, row in _textured_candidates(reference, size):
            template = np.ascontiguousarray(reference[row:row + size, col:col + size])
            # Out as soon as it cannot beat the best: an other_ncc of at least
            # own_ncc - best.score. Exact: what is dropped would not have been chosen.
            # A match found near each of the other place's views' coarse peak is one
            # the patch has there, so at least that good anywhere: most candidates are
            # out on that alone, before their own views are searched — own_ncc is at
            # most 1, and only falls as each own view is searched (the wrap margin lets
            # a match straddle the seam).
            peaks = _Peaks(others, template)
            if best is not None and peaks.reach(1.0 - best.score):
                continue
            own_ncc, out = 1.0, False
            for view in own[1:]:
                own_ncc = min(own_ncc, _near(view, margin, template, col, row))
                if best is not None and peaks.known >= own_ncc - best.score:
                    out = True
                    break
            out_at = math.inf if best is None else own_ncc - best.score
            if out or (best is not None and peaks.reach(out_at)):
                continue
            other_ncc = -1.0
            for v in others:
                other_ncc = max(other_ncc, v.best_ncc(template))
                if other_ncc >= out_at:
                    break
            if other_ncc >= out_at:
                continue
            candidate = Feature(col, row, template, own_ncc, other_ncc)
            if best is None or candidate.score > best.score:
                best = candidate
    if best is None:
        raise ValueError("the view has no textured patch to tell it by")
    return best


def prepared(views: Sequence[np.ndarray | PreparedImage]) -> list[PreparedImage]:
    """Grey views prepared for many best-NCC searches (those already prepared as they
    are)."""
    return [v if isinstance(v, PreparedImage) else PreparedImage(v) for v in views]


def decide(view: np.ndarray, feature_a: Feature, feature_b: Feature) -> Decision:
    """A's feature against B's in the current grey ``view`` (with its wrap margin),
    each searched for anywhere in it.

    The thesis lets the higher correlation win. That fails when one place has all the
    other has and more (a sign beside one of two identical doors): the plainer place's
    best feature matches well in both. So each correlation is first placed between what
    its feature scores in the other place (0) and in its own (1), and the two votes are
    weighed by each feature's score (how far apart those two are):

        e = clip((c − c_other) / (c_own − c_other), 0, 1),  d = w_a (e_a − ½) − w_b (e_b − ½)

    A wins when d ≥ 0; with equally good features this is the thesis's rule."""
    a = best_ncc(view, feature_a)
    b = best_ncc(view, feature_b)
    d = vote(a, feature_a) - vote(b, feature_b)
    return Decision("a" if d >= 0.0 else "b", a, b, d)


def choose(view: np.ndarray, features: dict[tuple[int, int], Feature]
           ) -> tuple[int, dict[int, float], dict[tuple[int, int], float]]:
    """Among several look-alikes: ``features[(x, y)]`` is x's feature against y. Each
    place scores the mean vote of its own features in ``view`` (a place whose features
    are missing here scores below one whose features say nothing, which scores below
    one whose features are seen); the highest wins. For two places this is
    :func:`decide`. Returns the winner, every place's score and each feature's best
    NCC in the view (the evidence)."""
    nccs = {pair: best_ncc(view, feature) for pair, feature in features.items()}
    votes: dict[int, list[float]] = {}
    for (x, y), feature in features.items():
        votes.setdefault(x, []).append(vote(nccs[(x, y)], feature))
    scores = {x: float(np.mean(v)) for x, v in votes.items()}
    return max(scores, key=lambda x: scores[x]), scores, nccs


def can_decide(pair: PairFeatures, min_evidence: float) -> bool:
    """Whether the pair's features can ever part its two places by ``min_evidence``: a
    place's score in :func:`choose` is a mean of votes within ±span/2 of its features,
    so two places part by at most (span_a + span_b)/2. Features that score about 0
    (seen as well in the other place as in their own: aliased-corridor seed 2's first
    and last places, 0.02 each) can only keep a decision waiting for a clear view that
    never comes; meanwhile the lower levels' pick, which a tracker would already be
    holding, goes unused."""
    return (max(pair.a.score, 0.0) + max(pair.b.score, 0.0)) / 2.0 >= min_evidence


def best_ncc(view: np.ndarray, feature: Feature) -> float:
    """The feature's best NCC anywhere in the grey ``view`` (with its wrap margin)."""
    return float(ncc_map(view, feature.template).max())


def vote(ncc: float, feature: Feature) -> float:
    """The feature's vote for its place when it matches ``ncc`` (see :func:`decide`)."""
    span = feature.own_ncc - feature.other_ncc
    if span <= 1e-6:
        return 0.0  # the other place has it too: no evidence either way
    e = min(max((ncc - feature.other_ncc) / span, 0.0), 1.0)
    return span * (e - 0.5)


class _Peaks:
    """A candidate's NCC near the coarse peak in each of the other place's views
    (:meth:`PreparedImage.ncc_near_coarse_peak`), each measured when first needed."""

    def __init__(self, views: list[PreparedImage], template: np.ndarray) -> None:
        self._views, self._template = views, template
        self._done = 0
        self.known = -1.0  # the highest measured so far

    def reach(self, level: float) -> bool:
        """Whether any view's peak reaches ``level``, measuring views until one does."""
        if self.known >= level:
            return True
        while self._done < len(self._views):
            self.known = max(self.known,
                             self._views[self._done].ncc_near_coarse_peak(self._template))
            self._done += 1
            if self.known >= level:
                return True
        return False


def _textured_candidates(core: np.ndarray, size: int) -> list[tuple[int, int]]:
    """Grid positions of the ``CANDIDATES_PER_SIZE`` most textured size x size patches."""
    h, w = core.shape
    spots = [(c, r) for r in range(0, h - size + 1, GRID_STEP)
             for c in range(0, w - size + 1, GRID_STEP)]
    if not spots:
        return []
    norms = window_norms(core, size)  # sqrt(Σ I² − (Σ I)² / n): the std times the side
    stds = np.array([norms[r, c] for c, r in spots], dtype=np.float64) / size
    order = np.argsort(-stds, kind="stable")
    return [spots[i] for i in order[:CANDIDATES_PER_SIZE] if stds[i] >= MIN_STD]


def _near(view: np.ndarray, margin: int, template: np.ndarray, col: int, row: int) -> float:
    """Best NCC of ``template`` within NEAR_COLS / NEAR_ROWS of (col, row) in ``view``."""
    size = template.shape[0]
    h = view.shape[0]
    r0 = max(0, row - NEAR_ROWS)
    r1 = min(h, row + size + NEAR_ROWS)
    core_w = view.shape[1] - 2 * margin
    idx = np.arange(col - NEAR_COLS, col + size + NEAR_COLS) % core_w + margin
    window = np.take(view[r0:r1], idx, axis=1)
    scores = ncc_map(window, template)
    return float(scores.max()) if scores.size else -1.0

