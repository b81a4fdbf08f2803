"""A picture of the map (``placecellctl map plot``): the places at their embedded
positions with their labels, the transitions by kind, the segments, a metric grid of the
`map` frame, and the robot's pose and recent path when the daemon is asked (design §6);
for a simulated robot, the world's walls under it, placed by fitting the robot's true path
to the path the daemon published (``fit_alignment``).

The picture is a list of primitives in metres; SVG and PNG (OpenCV, no plotting library
on the robot) are two renderings of the same list. The SVG carries each place's id and
metric position and each transition's ends, so what is drawn can be checked against the
map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import escape

import cv2
import numpy as np

from daemon.mapping.embedding import embed
from daemon.mapping.graph import TopologicalMap
from kernel.se2 import SE2

# Transition kinds (design §6-8): what measured each one.
KIND_COLOURS = {"odometry": (150, 150, 150), "vision": (40, 110, 220), "cycle": (30, 160, 60)}
SEGMENT_COLOURS = [(200, 60, 40), (140, 70, 170), (220, 140, 20), (20, 150, 150),
                   (120, 120, 20)]
PATH_COLOUR = (230, 60, 140)
WALL_COLOUR = (175, 160, 135)
INK, GRID = (40, 40, 40), (220, 220, 220)
SCALE_PX_PER_M = 60.0
MARGIN_PX = 70
OTHER_SEGMENT_GAP_M = 2.0
Pixel = tuple[float, float]


@dataclass(frozen=True)
class Item:
    """One primitive: ``kind`` line | circle | text | polyline | arrow; ``points`` in
    metres; ``data`` what the SVG says about it (place id, transition ends)."""

    kind: str
    points: tuple[tuple[float, float], ...]
    colour: tuple[int, int, int]
    cls: str = ""
    text: str = ""
    radius_px: float = 0.0
    data: tuple[tuple[str, str], ...] = ()


@dataclass
class Picture:
    items: list[Item] = field(default_factory=list)
    title: str = ""

    def extent(self) -> tuple[float, float, float, float]:
        pts = [p for it in self.items for p in it.points] or [(0.0, 0.0)]
        xs, ys = [p[0] for p in pts], [p[1] for p in pts]
        return min(xs) - 0.5, min(ys) - 0.5, max(xs) + 0.5, max(ys) + 0.5


def _segment_frames(graph: TopologicalMap) -> tuple[dict[int, SE2], dict[int, int]]:
    """Every place's position: the map frame's segment as embedded, each other segment in
    its own frame (its lowest place's), drawn to the right of what is already there."""
    segments = graph.segments()
    frames = embed(graph)
    right = max((p.x for p in frames.values()), default=0.0)
    for segment in sorted(set(segments.values())):
        members = [pid for pid, s in segments.items() if s == segment]
        if all(pid in frames for pid in members):
            continue
        sub = TopologicalMap([graph.place(pid) for pid in members],
                             [t for t in graph.transitions if t.from_id in members])
        own = embed(sub)
        left = min(p.x for p in own.values())
        shift = right + OTHER_SEGMENT_GAP_M - left
        for pid, pose in own.items():
            frames[pid] = SE2(pose.x + shift, pose.y, pose.yaw)
        right = max(p.x for p in frames.values())
    return frames, segments


def draw_map(graph: TopologicalMap, path: list[tuple[float, float]] | None = None,
             pose: SE2 | None = None, title: str = "") -> Picture:
    frames, segments = _segment_frames(graph)
    main_segment = min(segments.values(), default=None)
    pic = Picture(title=title)
    drawn_pairs = set()
    for t in graph.transitions:
        pair = (min(t.from_id, t.to_id), max(t.from_id, t.to_id))
        if pair in drawn_pairs or t.from_id not in frames or t.to_id not in frames:
            continue
        drawn_pairs.add(pair)
        a, b = frames[pair[0]], frames[pair[1]]
        pic.items.append(Item("line", ((a.x, a.y), (b.x, b.y)), KIND_COLOURS[t.source],
                              cls=f"transition {t.source}",
                              data=(("from", str(pair[0])), ("to", str(pair[1])))))
    for place in graph.places:
        p = frames[place.id]
        segment = segments[place.id]
        colour = SEGMENT_COLOURS[sorted(set(segments.values())).index(segment)
                                 % len(SEGMENT_COLOURS)]
        pic.items.append(Item("circle", ((p.x, p.y),), colour, cls="place", radius_px=7,
                              data=(("id", str(place.id)), ("segment", str(segment)),
                                    ("x", f"{p.x:.4f}"), ("y", f"{p.y:.4f}"))))
        name = f"{place.id}" + (f" {place.label}" if place.label else "")
        pic.items.append(Item("text", ((p.x, p.y),), INK, cls="label", text=name))
    for segment in sorted(set(segments.values()) - {main_segment}):
        first = frames[segment]  # a segment is named by its lowest place
        pic.items.append(Item("text", ((first.x, first.y - 0.45),), INK, cls="segment",
                              text=f"segment {segment}, its own frame"))
    if path:
        pic.items.append(Item("polyline", tuple(path), PATH_COLOUR, cls="path"))
    if pose is not None:
        tip = (pose.x + 0.4 * math.cos(pose.yaw), pose.y + 0.4 * math.sin(pose.yaw))
        pic.items.append(Item("arrow", ((pose.x, pose.y), tip), PATH_COLOUR, cls="robot"))
    return pic


def fit_alignment(pairs: list[tuple[tuple[float, float], tuple[float, float]]]
                  ) -> tuple[SE2, float]:
    """T_map_world, the rotation and translation taking world points onto map points in
    least squares (Kabsch in 2-D), from (map point, world point) pairs, and the RMS
    distance left between them (m). ValueError for fewer than two pairs or points that do
    not spread (a robot that stood still: no direction to fit)."""
    if len(pairs) < 2:
        raise ValueError(f"{len(pairs)} poses matched: at least two are needed")
    m = np.array([p[0] for p in pairs], dtype=float)
    w = np.array([p[1] for p in pairs], dtype=float)
    mc, wc = m - m.mean(axis=0), w - w.mean(axis=0)
    if float(np.sqrt((wc ** 2).sum(axis=1)).max()) < 0.2:
        raise ValueError("the robot moved less than 0.2 m: no direction to fit the plan by")
    h = wc.T @ mc
    yaw = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s], [s, c]])
    t = m.mean(axis=0) - rot @ w.mean(axis=0)
    rms = float(np.sqrt((((w @ rot.T) + t - m) ** 2).sum(axis=1).mean()))
    return SE2(float(t[0]), float(t[1]), yaw), rms


def add_plan(pic: Picture, walls: list[tuple[tuple[float, float], tuple[float, float]]],
             T_map_world: SE2) -> None:
    """The world's wall segments, in the map frame, under everything else."""
    items = []
    for a, b in walls:
        pa, pb = T_map_world.compose(SE2(a[0], a[1], 0.0)), T_map_world.compose(
            SE2(b[0], b[1], 0.0))
        items.append(Item("line", ((pa.x, pa.y), (pb.x, pb.y)), WALL_COLOUR, cls="wall"))
    pic.items[:0] = items


def _tick(span_m: float) -> float:
    for step in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0):
        if span_m / step <= 12:
            return step
    return span_m / 12


class _Frame:
    """Metres to pixels: x right, y up, SCALE_PX_PER_M, a margin for the axes."""

    def __init__(self, pic: Picture) -> None:
        self.x0, self.y0, x1, y1 = pic.extent()
        top = 30 + 18 * len(_legend(pic))  # the title and the legend, above the plot
        # room on the right for the last labels
        self.width = max(int((x1 - self.x0) * SCALE_PX_PER_M) + 2 * MARGIN_PX + 120, 360)
        self.height = int((y1 - self.y0) * SCALE_PX_PER_M) + 2 * MARGIN_PX + top
        self.x1, self.y1 = x1, y1

    def px(self, x: float, y: float) -> tuple[float, float]:
        return (MARGIN_PX + (x - self.x0) * SCALE_PX_PER_M,
                self.height - MARGIN_PX - (y - self.y0) * SCALE_PX_PER_M)

    def grid(self) -> list[tuple[Pixel, Pixel, Pixel, str]]:
        """Each grid line in pixels (its two ends), where its tick label goes, and the
        label: one geometry for both renderings."""
        step = _tick(max(self.x1 - self.x0, self.y1 - self.y0))
        out = []
        for v in np.arange(math.ceil(self.x0 / step) * step, self.x1, step):
            a, b = self.px(v, self.y0), self.px(v, self.y1)
            out.append((a, b, (a[0] - 8, a[1] + 16), f"{v:g}"))
        for v in np.arange(math.ceil(self.y0 / step) * step, self.y1, step):
            a, b = self.px(self.x0, v), self.px(self.x1, v)
            out.append((a, b, (a[0] - 40, a[1] + 4), f"{v:g}"))
        return out


def _legend(pic: Picture) -> list[tuple[str, tuple[int, int, int], str]]:
    kinds = sorted({it.cls.split()[1] for it in pic.items if it.cls.startswith("transition")})
    out = [("circle", SEGMENT_COLOURS[0], "place (colour: segment)")]
    out += [("line", KIND_COLOURS[k], f"transition: {k}") for k in kinds]
    if any(it.cls in ("path", "robot") for it in pic.items):
        out.append(("line", PATH_COLOUR, "robot: pose and recent path"))
    if any(it.cls == "wall" for it in pic.items):
        out.append(("line", WALL_COLOUR, "simulated world's walls (fitted to the true path)"))
    return out


def _hex(colour: tuple[int, int, int]) -> str:
    return "#" + "".join(f"{c:02x}" for c in colour)


def to_svg(pic: Picture) -> str:
    f = _Frame(pic)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{f.width}" height="{f.height}" '
           f'data-scale-px-per-m="{SCALE_PX_PER_M}" data-x0="{f.x0:.4f}" '
           f'data-y0="{f.y0:.4f}" data-margin-px="{MARGIN_PX}" font-family="sans-serif">',
           f'<rect width="{f.width}" height="{f.height}" fill="white"/>']
    for a, b, (lx, ly), label in f.grid():
        out.append(f'<line class="grid" x1="{a[0]:.1f}" y1="{a[1]:.1f}" x2="{b[0]:.1f}" '
                   f'y2="{b[1]:.1f}" stroke="{_hex(GRID)}"/>')
        out.append(f'<text class="tick" x="{lx:.1f}" y="{ly:.1f}" font-size="11">{label}</text>')
    out.append(f'<text x="{f.width / 2:.0f}" y="{f.height - 20}" font-size="12">'
               "x (m), map frame</text>")
    out.append(f'<text x="12" y="{f.height / 2:.0f}" font-size="12" transform="rotate(-90 12 '
               f'{f.height / 2:.0f})">y (m)</text>')
    for it in pic.items:
        data = "".join(f' data-{k}="{escape(v)}"' for k, v in it.data)
        cls = f' class="{it.cls}"' if it.cls else ""
        pts = [f.px(*p) for p in it.points]
        if it.kind == "line":
            out.append(f'<line{cls}{data} x1="{pts[0][0]:.1f}" y1="{pts[0][1]:.1f}" '
                       f'x2="{pts[1][0]:.1f}" y2="{pts[1][1]:.1f}" stroke="{_hex(it.colour)}" '
                       'stroke-width="3"/>')
        elif it.kind == "circle":
            out.append(f'<circle{cls}{data} cx="{pts[0][0]:.1f}" cy="{pts[0][1]:.1f}" '
                       f'r="{it.radius_px}" fill="{_hex(it.colour)}"/>')
        elif it.kind == "text":
            dx, dy = (9, -9) if it.cls == "label" else (-10, 4)
            out.append(f'<text{cls} x="{pts[0][0] + dx:.1f}" y="{pts[0][1] + dy:.1f}" '
                       f'font-size="12">{escape(it.text)}</text>')
        else:  # polyline, arrow
            joined = " ".join(f"{x:.1f},{y:.1f}" for x, y in pts)
            out.append(f'<polyline{cls} points="{joined}" fill="none" '
                       f'stroke="{_hex(it.colour)}" stroke-width="{4 if it.kind == "arrow" else 2}"'
                       '/>')
    y = 20
    if pic.title:
        out.append(f'<text x="{MARGIN_PX}" y="{y}" font-size="14">{escape(pic.title)}</text>')
    for shape, colour, text in _legend(pic):
        y += 18
        swatch = (f'<circle cx="{MARGIN_PX + 6}" cy="{y - 4}" r="5" fill="{_hex(colour)}"/>'
                  if shape == "circle" else
                  f'<line x1="{MARGIN_PX}" y1="{y - 4}" x2="{MARGIN_PX + 14}" y2="{y - 4}" '
                  f'stroke="{_hex(colour)}" stroke-width="3"/>')
        out.append(f'<g class="legend">{swatch}<text x="{MARGIN_PX + 20}" y="{y}" '
                   f'font-size="12">{escape(text)}</text></g>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def to_png(pic: Picture) -> np.ndarray:
    f = _Frame(pic)
    img = np.full((f.height, f.width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX

    def bgr(c: tuple[int, int, int]) -> tuple[int, int, int]:
        return c[2], c[1], c[0]

    def ip(p: tuple[float, float]) -> tuple[int, int]:
        return int(round(p[0])), int(round(p[1]))

    for a, b, at, label in f.grid():
        cv2.line(img, ip(a), ip(b), bgr(GRID), 1)
        cv2.putText(img, label, ip(at), font, 0.4, bgr(INK), 1, cv2.LINE_AA)
    cv2.putText(img, "x (m), map frame", (f.width // 2 - 60, f.height - 20), font, 0.45,
                bgr(INK), 1, cv2.LINE_AA)
    cv2.putText(img, "y (m)", (8, int(f.px(f.x0, f.y1)[1]) - 8), font, 0.45, bgr(INK), 1,
                cv2.LINE_AA)
    for it in pic.items:
        pts = [ip(f.px(*p)) for p in it.points]
        if it.kind == "line":
            cv2.line(img, pts[0], pts[1], bgr(it.colour), 3, cv2.LINE_AA)
        elif it.kind == "circle":
            cv2.circle(img, pts[0], int(it.radius_px), bgr(it.colour), -1, cv2.LINE_AA)
        elif it.kind == "text":
            dx, dy = (9, -9) if it.cls == "label" else (-10, 4)
            cv2.putText(img, it.text, (pts[0][0] + dx, pts[0][1] + dy), font, 0.45, bgr(INK),
                        1, cv2.LINE_AA)
        elif it.kind == "arrow":
            cv2.arrowedLine(img, pts[0], pts[1], bgr(it.colour), 3, cv2.LINE_AA, tipLength=0.3)
        else:
            cv2.polylines(img, [np.array(pts, np.int32)], False, bgr(it.colour), 2, cv2.LINE_AA)
    y = 20
    if pic.title:
        cv2.putText(img, pic.title, (MARGIN_PX, y), font, 0.5, bgr(INK), 1, cv2.LINE_AA)
    for shape, colour, text in _legend(pic):
        y += 18
        if shape == "circle":
            cv2.circle(img, (MARGIN_PX + 6, y - 4), 5, bgr(colour), -1, cv2.LINE_AA)
        else:
            cv2.line(img, (MARGIN_PX, y - 4), (MARGIN_PX + 14, y - 4), bgr(colour), 3)
        cv2.putText(img, text, (MARGIN_PX + 20, y), font, 0.42, bgr(INK), 1, cv2.LINE_AA)
    return img


def write(pic: Picture, out: Path) -> None:
    """SVG or PNG by the file's suffix."""
    if out.suffix.lower() == ".svg":
        out.write_text(to_svg(pic), encoding="utf-8")
    elif out.suffix.lower() == ".png":
        if not cv2.imwrite(str(out), to_png(pic)):
            raise OSError(f"cannot write {out}")
    else:
        raise ValueError(f"{out}: the picture is .svg or .png")
