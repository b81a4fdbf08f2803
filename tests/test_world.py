"""Worlds: generation, files, strict parsing, deterministic rendering (issue 3, point 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from daemon.config import load
from hal.sim.render import Person, Renderer
from hal.sim.world import load_world, save_world
from hal.sim.worldgen import KINDS
from kernel.errors import ConfigError

REPO = Path(__file__).resolve().parent.parent


def _pano(spec: str, pose: tuple[float, float, float] | None = None) -> np.ndarray:
    c = load(None)
    world = load_world(spec)
    return Renderer(world, c.projection, c.panorama, (640, 480)).panorama(pose or world.start_pose)


@pytest.mark.parametrize("kind", KINDS)
def test_same_kind_and_seed_give_identical_panoramas(kind: str) -> None:
    a = _pano(f"generate:{kind}:3")
    b = _pano(f"generate:{kind}:3")
    assert a.tobytes() == b.tobytes()
    assert load_world(f"generate:{kind}:3") == load_world(f"generate:{kind}:3")


@pytest.mark.parametrize("kind", ["office", "corridor", "open-room"])
def test_different_seeds_differ(kind: str) -> None:
    assert load_world(f"generate:{kind}:1") != load_world(f"generate:{kind}:2")
    pose = load_world(f"generate:{kind}:1").start_pose
    assert not np.array_equal(_pano(f"generate:{kind}:1", pose),
                              _pano(f"generate:{kind}:2", pose))


def test_office_size_and_aliased_doors() -> None:
    office = load_world("generate:office:1")
    x0, y0, x1, y1 = office.bounds()
    assert (x1 - x0, y1 - y0) == (30.0, 20.0)
    room = load_world("generate:open-room:1")
    rx0, ry0, rx1, ry1 = room.bounds()
    assert (rx1 - rx0, ry1 - ry0) == (7.0, 10.0)
    aliased = load_world("generate:aliased-corridor:1")
    doors = [d for w in aliased.walls for d in w.decorations if d.kind == "door"]
    assert len(doors) >= 16 and len({d.seed for d in doors}) == 1  # identical doors
    at = sorted(d.at_m for d in aliased.walls[0].decorations if d.kind == "door")
    assert np.allclose(np.diff(at), 3.0)
    signs = [d for d in aliased.walls[0].decorations if d.kind == "poster"]
    assert len(signs) >= 8 and len({d.seed for d in signs}) == len(signs)  # each its own
    assert all(d.width_m * d.height_m <= 0.2 for d in signs)  # small details


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    world = load_world("generate:office:4")
    path = tmp_path / "office.toml"
    save_world(world, path)
    again = load_world(str(path))
    assert again.walls == world.walls and again.start_pose == world.start_pose
    assert _pano(str(path)).tobytes() == _pano("generate:office:4").tobytes()


@pytest.mark.parametrize("path", sorted((REPO / "config" / "worlds").glob("*.toml")))
def test_shipped_worlds_load_and_render(path: Path) -> None:
    pano = _pano(str(path))
    assert pano.shape == (120, 720, 3) and pano.std() > 10


@pytest.mark.parametrize(("text", "message"), [
    ("walls = []", "'walls' must be a non-empty array"),
    ("[[walls]]\npoints = [[0, 0], [1, 0]]\ntexture = 'velvet'\n", "walls[0].texture"),
    ("[[walls]]\npoints = [[0, 0]]\n", "walls[0].points: expected at least two"),
    ("[[walls]]\npoints = [[0, 0], [1, 0]]\ncolor = [1, 2, 3]\n", "walls[0]: unknown key 'color'"),
    ("[[walls]]\npoints = [[0, 0], [1, 0]]\n[[walls.decorations]]\nkind = 'poster'\n"
     "at_m = -1\nwidth_m = 1\nheight_m = 1\n", "walls[0].decorations[0].at_m"),
    ("wall_height_m = 'tall'\n[[walls]]\npoints = [[0, 0], [1, 0]]\n", "world.wall_height_m"),
    ("floor_texture = 'lava'\n[[walls]]\npoints = [[0, 0], [1, 0]]\n", "world.floor_texture"),
    ("floor_gloss = 0.9\n[[walls]]\npoints = [[0, 0], [1, 0]]\n", "world.floor_gloss: 0.9"),
])
def test_bad_world_files_name_the_problem(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_world(str(path))
    assert message in str(e.value) and str(path) in str(e.value)


def test_bad_specs() -> None:
    with pytest.raises(ConfigError, match="unknown world kind 'castle'"):
        load_world("generate:castle:1")
    with pytest.raises(ConfigError, match="generate:<kind>:<seed>"):
        load_world("generate:office")
    with pytest.raises(ConfigError, match="unknown floor 'lava'"):
        load_world("generate:office:1:lava")
    carpeted = load_world("generate:office:1:carpet")
    assert carpeted.floor_texture == "carpet" and carpeted.walls == load_world(
        "generate:office:1").walls
    with pytest.raises(ConfigError, match="cannot read world"):
        load_world("/nonexistent/world.toml")


def test_people_occlude_and_floor_mask_is_floor() -> None:
    c = load(None)
    world = load_world("generate:open-room:1")
    r = Renderer(world, c.projection, c.panorama, (640, 480))
    x, y, _ = world.start_pose
    pose = (x, y, 0.0)
    person = Person(x + 1.0, y)  # one metre straight ahead
    clear, occluded = r.panorama(pose), r.panorama(pose, people=[person])
    W = c.panorama.width
    changed = np.abs(clear.astype(int) - occluded.astype(int)).sum(axis=(0, 2)) > 0
    cols = np.nonzero(changed)[0]
    assert abs(cols.mean() - W / 2) < 5 and 20 < len(cols) < 60  # ~28° wide at 1 m
    mask = r.floor_mask(pose)
    assert mask.shape == (120, 720)
    assert not mask[:40].any()  # above the horizon nothing is floor
    assert mask[-1].mean() > 0.5
    assert r.floor_mask(pose, people=[person])[-1, W // 2 - 5: W // 2 + 5].sum() == 0
