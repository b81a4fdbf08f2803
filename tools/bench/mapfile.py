"""The map file at scale: a 1000-place map (design §6).

Places are built from panoramas rendered in the default office world (so the PNG bytes
are those of real views) with landmarks by static selection; 1000 of them, linked in a
chain by transitions. Figures:

- ``map1000_load_s``: open the file (SQLite's quick check included) and load every place
  (without its panorama, as the daemon holds them) and transition, digests checked;
- ``place_query_ms``: one place by id, decoded (its landmark set: what the localiser
  needs); ``neighbours_query_ms``: the transitions out of a place (both indexed lookups,
  no scan); ``panorama_query_ms``: one reference panorama read and decoded (export,
  pictures);
- ``bytes_per_place``: the file's size over the place count.
"""

from __future__ import annotations

import random
import tempfile
from pathlib import Path

import numpy as np

from daemon.config import load
from daemon.mapping.place import Place
from daemon.store.sqlite_store import MapStore
from daemon.vision.selection import select_static
from daemon.vision.unwarp import Unwarper
from hal.sim.render import Renderer
from hal.sim.world import load_world
from kernel.se2 import SE2, UncertainSE2
from tools.bench.timing import median_seconds

PLACES = 1000
VIEWS = 12  # distinct rendered views, cycled


def _views() -> list[Place]:
    cfg = load(None)
    world = load_world("generate:office:1")
    renderer = Renderer(world, cfg.projection, cfg.panorama,
                        (cfg.camera.sim.image_width, cfg.camera.sim.image_height))
    unwarper = Unwarper(cfg.projection, cfg.panorama)
    rng = np.random.default_rng(0)
    places = []
    for i in range(VIEWS):
        pose = (2.0 + 2.2 * i, 10.0, 0.0)  # along the corridor
        a = unwarper.unwarp(renderer.donut(pose, noise_sigma=2.0, rng=rng))
        b = unwarper.unwarp(renderer.donut(pose, noise_sigma=2.0, rng=rng))
        landmarks = select_static(a, b, cfg.panorama.wrap_margin).best(16)
        places.append(Place(landmarks, a, label=f"view {i}", created_unix_s=1.7e9 + i))
    return places


def _build(path: Path) -> None:
    views = _views()
    step = UncertainSE2(SE2(1.0, 0.0, 0.05), np.diag([0.01, 0.01, 0.001]))
    with MapStore.open(path, "bench") as store:
        last = None
        for i in range(PLACES):
            links: list[tuple[int, UncertainSE2, str]] = [] if last is None else [
                (last, step, "odometry")]
            last = store.add_place(views[i % VIEWS], links).id


def run(repeats: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "map1000.db"
        _build(path)

        def load_all() -> None:
            with MapStore.open(path, "bench") as store:
                assert len(store.load()) == PLACES

        load_s = median_seconds(load_all, max(3, repeats // 2))
        picks = random.Random(1)
        with MapStore.open(path, "bench", readonly=True) as store:
            place_s = median_seconds(lambda: store.place(picks.randint(1, PLACES)), repeats,
                                     inner=50)
            neighbours_s = median_seconds(
                lambda: store.neighbours(picks.randint(1, PLACES)), repeats, inner=200)
            panorama_s = median_seconds(
                lambda: store.reference_panorama(picks.randint(1, PLACES)), repeats, inner=20)
        size = path.stat().st_size + sum(
            p.stat().st_size for p in Path(tmp).glob("map1000.db-*"))
    return {"map1000_load_s": load_s, "place_query_ms": place_s * 1e3,
            "neighbours_query_ms": neighbours_s * 1e3, "panorama_query_ms": panorama_s * 1e3,
            "bytes_per_place": size / PLACES}
