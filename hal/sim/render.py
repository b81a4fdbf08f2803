"""The simulated mirror camera: ray-cast panorama, warped into the raw donut (docs/design.md §10).

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
from statistics import NormalDist

import cv2
import numpy as np

from hal.sim import textures
from hal.sim.world import World
from kernel.camera_models import Projection, camera_model
from kernel.mirror import MirrorModel, hyperboloid_radius
from kernel.panorama import bearing_of_column
from kernel.sensor_settings import MirrorSettings, PanoramaSettings

PX = textures.PX_PER_M
SUPERSAMPLE = 2
SHADOW_PX_PER_M = 50
CAMERA_BODY_BGR = (35, 35, 35)  # what the mirror shows inside r_inner: the camera itself


@dataclass(frozen=True)
class Person:
    """A moving occluder: an upright cylinder standing at (x, y)."""

    x: float
    y: float
    radius: float = 0.25
    height: float = 1.75
    colour: tuple[int, int, int] = (70, 60, 140)


def _pack(bgr: np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 -> (h, w) uint32 holding B, G, R, 0 in memory order."""
    four = np.zeros((*bgr.shape[:2], 4), np.uint8)
    four[..., :3] = bgr
    return four.view(np.uint32)[..., 0]


class Renderer:
    def __init__(self, world: World, projection: Projection, panorama: PanoramaSettings,
                 image_size: tuple[int, int]) -> None:
        self.world = world
        self.projection = projection
        self.pano = panorama
        self.image_size = image_size
        self.model = camera_model(projection, panorama)
        self._build_geometry()
        self._carpet = _pack(textures.floor(world.floor_texture, world.floor_colour,
                                            world.texture_seed))
        self._shade = self._shadow_map() if world.floor_shadow > 0 else None
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
        atlas = np.concatenate(strips, axis=1)
        # Packed as one uint32 per pixel (B, G, R, 0): one gather per pixel instead of three.
        self._atlas = _pack(atlas)
        self._atlas_rows = rows
        self._p0 = np.asarray(p0, float)
        self._d = np.asarray(d, float)
        self._len = np.asarray(length, float)
        self._height = np.asarray(height, float)
        self._offset = np.asarray(offset, float)
        self._low = self._height < w.wall_height_m - 1e-9

    def _shadow_map(self) -> tuple[np.ndarray, float, float]:
        """The floor's brightness factor on a 2 cm grid over the world (ambient occlusion):
        1 − floor_shadow · exp(−d / 0.15 m), d the distance to the nearest wall or obstacle
        foot; with the grid's origin (x0, y0)."""
        x0, y0, x1, y1 = self.world.bounds()
        x0, y0 = x0 - 0.5, y0 - 0.5
        shape = (int((y1 + 0.5 - y0) * SHADOW_PX_PER_M) + 1,
                 int((x1 + 0.5 - x0) * SHADOW_PX_PER_M) + 1)
        free = np.full(shape, 255, np.uint8)
        for a, d in zip(self._p0, self._d, strict=True):
            pa = (int((a[0] - x0) * SHADOW_PX_PER_M), int((a[1] - y0) * SHADOW_PX_PER_M))
            pb = (int((a[0] + d[0] - x0) * SHADOW_PX_PER_M),
                  int((a[1] + d[1] - y0) * SHADOW_PX_PER_M))
            cv2.line(free, pa, pb, 0, 1)
        dist_m = cv2.distanceTransform(free, cv2.DIST_L2, 5) / SHADOW_PX_PER_M
        shade = 1.0 - self.world.floor_shadow * np.exp(-dist_m / 0.15)
        return shade.astype(np.float32), x0, y0

    def _floor_pixels(self, fx: np.ndarray, fy: np.ndarray, refl: np.ndarray | None
                      ) -> np.ndarray:
        """Packed floor colour at world points (fx, fy): the texture, darkened near walls
        and obstacles, blended with ``refl`` (packed: what the floor mirrors there)."""
        n = self._carpet.shape[0]
        px = self._carpet[(fy * PX).astype(np.intp) % n, (fx * PX).astype(np.intp) % n]
        if self._shade is None and refl is None:
            return px
        colour = px.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.float32)
        if self._shade is not None:
            shade, x0, y0 = self._shade
            iy = np.clip(((fy - y0) * SHADOW_PX_PER_M).astype(np.intp), 0, shade.shape[0] - 1)
            ix = np.clip(((fx - x0) * SHADOW_PX_PER_M).astype(np.intp), 0, shade.shape[1] - 1)
            colour *= shade[iy, ix][:, None]
        if refl is not None:
            g = self.world.floor_gloss
            mirrored = refl.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.float32)
            colour = (1.0 - g) * colour + g * mirrored
        return _pack(np.clip(colour, 0, 255).astype(np.uint8)[None])[0]

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
        return self._atlas[rows, np.clip(cols, 0, self._atlas.shape[1] - 1)]  # packed uint32

    def _render(self, pose: tuple[float, float, float], elevations: np.ndarray,
                bearings: np.ndarray, people: Sequence[Person], gain: float
                ) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols, 3) BGR view and its floor mask for the given elevation rows and
        bearing columns. Work is done per visible surface on flat index arrays only."""
        x, y, yaw = pose
        h = self.pano.camera_height_m
        wall_h = self.world.wall_height_m
        angles = yaw + bearings
        cos_a, sin_a = np.cos(angles), np.sin(angles)
        hit = self._cast(x, y, angles, people)
        R, C = len(elevations), len(bearings)
        tan_phi = np.tan(elevations).astype(np.float32)[:, None]
        # Height where each pixel's ray meets the nearest full wall: z = h + t tan(phi).
        t_full = np.minimum(hit["t_full"], 1e6).astype(np.float32)[None, :]
        z_full = h + t_full * tan_phi
        packed = np.empty((R, C), np.uint32)
        img = packed.view(np.uint8).reshape(R, C, 4)
        floor = z_full < 0
        ceiling = z_full > wall_h
        wall = ~(floor | ceiling)
        # Ceiling: light panels on a 0.6 m grid, seen at d = (H_wall - h) / tan(phi).
        cr, cc = np.nonzero(ceiling)
        d = (wall_h - h) / tan_phi[cr, 0]
        gx = np.mod(x + d * cos_a[cc], 0.6)
        gy = np.mod(y + d * sin_a[cc], 0.6)
        seam = (np.abs(gx - 0.3) > 0.28) | (np.abs(gy - 0.3) > 0.28)
        ceil_colour = np.array(self.world.ceiling_colour, np.uint8)
        img[cr, cc, :3] = np.where(seam[:, None], (ceil_colour * 0.8).astype(np.uint8),
                                   ceil_colour)
        # Floor: tiled texture in world coordinates, seen at d = h / -tan(phi); a glossy
        # floor mirrors the full wall, seen at height -z (the camera's image below the
        # floor), or the ceiling above it.
        fr, fc = np.nonzero(floor)
        d = h / -tan_phi[fr, 0]
        refl = None
        if self.world.floor_gloss > 0:
            z_ref = -z_full[fr, fc]
            refl = np.full(len(fr), _pack(ceil_colour[None, None])[0, 0], np.uint32)
            on_wall = np.nonzero(z_ref <= wall_h)[0]
            cols = fc[on_wall]
            refl[on_wall] = self._wall_pixels(hit["i_full"][cols], hit["s_full"][cols],
                                              z_ref[on_wall])
        packed[fr, fc] = self._floor_pixels(x + d * cos_a[fc], y + d * sin_a[fc], refl)
        # Full-height walls.
        wr, wc = np.nonzero(wall)
        packed[wr, wc] = self._wall_pixels(hit["i_full"][wc], hit["s_full"][wc], z_full[wr, wc])
        # Low obstacles in front of the wall.
        if "t_low" in hit:
            in_front = np.nonzero(hit["t_low"] < hit["t_full"])[0]
            if len(in_front):
                t_low = hit["t_low"][in_front].astype(np.float32)[None, :]
                z_low = h + t_low * tan_phi
                top = self._height[hit["i_low"][in_front]][None, :]
                lr, lk = np.nonzero((z_low >= 0) & (z_low <= top))
                lc = in_front[lk]
                packed[lr, lc] = self._wall_pixels(hit["i_low"][lc], hit["s_low"][lc],
                                                z_low[lr, lk])
                floor[lr, lc] = False
        # People in front of everything else.
        if people:
            nearest = np.minimum(hit["t_full"], hit.get("t_low", hit["t_full"]))
            cols = np.nonzero(hit["t_person"] < nearest)[0]
            if len(cols):
                t_p = hit["t_person"][cols].astype(np.float32)[None, :]
                z_p = h + t_p * tan_phi
                heights = np.array([p.height for p in people])[hit["i_person"][cols]]
                pr, pk = np.nonzero((z_p >= 0) & (z_p <= heights[None, :]))
                pc = cols[pk]
                colours = np.array([p.colour for p in people], float)[hit["i_person"][pc]]
                colours[z_p[pr, pk] > heights[pk] - 0.25] = (90, 120, 170)  # head
                shade = 0.8 + 0.2 * np.cos(angles[pc] * 7.0)
                img[pr, pc, :3] = np.clip(colours * shade[:, None], 0, 255).astype(np.uint8)
                floor[pr, pc] = False
        if gain != 1.0:
            img = np.asarray(cv2.convertScaleAbs(img, alpha=gain))
        return img, floor  # (R, C, 4): B, G, R and an unused fourth byte

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
        return np.asarray(cv2.cvtColor(cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA),
                                       cv2.COLOR_BGRA2BGR))

    def floor_mask(self, pose: tuple[float, float, float], *,
                   people: Sequence[Person] = ()) -> np.ndarray:
        """(H, W) bool: the panorama pixels that show floor (ground truth)."""
        H, W = self.pano.height, self.pano.width
        elev, bearings = self._pano_grid(H, W, self.model.top, self.model.bottom)
        _, floor = self._render(pose, elev, bearings, people, 1.0)
        return floor

    # ---------------------------------------------------------------- donut
    def _build_donut_map(self) -> None:
        """Raw pixel -> (row, col) in a band panorama covering what the camera sees."""
        if not isinstance(self.projection, MirrorSettings):
            self._build_model_map()
            return
        m = self.projection
        model = self.model
        assert isinstance(model, MirrorModel)
        w, h = self.image_size
        self._band_cols = self.pano.width * SUPERSAMPLE
        # One band row per pixel of radial extent: the raw image's own radial resolution.
        self._band_rows = int(math.ceil(m.r_outer_px - m.r_inner_px))
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        du, dv = u - m.center_x_px, m.center_y_px - v
        r = np.hypot(du, dv)
        alpha = np.arctan2(dv, du)
        bearing = model.azimuth.bearing(alpha)
        col = self._band_column(bearing)
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
            self._band_top, self._band_bottom = model.top, model.bottom
            rows = np.linspace(-0.5, self.pano.height - 0.5, 2000)
            radii = model.radius_of_row(rows)
            order = np.argsort(radii)
            row = (np.interp(r, radii[order], rows[order]) + 0.5) * (
                self._band_rows / self.pano.height) - 0.5
        # Three extra band rows: the camera body (row band_rows, seen inside r_inner) and
        # black (the last row, outside r_outer; BORDER_WRAP also blends it into the rim at
        # row -0.5). Whole row numbers, so the camera body is not mixed with black.
        row = np.where(r < m.r_inner_px, float(self._band_rows), row)
        row = np.where(r > m.r_outer_px, self._band_rows + 2.0, row)
        self._map_x = np.asarray(col, np.float32)
        self._map_y = np.asarray(row, np.float32)

    def _band_column(self, bearing: np.ndarray) -> np.ndarray:
        """Fractional band column of ``bearing`` (the panorama's column rule, kernel/panorama.py,
        over the band's columns, the seam wrapped)."""
        return np.mod((math.pi - np.asarray(bearing)) * self._band_cols / (2 * math.pi) - 0.5,
                      self._band_cols)

    BAND_ROWS_MAX = 720
    BAND_MARGIN_DEG = 5.0
    ABOVE_ROW, BELOW_ROW = 1, 3  # extra band rows after the band's own (see donut)

    def _build_model_map(self) -> None:
        """The same for any camera model (kernel/camera_models.py): the band spans the
        elevations the camera sees within BAND_MARGIN_DEG of the panorama's, at half the
        panorama's row step (at most BAND_ROWS_MAX rows). What it sees above and below
        them (the ceiling, the floor at the robot's feet) is drawn flat in the ceiling's
        and the floor's colours: the daemon's panorama never looks there, and a 360°
        camera's whole sphere costs three times the mirror's rendering. Pixels that see
        nothing of the world are black."""
        w, h = self.image_size
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        bearing, phi = self.model.direction_of_point(u, v)
        seen = np.isfinite(phi)
        if not seen.any():
            raise ValueError("the camera model sees nothing of the world in a "
                             f"{w} x {h} image")
        limit = math.radians(89.5)
        margin = math.radians(self.BAND_MARGIN_DEG)
        self._band_top = min(float(np.max(phi[seen])), limit, self.model.top + margin)
        self._band_bottom = max(float(np.min(phi[seen])), -limit, self.model.bottom - margin)
        step = (self.model.top - self.model.bottom) / self.pano.height / 2.0
        self._band_rows = min(self.BAND_ROWS_MAX, int(math.ceil(
            (self._band_top - self._band_bottom) / step)))
        self._band_cols = self.pano.width * SUPERSAMPLE
        col = self._band_column(bearing)
        row = (self._band_top - np.clip(phi, self._band_bottom, self._band_top)) * (
            self._band_rows / (self._band_top - self._band_bottom)) - 0.5
        with np.errstate(invalid="ignore"):
            row = np.where(phi > self._band_top + 1e-9, self._band_rows + self.ABOVE_ROW, row)
            row = np.where(phi < self._band_bottom - 1e-9, self._band_rows + self.BELOW_ROW,
                           row)
        row = np.where(seen, row, self._band_rows + 2.0)
        self._map_x = np.asarray(np.where(seen, col, 0.0), np.float32)
        self._map_y = np.asarray(row, np.float32)

    NOISE_FIXED_POINT = 16.0
    # N(0, 1) quantiles at the centres of 65536 equal-probability bins, in fixed point: a
    # uniform 16-bit index into this table is a Gaussian sample (tails cut at 4.3 sigma).
    _GAUSS_TABLE = np.round(
        np.array([NormalDist().inv_cdf((k + 0.5) / 65536) for k in range(65536)])
        * NOISE_FIXED_POINT).astype(np.int16)

    def _add_noise(self, raw: np.ndarray, sigma: float, rng: np.random.Generator
                   ) -> np.ndarray:
        """Gaussian sensor noise N(0, sigma²), independent per pixel, channel and frame, all
        drawn from ``rng``. Drawing float normals costs ~8 ms a frame; uniform bytes looked
        up in an inverse-CDF table cost ~2 ms, with the same distribution (to 1/16 grey
        level and 4.3 sigma)."""
        index = np.frombuffer(rng.bytes(2 * raw.size), np.uint16)
        noise = np.take(self._GAUSS_TABLE, index).reshape(raw.shape)
        return np.asarray(cv2.addWeighted(raw, 1.0, noise, sigma / self.NOISE_FIXED_POINT, 0.0,
                                          dtype=cv2.CV_8U))

    def donut(self, pose: tuple[float, float, float], *, people: Sequence[Person] = (),
              gain: float = 1.0, noise_sigma: float = 0.0, blur_sigma_px: float = 0.0,
              rng: np.random.Generator | None = None) -> np.ndarray:
        """The raw (h, w, 3) BGR mirror-camera image seen at ``pose``."""
        elev, bearings = self._pano_grid(self._band_rows, self._band_cols, self._band_top,
                                         self._band_bottom)
        band, _ = self._render(pose, elev, bearings, people, gain)
        # Extra rows: the camera body (n), black (n + 2, n + 4: the last row, which
        # BORDER_WRAP blends into the band's first), and for other camera models what is
        # seen above and below the band, drawn flat: the ceiling's colour and the floor's.
        n = band.shape[0]
        band = np.concatenate([band, np.zeros((5, band.shape[1], 4), np.uint8)])
        band[n, :, :3] = CAMERA_BODY_BGR
        band[n + self.ABOVE_ROW, :, :3] = np.array(self.world.ceiling_colour, np.uint8) * gain
        band[n + self.BELOW_ROW, :, :3] = np.array(self.world.floor_colour, np.uint8) * gain
        raw = cv2.cvtColor(cv2.remap(band, self._map_x, self._map_y,
                                     interpolation=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_WRAP), cv2.COLOR_BGRA2BGR)
        if blur_sigma_px > 0:
            raw = cv2.GaussianBlur(raw, (0, 0), blur_sigma_px)
        if noise_sigma > 0:
            if rng is None:
                raise ValueError("noise needs an np.random.Generator (rng)")
            raw = self._add_noise(raw, noise_sigma, rng)
        return raw
