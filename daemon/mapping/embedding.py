"""One `map` frame for the topological map (design §6): every place's reference pose in the
frame of the map's first place, by least squares over the transitions — a 2-D pose graph.

The thesis keeps only the graph (§7.1); robot software (ROS 2, Foxglove) wants one frame.
Each transition T_a_b, measured with covariance Σ, is one residual

    e_ab = log( T_a_b⁻¹ ∘ (X_a⁻¹ ∘ X_b) ),   whitened by L with Lᵀ L = Σ⁻¹,

X_a the place poses in the map frame, X_first fixed at the origin; the sum of ‖L e‖² is
minimised (scipy's trust-region least squares, the Jacobian's sparsity given: each
residual touches two places). A map that is a chain (no cycle) comes out as the
composition of its transitions; a closed cycle spreads its error over the loop by the
transitions' covariances. Places that no transition joins to the first one are left out.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from daemon.mapping.graph import TopologicalMap
from daemon.mapping.transition import Transition
from kernel.angles import wrap_angle
from kernel.se2 import SE2


def embed(graph: TopologicalMap) -> dict[int, SE2]:
    """Each place's reference pose in the `map` frame (the lowest id's frame), for the
    places joined to it by transitions."""
    if not len(graph):
        return {}
    anchor = min(p.id for p in graph.places)
    initial = _dead_reckoning(graph, anchor)
    edges = [t for t in graph.transitions if t.from_id < t.to_id
             and t.from_id in initial and t.to_id in initial]
    free = sorted(p for p in initial if p != anchor)
    if not free or len(edges) < len(free) + 1:  # a tree: nothing to spread
        return initial
    column = {p: 3 * i for i, p in enumerate(free)}
    roots = [np.linalg.cholesky(np.linalg.inv(t.T_from_to.covariance)).T for t in edges]
    measured = [t.T_from_to.mean for t in edges]

    def pose(x: np.ndarray, place: int) -> SE2:
        if place == anchor:
            return SE2(0.0, 0.0, 0.0)
        c = column[place]
        return SE2(float(x[c]), float(x[c + 1]), float(x[c + 2]))

    def residuals(x: np.ndarray) -> np.ndarray:
        out = np.empty(3 * len(edges))
        for k, (t, z, root) in enumerate(zip(edges, measured, roots, strict=True)):
            e = z.between(pose(x, t.from_id).between(pose(x, t.to_id)))
            out[3 * k: 3 * k + 3] = root @ np.array([e.x, e.y, float(wrap_angle(e.yaw))])
        return out

    x0 = np.concatenate([np.array(initial[p].as_tuple()) for p in free])
    solved = least_squares(residuals, x0, jac_sparsity=_sparsity(edges, column),
                           x_scale="jac", method="trf")
    return {anchor: SE2(0.0, 0.0, 0.0)} | {p: pose(solved.x, p) for p in free}


def _dead_reckoning(graph: TopologicalMap, anchor: int) -> dict[int, SE2]:
    """The poses composed along a breadth-first tree of transitions from ``anchor``."""
    poses = {anchor: SE2(0.0, 0.0, 0.0)}
    queue = deque([anchor])
    while queue:
        here = queue.popleft()
        for t in sorted(graph.neighbours(here), key=lambda t: t.to_id):
            if t.to_id not in poses:
                poses[t.to_id] = poses[here].compose(t.T_from_to.mean)
                queue.append(t.to_id)
    return poses


def _sparsity(edges: list[Transition], column: dict[int, int]) -> lil_matrix:
    pattern = lil_matrix((3 * len(edges), 3 * len(column)), dtype=int)
    for k, t in enumerate(edges):
        for place in (t.from_id, t.to_id):
            if place in column:
                pattern[3 * k: 3 * k + 3, column[place]: column[place] + 3] = 1
    return pattern
