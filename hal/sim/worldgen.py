"""World generator: ``generate(kind, seed)``; the same kind and seed give the same world.

Kinds: ``office`` (rooms off a corridor, about 30 x 20 m), ``corridor``,
``aliased-corridor`` (identical doors at a fixed spacing; a small sign beside each is the
only thing that tells places apart), ``open-room`` (a cluttered 7 x 10 m room).

Floors: a generated world has the ``fine`` floor (nearly one flat colour);
:func:`with_floor` gives it one of ``FLOORS``, as hard as real ones (design §4).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from hal.sim.world import Decoration, Wall, World
from kernel.errors import ConfigError

KINDS = ("office", "corridor", "aliased-corridor", "open-room")
WALL_COLOURS = [(200, 205, 210), (170, 190, 200), (185, 200, 185), (150, 170, 200),
                (210, 200, 180)]


# name -> World fields. "-coloured": the carpet in the commonest colour of the obstacles
# (cabinets) or of the full-height walls.
FLOORS: dict[str, dict[str, Any]] = {
    "carpet": {"floor_texture": "carpet", "floor_shadow": 0.5},
    "glossy-tiles": {"floor_texture": "tiles", "floor_gloss": 0.3, "floor_shadow": 0.5},
    "obstacle-coloured": {"floor_texture": "carpet", "floor_shadow": 0.5},
    "wall-coloured": {"floor_texture": "carpet", "floor_shadow": 0.5},
}


def with_floor(world: World, name: str) -> World:
    """``world`` with the floor ``name`` of ``FLOORS``."""
    if name not in FLOORS:
        raise ConfigError(f"unknown floor {name!r} (known: {', '.join(FLOORS)})")
    fields = dict(FLOORS[name])
    if name.endswith("-coloured"):
        colours = [w.colour for w in world.walls
                   if (w.height_m is None) == (name == "wall-coloured")]
        if colours:
            fields["floor_colour"] = max(set(colours), key=colours.count)
    return dataclasses.replace(world, name=f"{world.name}-{name}", **fields)


def generate(kind: str, seed: int) -> World:
    makers = {"office": _office, "corridor": _corridor, "aliased-corridor": _aliased_corridor,
              "open-room": _open_room}
    if kind not in makers:
        raise ConfigError(f"unknown world kind {kind!r} (known: {', '.join(KINDS)})")
    return makers[kind](np.random.default_rng([seed, KINDS.index(kind)]), seed)


def _decorations(length: float, rng: np.random.Generator, density: float = 0.45,
                 kinds: tuple[str, ...] = ("poster", "poster", "door", "window", "poster"),
                 margin: float = 0.3) -> tuple[Decoration, ...]:
    """Random decorations along a wall of ``length`` metres, not overlapping."""
    out = []
    x = margin + rng.uniform(0.0, 1.0)
    while x < length - margin:
        kind = str(rng.choice(kinds))
        w, bottom, h = {
            "poster": (rng.uniform(0.4, 1.0), rng.uniform(1.0, 1.5), rng.uniform(0.4, 0.8)),
            "door": (0.9, 0.0, 2.05),
            "window": (rng.uniform(0.8, 1.6), 0.9, 1.2),
            "cabinet": (rng.uniform(0.4, 0.9), 0.0, rng.uniform(1.0, 1.4)),
        }[kind]
        if x + w > length - margin:
            break
        out.append(Decoration(kind, round(float(x), 3), round(float(w), 3), round(float(bottom), 3),
                              round(float(h), 3), int(rng.integers(1 << 30))))
        x += w + rng.exponential(1.0 / density)
    return tuple(out)


def _wall(a: tuple[float, float], b: tuple[float, float], rng: np.random.Generator,
          decorate: bool = True, texture: str | None = None) -> Wall:
    length = float(np.hypot(b[0] - a[0], b[1] - a[1]))
    return Wall(points=(a, b),
                texture=texture or str(rng.choice(["plain", "plain", "noise", "bricks",
                                                   "stripes"])),
                colour=WALL_COLOURS[int(rng.integers(len(WALL_COLOURS)))],
                decorations=_decorations(length, rng) if decorate else (),
                seed=int(rng.integers(1 << 30)))


def _box(x: float, y: float, w: float, d: float, height: float,
         rng: np.random.Generator) -> Wall:
    """A low box obstacle (filing cabinet, desk block) with a drawer texture."""
    pts = ((x, y), (x + w, y), (x + w, y + d), (x, y + d))
    deco = (Decoration("cabinet", 0.0, w, 0.0, height, int(rng.integers(1 << 30))),)
    return Wall(points=pts, texture="plain", colour=(120, 130, 140), closed=True,
                height_m=height, decorations=deco, seed=int(rng.integers(1 << 30)))


def _office(rng: np.random.Generator, seed: int) -> World:
    # A corridor along x at y in [9, 11], five rooms of 6 x 9 m on each side, 1 m doorways.
    walls: list[Wall] = []
    length, room_w, cy0, cy1, depth = 30.0, 6.0, 9.0, 11.0, 9.0
    walls.append(_wall((0.0, 0.0), (length, 0.0), rng))
    walls.append(_wall((length, 0.0), (length, 20.0), rng))
    walls.append(_wall((length, 20.0), (0.0, 20.0), rng))
    walls.append(_wall((0.0, 20.0), (0.0, 0.0), rng))
    for y_wall, room_y0 in ((cy0, cy0 - depth), (cy1, cy1)):
        for i in range(5):
            x0 = i * room_w
            door = x0 + rng.uniform(1.0, room_w - 2.0)
            walls.append(_wall((x0, y_wall), (door, y_wall), rng))
            walls.append(_wall((door + 1.0, y_wall), (x0 + room_w, y_wall), rng))
            if i > 0:  # partition between rooms
                walls.append(_wall((x0, room_y0), (x0, room_y0 + depth), rng))
            for _ in range(int(rng.integers(1, 4))):  # cabinets along the room's walls
                bx = x0 + rng.uniform(0.4, room_w - 1.4)
                by = room_y0 + rng.uniform(0.5, depth - 1.5)
                walls.append(_box(bx, by, rng.uniform(0.5, 1.0), rng.uniform(0.4, 0.6),
                                  rng.uniform(0.9, 1.3), rng))
    return World(name=f"office-{seed}", walls=tuple(walls), texture_seed=seed,
                 floor_colour=(60, 80, 110), start_pose=(3.0, 10.0, 0.0),
                 meta={"kind": "office", "seed": seed})


def _corridor(rng: np.random.Generator, seed: int) -> World:
    length, width = 30.0, 2.4
    walls = [_wall((0.0, 0.0), (length, 0.0), rng), _wall((length, 0.0), (length, width), rng),
             _wall((length, width), (0.0, width), rng), _wall((0.0, width), (0.0, 0.0), rng)]
    return World(name=f"corridor-{seed}", walls=tuple(walls), texture_seed=seed,
                 start_pose=(1.5, width / 2, 0.0), meta={"kind": "corridor", "seed": seed})


def _aliased_corridor(rng: np.random.Generator, seed: int) -> World:
    # Identical doors every 3 m on both walls; the walls themselves are plain and equal.
    # Beside each door on one wall, a small sign of its own (0.5 x 0.4 m, a notice
    # board): the only thing that tells one stretch of corridor from the next.
    length, width, spacing = 30.0, 2.4, 3.0
    door_seed = int(rng.integers(1 << 30))
    at = np.arange(1.05, length - 1.0, spacing)
    doors = tuple(Decoration("door", float(x), 0.9, 0.0, 2.05, door_seed) for x in at)
    signs = tuple(Decoration("poster", round(float(x) + 1.05, 3), 0.5, 1.2, 0.4,
                             int(rng.integers(1 << 30))) for x in at if x + 1.3 < length)
    colour = (190, 200, 205)
    walls = [Wall(((0.0, 0.0), (length, 0.0)), "plain", colour, decorations=doors + signs,
                  seed=1),
             Wall(((length, width), (0.0, width)), "plain", colour,
                  decorations=tuple(Decoration("door", length - d.at_m - d.width_m, d.width_m,
                                               0.0, 2.05, door_seed) for d in doors), seed=1),
             Wall(((length, 0.0), (length, width)), "plain", colour, seed=1),
             Wall(((0.0, width), (0.0, 0.0)), "plain", colour, seed=1)]
    return World(name=f"aliased-corridor-{seed}", walls=tuple(walls), texture_seed=seed,
                 start_pose=(12.0, width / 2, 0.0),
                 meta={"kind": "aliased-corridor", "seed": seed, "door_spacing_m": spacing})


def _open_room(rng: np.random.Generator, seed: int) -> World:
    w, d = 7.0, 10.0
    walls = [_wall((0.0, 0.0), (w, 0.0), rng), _wall((w, 0.0), (w, d), rng),
             _wall((w, d), (0.0, d), rng), _wall((0.0, d), (0.0, 0.0), rng)]
    for _ in range(int(rng.integers(6, 10))):  # clutter: cabinets, boxes, pillars
        bx, by = rng.uniform(0.3, w - 1.3), rng.uniform(0.3, d - 1.3)
        if abs(bx - w / 2) < 1.2 and abs(by - d / 2) < 1.2:
            continue  # keep the centre free for the robot
        walls.append(_box(bx, by, rng.uniform(0.4, 1.0), rng.uniform(0.4, 1.0),
                          rng.uniform(0.8, 1.3), rng))
    return World(name=f"open-room-{seed}", walls=tuple(walls), texture_seed=seed,
                 start_pose=(w / 2, d / 2, 0.0), meta={"kind": "open-room", "seed": seed})
