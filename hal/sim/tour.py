"""A tour of a world: a collision-free route through every room (design §10).

Planned on the world's free space, rasterised at ``RESOLUTION``: walls and obstacles are
drawn, the outside of the outer walls is not free, and the distance to the nearest wall
(``cv2.distanceTransform``) gives each cell's clearance. Rooms are the connected parts of
the space with a large clearance (``ROOM_CLEARANCE``; doorways are too narrow to join
them); the tour visits the most open point of each room and enough further points to come
within ``COVER`` of all of it, nearest first from the start, along shortest paths that
keep at least ``clearance`` from every wall and obstacle (Dijkstra on the grid, which
prefers cells with more room), and comes back to the start.
Deterministic per world.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from hal.sim.world import World

RESOLUTION = 0.05  # m per cell
ROOM_CLEARANCE = 0.9  # m: more than half of a 1 m doorway, less than half a corridor
WAYPOINT_SPACING = 0.5  # m between the tour's waypoints along a path
COVER = 3.0  # m: every open cell of a room is this close to a goal of the tour


class TourError(ValueError):
    pass


class _Grid:
    def __init__(self, world: World) -> None:
        x0, y0, x1, y1 = world.bounds()
        self.x0, self.y0 = x0 - 0.5, y0 - 0.5
        self.nx = int(math.ceil((x1 - x0 + 1.0) / RESOLUTION))
        self.ny = int(math.ceil((y1 - y0 + 1.0) / RESOLUTION))
        walls = np.zeros((self.ny, self.nx), np.uint8)
        for wall in world.walls:
            pts = np.array([self.cell(x, y) for x, y in wall.points], np.int32)
            if wall.closed:
                cv2.fillPoly(walls, [pts], 255)
            cv2.polylines(walls, [pts], wall.closed, 255, thickness=2)
        # Free space is what the robot's start can reach without crossing a wall.
        reach = (walls == 0).astype(np.uint8)
        sx, sy = self.cell(*world.start_pose[:2])
        mask = np.zeros((self.ny + 2, self.nx + 2), np.uint8)
        cv2.floodFill(reach, mask, (sx, sy), 2)
        free = (reach == 2).astype(np.uint8)
        self.clearance = cv2.distanceTransform(free, cv2.DIST_L2, 5) * RESOLUTION

    def cell(self, x: float, y: float) -> tuple[int, int]:
        return int(round((x - self.x0) / RESOLUTION)), int(round((y - self.y0) / RESOLUTION))

    def point(self, cx: int, cy: int) -> tuple[float, float]:
        return self.x0 + cx * RESOLUTION, self.y0 + cy * RESOLUTION


def plan_tour(world: World, clearance: float = 0.4, laps: int = 1
              ) -> list[tuple[float, float]]:
    """Waypoints (x, y) from the world's start pose through every room and back."""
    grid = _Grid(world)
    clearance += RESOLUTION / 2  # the polyline between cell centres keeps the asked one
    start = grid.cell(*world.start_pose[:2])
    if grid.clearance[start[1], start[0]] < clearance:
        raise TourError(f"{world.name}: the start pose has less than {clearance} m of room")
    graph, index = _graph(grid, clearance)
    goals = _goals(grid, clearance)
    here, left, path = start, list(goals), [start]
    while left:  # the nearest goal by path length each time
        dist, pred = dijkstra(graph, indices=index[here[1], here[0]],
                              return_predecessors=True)
        reachable = [g for g in left if math.isfinite(dist[index[g[1], g[0]]])]
        if not reachable:
            break
        nxt = min(reachable, key=lambda g: (dist[index[g[1], g[0]]], g))
        path += _backtrack(pred, index, grid, here, nxt)[1:]
        left = [g for g in left if g != nxt and math.dist(g, nxt) * RESOLUTION > 0.5]
        here = nxt
    if len(path) == 1:
        raise TourError(f"{world.name}: no room reachable with {clearance} m of clearance")
    path += _shortest(graph, index, grid, here, start)[1:]
    return _simplify(grid, path, clearance) * laps


def close_lap(world: World, points: list[tuple[float, float]], clearance: float = 0.4
              ) -> list[tuple[float, float]]:
    """``points`` (a tour cut short: its first waypoints) and then the shortest path
    keeping ``clearance`` from their last point back towards their first (which starts
    the next lap), so a lap of them repeated never drives through a wall from its end to
    its start."""
    grid = _Grid(world)
    clearance += RESOLUTION / 2
    graph, index = _graph(grid, clearance)
    end, start = grid.cell(*points[-1]), grid.cell(*points[0])
    for x, y in (end, start):
        if index[y, x] < 0:
            raise TourError(f"{world.name}: ({grid.point(x, y)}) has less than "
                            f"{clearance} m of room")
    back = _simplify(grid, _shortest(graph, index, grid, end, start), clearance)
    return [*points, *back[1:-1]]


def _goals(grid: _Grid, clearance: float) -> list[tuple[int, int]]:
    """In every room, its most open point, then farthest-point samples until every open
    cell of the room is within COVER of a goal (a corridor gets one every few metres)."""
    open_space = (grid.clearance >= max(ROOM_CLEARANCE, clearance)).astype(np.uint8)
    count, labels = cv2.connectedComponents(open_space, connectivity=4)
    goals = []
    for k in range(1, count):
        ys, xs = np.nonzero(labels == k)
        cells = np.stack([xs, ys], axis=1).astype(float)
        first = int(np.argmax(grid.clearance[ys, xs]))
        chosen = [first]
        far = np.linalg.norm(cells - cells[first], axis=1)
        while far.max() * RESOLUTION > COVER:
            nxt = int(np.argmax(far))
            chosen.append(nxt)
            far = np.minimum(far, np.linalg.norm(cells - cells[nxt], axis=1))
        goals += [(int(cells[i][0]), int(cells[i][1])) for i in chosen]
    return goals


def _graph(grid: _Grid, clearance: float) -> tuple[csr_matrix, np.ndarray]:
    """The 8-connected grid of cells with enough clearance; a step into a cell near a
    wall costs up to 2x, so paths keep to the middle of corridors and doorways."""
    ok = grid.clearance >= clearance
    index = np.full(ok.shape, -1, np.int64)
    index[ok] = np.arange(int(ok.sum()))
    cost = 1.0 + np.clip(1.0 - grid.clearance / 1.5, 0.0, 1.0)
    rows, cols, weights = [], [], []
    ny, nx = ok.shape
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        step = math.hypot(dx, dy) * RESOLUTION
        ys, xs = np.nonzero(ok)
        tx, ty = xs + dx, ys + dy
        inside = (tx >= 0) & (tx < nx) & (ty >= 0) & (ty < ny)
        xs, ys, tx, ty = xs[inside], ys[inside], tx[inside], ty[inside]
        both = ok[ty, tx]
        a, b = index[ys[both], xs[both]], index[ty[both], tx[both]]
        w = step * 0.5 * (cost[ys[both], xs[both]] + cost[ty[both], tx[both]])
        rows += [a, b]
        cols += [b, a]
        weights += [w, w]
    n = int(ok.sum())
    graph = csr_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(n, n))
    return graph, index


def _shortest(graph: csr_matrix, index: np.ndarray, grid: _Grid, source: tuple[int, int],
              target: tuple[int, int]) -> list[tuple[int, int]]:
    """The cells of the shortest clear path from ``source`` to ``target``."""
    _, pred = dijkstra(graph, indices=index[source[1], source[0]], return_predecessors=True)
    return _backtrack(pred, index, grid, source, target)


def _backtrack(pred: np.ndarray, index: np.ndarray, grid: _Grid, source: tuple[int, int],
               target: tuple[int, int]) -> list[tuple[int, int]]:
    cells = np.argwhere(index >= 0)  # (y, x) in index order
    out = [target]
    node = int(index[target[1], target[0]])
    end = int(index[source[1], source[0]])
    while node != end:
        node = int(pred[node])
        if node < 0:
            raise TourError(f"no path from {source} to {target}")
        y, x = cells[node]
        out.append((int(x), int(y)))
    return out[::-1]


def _simplify(grid: _Grid, path: list[tuple[int, int]], clearance: float
              ) -> list[tuple[float, float]]:
    """Waypoints along the cell path: from each, the farthest later cell at most
    WAYPOINT_SPACING away that a straight segment reaches keeping ``clearance`` (sampled
    every half cell), so the polyline keeps the clearance the path had."""
    out = [path[0]]
    i = 0
    while i < len(path) - 1:
        j = i + 1
        while j + 1 < len(path) and math.dist(path[i], path[j + 1]) * RESOLUTION \
                <= WAYPOINT_SPACING and _clear(grid, path[i], path[j + 1], clearance):
            j += 1
        out.append(path[j])
        i = j
    return [grid.point(*c) for c in out]


def _clear(grid: _Grid, a: tuple[int, int], b: tuple[int, int], clearance: float) -> bool:
    n = max(2, int(math.dist(a, b) * 2) + 1)
    xs = np.rint(np.linspace(a[0], b[0], n)).astype(int)
    ys = np.rint(np.linspace(a[1], b[1], n)).astype(int)
    return bool(np.all(grid.clearance[ys, xs] >= clearance))
