"""Simulated worlds: a 2-D floor plan of textured walls and obstacles (docs/design.md §10).

A world file is TOML (format documented in ``config/worlds/README.md``). ``load_world`` also
accepts ``generate:<kind>:<seed>`` for a generated world (``hal/sim/worldgen.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hal.sim.textures import DECORATION_KINDS, FLOOR_KINDS, WALL_KINDS
from kernel.errors import ConfigError
from kernel.settings import read_toml

Colour = tuple[int, int, int]


@dataclass(frozen=True)
class Decoration:
    """Something painted on a wall face: ``at_m`` along the wall from its first point,
    ``bottom_m`` above the floor."""

    kind: str
    at_m: float
    width_m: float
    bottom_m: float
    height_m: float
    seed: int = 0


@dataclass(frozen=True)
class Wall:
    """A polyline of wall segments (closed: back to the first point), full height unless
    ``height_m`` is given (obstacles such as filing cabinets are lower than the camera)."""

    points: tuple[tuple[float, float], ...]
    texture: str = "plain"
    colour: Colour = (200, 200, 200)
    closed: bool = False
    height_m: float | None = None
    decorations: tuple[Decoration, ...] = ()
    seed: int = 0

    def segments(self) -> list[tuple[tuple[float, float], tuple[float, float]]]:
        pts = list(self.points) + ([self.points[0]] if self.closed else [])
        return list(zip(pts[:-1], pts[1:], strict=True))


@dataclass(frozen=True)
class World:
    name: str
    walls: tuple[Wall, ...]
    wall_height_m: float = 2.5
    floor_colour: Colour = (60, 80, 110)
    floor_texture: str = "fine"  # one of textures.FLOOR_KINDS
    floor_gloss: float = 0.0  # the share of a floor pixel that mirrors the walls, [0, 0.6]
    floor_shadow: float = 0.0  # how much darker the floor is right beside walls and
    #                            obstacles, [0, 0.8] (ambient occlusion, 0.15 m falloff)
    ceiling_colour: Colour = (225, 225, 225)
    texture_seed: int = 0
    start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    meta: dict[str, Any] = field(default_factory=dict)

    def bounds(self) -> tuple[float, float, float, float]:
        xs = [p[0] for w in self.walls for p in w.points]
        ys = [p[1] for w in self.walls for p in w.points]
        return min(xs), min(ys), max(xs), max(ys)


def load_world(spec: str) -> World:
    """A world from a TOML file, or ``generate:<kind>:<seed>[:<floor>]`` (a floor of
    ``worldgen.FLOORS``; the generated ``fine`` one without)."""
    if spec.startswith("generate:"):
        from hal.sim.worldgen import generate, with_floor

        parts = spec.split(":")
        if len(parts) not in (3, 4) or not parts[2].lstrip("-").isdigit():
            raise ConfigError(f"world spec {spec!r}: expected generate:<kind>:<seed>"
                              f"[:<floor>]")
        world = generate(parts[1], int(parts[2]))
        return with_floor(world, parts[3]) if len(parts) == 4 else world
    path = Path(spec)
    data = read_toml(path, "world")
    try:
        return world_from_dict(data)
    except ConfigError as e:
        raise ConfigError(f"world {path}: {e}") from e


_WORLD_KEYS = {"name", "wall_height_m", "floor_colour", "floor_texture", "floor_gloss",
               "floor_shadow", "ceiling_colour", "texture_seed", "start_pose", "walls", "meta"}
_WALL_KEYS = {"points", "texture", "colour", "closed", "height_m", "decorations", "seed"}
_DECO_KEYS = {"kind", "at_m", "width_m", "bottom_m", "height_m", "seed"}


def _check_keys(table: dict[str, Any], known: set[str], where: str) -> None:
    unknown = sorted(set(table) - known)
    if unknown:
        known_keys = ", ".join(sorted(known))
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known: {known_keys})")


def _colour(value: Any, where: str) -> Colour:
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(v, int) and 0 <= v <= 255 for v in value)):
        raise ConfigError(f"{where}: expected [b, g, r] with integers 0..255, got {value!r}")
    return (value[0], value[1], value[2])


def _number(value: Any, where: str, minimum: float | None = None,
            maximum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where}: expected a number, got {value!r}")
    if minimum is not None and value < minimum:
        raise ConfigError(f"{where}: {value} is out of range (must be >= {minimum})")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{where}: {value} is out of range (must be <= {maximum})")
    return float(value)


def _floor_texture(value: Any) -> str:
    if value not in FLOOR_KINDS:
        raise ConfigError(f"world.floor_texture: {value!r} is not one of "
                          f"{', '.join(FLOOR_KINDS)}")
    return str(value)


def world_from_dict(data: dict[str, Any]) -> World:
    _check_keys(data, _WORLD_KEYS, "world")
    walls_data = data.get("walls")
    if not isinstance(walls_data, list) or not walls_data:
        raise ConfigError("world: 'walls' must be a non-empty array of tables ([[walls]])")
    walls = []
    for i, w in enumerate(walls_data):
        where = f"walls[{i}]"
        if not isinstance(w, dict):
            raise ConfigError(f"{where}: expected a table")
        _check_keys(w, _WALL_KEYS, where)
        pts = w.get("points")
        if not isinstance(pts, list) or len(pts) < 2:
            raise ConfigError(f"{where}.points: expected at least two [x, y] points")
        points = []
        for j, p in enumerate(pts):
            if not isinstance(p, list) or len(p) != 2:
                raise ConfigError(f"{where}.points[{j}]: expected [x, y], got {p!r}")
            points.append((_number(p[0], f"{where}.points[{j}]"),
                           _number(p[1], f"{where}.points[{j}]")))
        texture = w.get("texture", "plain")
        if texture not in WALL_KINDS:
            raise ConfigError(f"{where}.texture: {texture!r} is not one of {', '.join(WALL_KINDS)}")
        decos = []
        for k, d in enumerate(w.get("decorations", [])):
            dw = f"{where}.decorations[{k}]"
            if not isinstance(d, dict):
                raise ConfigError(f"{dw}: expected a table")
            _check_keys(d, _DECO_KEYS, dw)
            if d.get("kind") not in DECORATION_KINDS:
                raise ConfigError(f"{dw}.kind: {d.get('kind')!r} is not one of "
                                  f"{', '.join(DECORATION_KINDS)}")
            decos.append(Decoration(
                kind=d["kind"], at_m=_number(d.get("at_m"), f"{dw}.at_m", 0.0),
                width_m=_number(d.get("width_m"), f"{dw}.width_m", 0.01),
                bottom_m=_number(d.get("bottom_m", 0.0), f"{dw}.bottom_m", 0.0),
                height_m=_number(d.get("height_m"), f"{dw}.height_m", 0.01),
                seed=int(d.get("seed", 0))))
        height = w.get("height_m")
        walls.append(Wall(
            points=tuple(points), texture=texture,
            colour=_colour(w.get("colour", [200, 200, 200]), f"{where}.colour"),
            closed=bool(w.get("closed", False)),
            height_m=None if height is None else _number(height, f"{where}.height_m", 0.01),
            decorations=tuple(decos), seed=int(w.get("seed", i))))
    start = data.get("start_pose", [0.0, 0.0, 0.0])
    if not isinstance(start, list) or len(start) != 3:
        raise ConfigError(f"world.start_pose: expected [x, y, yaw], got {start!r}")
    return World(
        name=str(data.get("name", "world")), walls=tuple(walls),
        wall_height_m=_number(data.get("wall_height_m", 2.5), "world.wall_height_m", 0.5),
        floor_colour=_colour(data.get("floor_colour", [60, 80, 110]), "world.floor_colour"),
        floor_texture=_floor_texture(data.get("floor_texture", "fine")),
        floor_gloss=_number(data.get("floor_gloss", 0.0), "world.floor_gloss", 0.0, 0.6),
        floor_shadow=_number(data.get("floor_shadow", 0.0), "world.floor_shadow", 0.0, 0.8),
        ceiling_colour=_colour(data.get("ceiling_colour", [225, 225, 225]),
                               "world.ceiling_colour"),
        texture_seed=int(data.get("texture_seed", 0)),
        start_pose=(_number(start[0], "world.start_pose"), _number(start[1], "world.start_pose"),
                    _number(start[2], "world.start_pose")),
        meta=dict(data.get("meta", {})))


def world_to_toml(world: World) -> str:
    out = [f'name = "{world.name}"', f"wall_height_m = {world.wall_height_m}",
           f"floor_colour = {list(world.floor_colour)}",
           f'floor_texture = "{world.floor_texture}"', f"floor_gloss = {world.floor_gloss}",
           f"floor_shadow = {world.floor_shadow}",
           f"ceiling_colour = {list(world.ceiling_colour)}",
           f"texture_seed = {world.texture_seed}", f"start_pose = {list(world.start_pose)}"]
    if world.meta:
        out.append("[meta]")
        out += [f'{k} = "{v}"' if isinstance(v, str) else f"{k} = {v}"
                for k, v in world.meta.items()]
    for w in world.walls:
        out += ["", "[[walls]]", f"points = {[list(p) for p in w.points]}",
                f'texture = "{w.texture}"', f"colour = {list(w.colour)}",
                f"closed = {'true' if w.closed else 'false'}", f"seed = {w.seed}"]
        if w.height_m is not None:
            out.append(f"height_m = {w.height_m}")
        for d in w.decorations:
            out += ["[[walls.decorations]]", f'kind = "{d.kind}"', f"at_m = {d.at_m}",
                    f"width_m = {d.width_m}", f"bottom_m = {d.bottom_m}",
                    f"height_m = {d.height_m}", f"seed = {d.seed}"]
    return "\n".join(out) + "\n"


def save_world(world: World, path: str | Path) -> None:
    Path(path).write_text(world_to_toml(world), encoding="utf-8")
