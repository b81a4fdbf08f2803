"""One `map` frame for the topological map (design §6): every place's reference pose in the
frame of the map's first place, by least squares over the transitions — a 2-D pose graph.

The thesis keeps only the graph (§7.1); robot software (ROS 2, Foxglove) wants one frame.
Each transition T_a_b, measured with covariance Σ, is one residual

    e_ab = log( T_a_b⁻¹ ∘ (X_a⁻¹ ∘ X_b) ),   whitened by L with Lᵀ L = Σ⁻¹,

X_a the place poses in the map frame, X_first fixed at the origin; the sum of ‖L e‖² is
minimised by Levenberg–Marquardt with the analytic Jacobian on the sparse normal
equations (each residual touches two places; residuals and Jacobian computed for all
edges at once; `placecell-bench --only embedding` times a thousand places). Our own
twenty lines rather than scipy.optimize's least_squares: importing that took 18 MB of the
daemon's memory (design §13), scipy.sparse's solver alone 10. A map that is a chain (no
cycle) comes out as the composition of its transitions; a closed cycle spreads its error
over the loop by the transitions' covariances. Places that no transition joins to the
first one are left out.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np
from scipy.sparse import csr_matrix, diags
from scipy.sparse.linalg import spsolve

from daemon.mapping.graph import TopologicalMap
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
    index = {p: i for i, p in enumerate(free)}  # the anchor is row len(free)
    a = np.array([index.get(t.from_id, len(free)) for t in edges])
    b = np.array([index.get(t.to_id, len(free)) for t in edges])
    z = np.array([t.T_from_to.mean.as_tuple() for t in edges])
    roots = np.array([np.linalg.cholesky(np.linalg.inv(t.T_from_to.covariance)).T
                      for t in edges])
    # R(-θz) tz: the measured translation seen from its own end, once for all.
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    z_back = np.stack([cz * z[:, 0] + sz * z[:, 1], -sz * z[:, 0] + cz * z[:, 1]], axis=1)

    def poses(x: np.ndarray) -> np.ndarray:
        return np.vstack([x.reshape(-1, 3), np.zeros((1, 3))])

    def unwhitened(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """e = T_a_b⁻¹ ∘ (X_a⁻¹ ∘ X_b) per edge: e_xy = R(−φ)(p_b − p_a) − R(−θz) t_z with
        φ = θz + θa, e_θ = θb − θa − θz (wrapped); also d = p_b − p_a and φ."""
        P = poses(x)
        d = P[b, :2] - P[a, :2]
        phi = z[:, 2] + P[a, 2]
        c, s = np.cos(phi), np.sin(phi)
        e = np.stack([c * d[:, 0] + s * d[:, 1] - z_back[:, 0],
                      -s * d[:, 0] + c * d[:, 1] - z_back[:, 1],
                      wrap_angle(P[b, 2] - P[a, 2] - z[:, 2])], axis=1)
        return e, d, phi

    def residuals(x: np.ndarray) -> np.ndarray:
        e, _, _ = unwhitened(x)
        return np.einsum("kij,kj->ki", roots, e).ravel()

    def jacobian(x: np.ndarray) -> csr_matrix:
        _, d, phi = unwhitened(x)
        c, s = np.cos(phi), np.sin(phi)
        n = len(edges)
        d_b = np.zeros((n, 3, 3))  # ∂e/∂X_b: R(−φ) on the translation, 1 on the heading
        d_b[:, 0, 0], d_b[:, 0, 1], d_b[:, 1, 0], d_b[:, 1, 1] = c, s, -s, c
        d_b[:, 2, 2] = 1.0
        d_a = -d_b  # ∂e/∂X_a: the opposite, plus ∂R(−φ)/∂θa (p_b − p_a)
        d_a[:, 0, 2] = -s * d[:, 0] + c * d[:, 1]
        d_a[:, 1, 2] = -c * d[:, 0] - s * d[:, 1]
        rows, cols, values = [], [], []
        for place, block in ((a, roots @ d_a), (b, roots @ d_b)):
            free_end = place < len(free)
            k = np.nonzero(free_end)[0]
            r = 3 * k[:, None, None] + np.arange(3)[None, :, None]
            q = 3 * place[k][:, None, None] + np.arange(3)[None, None, :]
            rows.append(np.broadcast_to(r, (len(k), 3, 3)).ravel())
            cols.append(np.broadcast_to(q, (len(k), 3, 3)).ravel())
            values.append(block[k].ravel())
        return csr_matrix((np.concatenate(values), (np.concatenate(rows),
                                                    np.concatenate(cols))),
                          shape=(3 * n, 3 * len(free)))

    x0 = np.concatenate([np.array(initial[p].as_tuple()) for p in free])
    P = poses(_levenberg_marquardt(residuals, jacobian, x0))
    return {anchor: SE2(0.0, 0.0, 0.0)} | {
        p: SE2(float(P[i, 0]), float(P[i, 1]), float(wrap_angle(P[i, 2])))
        for i, p in enumerate(free)}


TOLERANCE = 1e-10  # relative: the cost's last decrease, the step against the poses
MAX_ITERATIONS = 50


def _levenberg_marquardt(residuals: Callable[[np.ndarray], np.ndarray],
                         jacobian: Callable[[np.ndarray], csr_matrix],
                         x: np.ndarray) -> np.ndarray:
    """The x that minimises ‖r(x)‖² from ``x``: each step solves
    (JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr, taken when it lowers the cost (λ then shrinks tenfold),
    else λ grows tenfold; stops when the cost or the poses change by less than
    TOLERANCE of themselves."""
    r = residuals(x)
    cost = float(r @ r)
    damping = 1e-4
    for _ in range(MAX_ITERATIONS):
        J = jacobian(x)
        normal = (J.T @ J).tocsc()
        gradient = J.T @ r
        scale = diags(np.maximum(normal.diagonal(), 1e-12))
        while damping < 1e12:
            step = spsolve((normal + damping * scale).tocsc(), -gradient)
            r_new = residuals(x + step)
            cost_new = float(r_new @ r_new)
            if cost_new < cost:
                break
            damping *= 10.0
        else:
            return x  # no step lowers the cost: at the minimum to float precision
        x, r, decrease, cost = x + step, r_new, cost - cost_new, cost_new
        damping = max(damping / 10.0, 1e-12)
        if decrease <= TOLERANCE * cost or \
                np.linalg.norm(step) <= TOLERANCE * (np.linalg.norm(x) + TOLERANCE):
            break
    return x


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
