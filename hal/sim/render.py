"""The simulated mirror camera: ray-cast panorama, warped into the raw donut (SPEC §10).

Per panorama column a ray is cast from the camera over the floor plan (nearest full-height
wall, nearest low obstacle, nearest person); per row the elevation decides whether the wall,
the floor ("carpet") or the ceiling is seen, and the wall texture is sampled where the ray
hits. The donut is the same view warped through the mirror model, so the daemon's own
unwarping path is exercised. Rendering is supersampled 2x and reduced with area averaging.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from daemon.vision.mirror import MirrorModel, hyperboloid_radius
from daemon.vision.panorama import bearing_of_column
from daemon.vision.settings import MirrorSettings, PanoramaSettings
from hal.sim import textures
from hal.sim.world import World

PX = textures.PX_PER_M
SUPERSAMPLE = 2
CAMERA_BODY_BGR = (35, 35, 35)  # what the mirror shows inside r_inner: the camera itself


@dataclass(frozen=True)
class Person:
    """A moving occluder: an upright cylinder standing at (x, y)."""

    x: float
    y: float
    radius: float = 0.25
    height: float = 1.75
    colour: tuple[int, int, int] = (70, 60, 140)


class Renderer:
    def __init__(self, world: World, mirror: MirrorSettings, panorama: PanoramaSettings,
                 image_size: tuple[int, int]) -> None:
        self.world = world
        self.mirror = mirror
        self.pano = panorama
        self.image_size = image_size
        self.model = MirrorModel(mirror, panorama)
        self._build_geometry()
        self._carpet = textures.carpet(world.floor_colour, world.texture_seed)
        self._build_donut_map()

    # ---------------------------------------------------------------- geometry
    def _build_geometry(self) -> None:
        w = self.world
        rows = int(math.ceil(w.wall_height_m * PX)) + 1
        strips, p0, d, length, height, offset = [], [], [], [], [], []
        col = 0
        for wall in w.walls:
            segs = wall.segments()
            seg_len = [math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in segs]
            total = sum(seg_len)
            strip_w = int(math.ceil(total * PX)) + 2
            seed = hash((w.texture_seed, wall.seed)) & 0x7FFFFFFF
            strip = textures.wall(wall.texture, strip_w, rows, wall.colour, seed)
            for deco in wall.decorations:
                c0 = int(round(deco.at_m * PX))
                c1 = min(strip_w, int(round((deco.at_m + deco.width_m) * PX)))
                r1 = rows - int(round(deco.bottom_m * PX))
                r0 = max(0, r1 - int(round(deco.height_m * PX)))
                if c1 > c0 and r1 > r0:
                    img = textures.decoration(deco.kind, c1 - c0, r1 - r0,
                                              hash((w.texture_seed, deco.seed)) & 0x7FFFFFFF)
                    strip[r0:r1, c0:c1] = img[: r1 - r0, : c1 - c0]
            strips.append(strip)
            along = 0.0
            for (a, b), sl in zip(segs, seg_len, strict=True):
                p0.append(a)
                d.append((b[0] - a[0], b[1] - a[1]))
                length.append(sl)
                height.append(wall.height_m if wall.height_m is not None else w.wall_height_m)
                offset.append(col + along * PX)
                along += sl
            col += strip_w
        self._atlas = np.concatenate(strips, axis=1)
        self._atlas_rows = rows
        self._p0 = np.asarray(p0, float)
        self._d = np.asarray(d, float)
        self._len = np.asarray(length, float)
        self._height = np.asarray(height, float)
        self._offset = np.asarray(offset, float)
        self._low = self._height < w.wall_height_m - 1e-9

    def _cast(self, x: float, y: float, angles: np.ndarray, people: Sequence[Person]
              ) -> dict[str, np.ndarray]:
        """Nearest hits along rays from (x, y) at world ``angles``."""
        rx, ry = np.cos(angles)[:, None], np.sin(angles)[:, None]
        wx, wy = self._p0[:, 0] - x, self._p0[:, 1] - y
        dx, dy = self._d[:, 0], self._d[:, 1]
        denom = rx * dy - ry * dx  # r x d
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (wx * dy - wy * dx) / denom  # (w x d) / (r x d)
            s = (wx * ry - wy * rx) / denom  # (w x r) / (r x d)
        valid = (np.abs(denom) > 1e-12) & (t > 1e-4) & (s >= 0.0) & (s <= 1.0)
        t = np.where(valid, t, np.inf)
        cols = np.arange(len(angles))
        t_full = np.where(self._low[None, :], np.inf, t)
        i_full = np.argmin(t_full, axis=1)
        out = {"t_full": t_full[cols, i_full], "i_full": i_full, "s_full": s[cols, i_full]}
        if self._low.any():
            t_low = np.where(self._low[None, :], t, np.inf)
            i_low = np.argmin(t_low, axis=1)
            out.update(t_low=t_low[cols, i_low], i_low=i_low, s_low=s[cols, i_low])
        t_p = np.full(len(angles), np.inf)
        p_idx = np.zeros(len(angles), int)
        for k, p in enumerate(people):  # ray-circle: |O + t r - C|² = R²
            ox, oy = x - p.x, y - p.y
            b = ox * rx[:, 0] + oy * ry[:, 0]
            c = ox * ox + oy * oy - p.radius**2
            disc = b * b - c
            with np.errstate(invalid="ignore"):
                tp = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
            tp = np.where(tp > 1e-3, tp, np.inf)
            closer = tp < t_p
            t_p = np.where(closer, tp, t_p)
            p_idx = np.where(closer, k, p_idx)
        out.update(t_person=t_p, i_person=p_idx)
        return out

    def _wall_pixels(self, seg: np.ndarray, s: np.ndarray, z: np.ndarray) -> np.ndarray:
        cols = (self._offset[seg] + s * self._len[seg] * PX).astype(np.intp)
        rows = np.clip(((self.world.wall_height_m - z) * PX).astype(np.intp), 0,
                       self._atlas_rows - 1)
        return self._atlas[rows, np.clip(cols, 0, self._atlas.shape[1] - 1)]

    def _render(self, pose: tuple[float, float, float], elevations: np.ndarray,
                bearings: np.ndarray, people: Sequence[Person], gain: float
                ) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols, 3) BGR view and its floor mask for the given elevation rows and
        bearing columns."""
        x, y, yaw = pose
        h = self.pano.camera_height_m
        wall_h = self.world.wall_height_m
        angles = yaw + bearings
        hit = self._cast(x, y, angles, people)
        R, C = len(elevations), len(bearings)
        tan_phi = np.tan(elevations)[:, None]
        img = np.empty((R, C, 3), np.uint8)
        # Ceiling: light panels on a 0.6 m grid.
        with np.errstate(divide="ignore", invalid="ignore"):
            d_ceil = np.where(tan_phi > 0, (wall_h - h) / tan_phi, np.inf)
            d_floor = np.where(tan_phi < 0, h / -tan_phi, np.inf)
        d_ceil = np.where(np.isfinite(d_ceil), d_ceil, 0.0)
        cx = x + d_ceil * np.cos(angles)[None, :]
        cy = y + d_ceil * np.sin(angles)[None, :]
        grid = (np.abs(np.mod(cx, 0.6) - 0.3) > 0.28) | (np.abs(np.mod(cy, 0.6) - 0.3) > 0.28)
        ceiling = np.where(grid[..., None], np.array(self.world.ceiling_colour) * 0.8,
                           np.array(self.world.ceiling_colour))
        img[:] = np.nan_to_num(ceiling).astype(np.uint8)
        # Floor: tiled carpet texture in world coordinates.
        z_full = h + hit["t_full"][None, :] * tan_phi
        floor = z_full < 0
        fr, fc = np.nonzero(floor)
        fx = x + d_floor[fr, 0] * np.cos(angles[fc])
        fy = y + d_floor[fr, 0] * np.sin(angles[fc])
        n = self._carpet.shape[0]
        img[fr, fc] = self._carpet[(fy * PX).astype(np.intp) % n, (fx * PX).astype(np.intp) % n]
        # Full-height walls.
        wall = (z_full >= 0) & (z_full <= wall_h)
        wr, wc = np.nonzero(wall)
        img[wr, wc] = self._wall_pixels(hit["i_full"][wc], hit["s_full"][wc], z_full[wr, wc])
        # Low obstacles in front of the wall.
        if "t_low" in hit:
            t_low = hit["t_low"][None, :]
            z_low = h + t_low * tan_phi
            low = (t_low < hit["t_full"][None, :]) & (z_low >= 0) & (
                z_low <= self._height[hit["i_low"]][None, :])
            lr, lc = np.nonzero(low)
            img[lr, lc] = self._wall_pixels(hit["i_low"][lc], hit["s_low"][lc], z_low[lr, lc])
            floor &= ~low
        # People in front of everything else.
        if people:
            nearest = np.minimum(hit["t_full"], hit.get("t_low", hit["t_full"]))
            t_p = hit["t_person"][None, :]
            z_p = h + t_p * tan_phi
            heights = np.array([p.height for p in people])[hit["i_person"]][None, :]
            person = (t_p < nearest[None, :]) & (z_p >= 0) & (z_p <= heights)
            pr, pc = np.nonzero(person)
            colours = np.array([p.colour for p in people], float)[hit["i_person"][pc]]
            head = z_p[pr, pc] > heights[0, pc] - 0.25
            colours[head] = (90, 120, 170)
            img[pr, pc] = np.clip(colours * (0.8 + 0.2 * np.cos(angles[pc] * 7.0))[:, None],
                                  0, 255).astype(np.uint8)
            floor &= ~person
        if gain != 1.0:
            img = np.asarray(cv2.convertScaleAbs(img, alpha=gain))
        return img, floor

    # ---------------------------------------------------------------- panorama
    def _pano_grid(self, rows: int, cols: int, top: float, bottom: float
                   ) -> tuple[np.ndarray, np.ndarray]:
        elev = top - (top - bottom) * (np.arange(rows) + 0.5) / rows
        bearings = np.asarray(bearing_of_column(np.arange(cols, dtype=float), cols))
        return elev, bearings

    def panorama(self, pose: tuple[float, float, float], *, people: Sequence[Person] = (),
                 gain: float = 1.0) -> np.ndarray:
        """The (H, W, 3) BGR core panorama (no wrap margin) seen at ``pose``."""
        H, W = self.pano.height, self.pano.width
        top, bottom = self.model.top, self.model.bottom
        elev, bearings = self._pano_grid(H * SUPERSAMPLE, W * SUPERSAMPLE, top, bottom)
        img, _ = self._render(pose, elev, bearings, people, gain)
        return cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)

    def floor_mask(self, pose: tuple[float, float, float], *,
                   people: Sequence[Person] = ()) -> np.ndarray:
        """(H, W) bool: the panorama pixels that show floor (ground truth)."""
        H, W = self.pano.height, self.pano.width
        elev, bearings = self._pano_grid(H, W, self.model.top, self.model.bottom)
        _, floor = self._render(pose, elev, bearings, people, 1.0)
        return floor

    # ---------------------------------------------------------------- donut
    def _build_donut_map(self) -> None:
        """Raw pixel -> (row, col) in a band panorama covering r_inner..r_outer."""
        m = self.mirror
        w, h = self.image_size
        self._band_cols = self.pano.width * SUPERSAMPLE
        self._band_rows = self.pano.height * SUPERSAMPLE
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        du, dv = u - m.center_x_px, m.center_y_px - v
        r = np.hypot(du, dv)
        alpha = np.arctan2(dv, du)
        bearing = self.model.bearing_of_image_angle(alpha)
        col = np.mod((math.pi - np.asarray(bearing)) * self._band_cols / (2 * math.pi) - 0.5,
                     self._band_cols)
        if m.model == "hyperboloid":
            phis = np.radians(np.linspace(-89.0, 89.0, 4000))
            radii = hyperboloid_radius(phis, m.a_m, m.b_m, m.focal_px)
            ok = np.isfinite(radii) & (np.diff(radii, prepend=-np.inf) > 0)
            phis, radii = phis[ok], radii[ok]
            self._band_top = float(np.interp(m.r_outer_px, radii, phis))
            self._band_bottom = float(np.interp(m.r_inner_px, radii, phis))
            phi = np.interp(r, radii, phis)
            row = (self._band_top - phi) * self._band_rows / (
                self._band_top - self._band_bottom) - 0.5
        else:  # polynomial: the band is the configured one, rows from the radius polynomial
            self._band_top, self._band_bottom = self.model.top, self.model.bottom
            rows = np.linspace(-0.5, self.pano.height - 0.5, 2000)
            radii = self.model.radius_of_row(rows)
            order = np.argsort(radii)
            row = np.interp(r, radii[order], rows[order]) * SUPERSAMPLE
        self._inside = r < m.r_inner_px
        self._outside = r > m.r_outer_px
        self._map_x = np.asarray(col, np.float32)
        self._map_y = np.asarray(row, np.float32)

    def donut(self, pose: tuple[float, float, float], *, people: Sequence[Person] = (),
              gain: float = 1.0, noise_sigma: float = 0.0, blur_sigma_px: float = 0.0,
              rng: np.random.Generator | None = None) -> np.ndarray:
        """The raw (h, w, 3) BGR mirror-camera image seen at ``pose``."""
        elev, bearings = self._pano_grid(self._band_rows, self._band_cols, self._band_top,
                                         self._band_bottom)
        band, _ = self._render(pose, elev, bearings, people, gain)
        raw = cv2.remap(band, self._map_x, self._map_y, interpolation=cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_WRAP)
        raw[self._inside] = CAMERA_BODY_BGR
        raw[self._outside] = 0
        if blur_sigma_px > 0:
            raw = cv2.GaussianBlur(raw, (0, 0), blur_sigma_px)
        if noise_sigma > 0:
            if rng is None:
                raise ValueError("noise needs an np.random.Generator (rng)")
            noise = np.asarray(rng.normal(0.0, noise_sigma, raw.shape), np.float32)
            raw = np.clip(raw.astype(np.float32) + noise, 0, 255).astype(np.uint8)
        return raw
