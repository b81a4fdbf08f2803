"""The simulated robot with another camera model (``placecell-eval ... --camera-model M``;
docs/design.md §2): the same world and robot, rendered through M and unwarped through
M, so every experiment runs on any camera the daemon supports.

Each model's simulated camera is a plausible one of its kind: ``ocamcalib`` is the
default mirror as OCamCalib would have calibrated it (:func:`ocamcalib_of_mirror`),
``fisheye`` an upward equidistant 220° lens with the panorama's band set within its
view (from -18°, as its user would set it), ``equirectangular`` and ``dual-fisheye``
a consumer 360° camera's 1280 x 640 frames.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from daemon.config import PlacecellConfig
from kernel.camera_models import MODEL_NAMES
from kernel.mirror import MirrorModel
from kernel.sensor_settings import MirrorSettings, OcamcalibSettings, PanoramaSettings

__all__ = ["MODEL_NAMES", "ocamcalib_of_mirror", "with_camera_model"]

FISHEYE_BAND_BOTTOM_DEG = -18.0
# The simulated camera's frame size for each model (width, height).
SIM_IMAGE_SIZE = {"mirror": (640, 480), "ocamcalib": (640, 480), "fisheye": (640, 480),
                  "equirectangular": (1280, 640), "dual-fisheye": (1280, 640)}


def with_camera_model(cfg: PlacecellConfig, name: str) -> PlacecellConfig:
    """``cfg`` with its simulated camera and the daemon's camera model set to ``name``."""
    model = next((m for m in MODEL_NAMES if m == name), None)
    if model is None:
        raise ValueError(f"camera model {name!r} is not one of {', '.join(MODEL_NAMES)}")
    camera = cfg.camera
    if model == "ocamcalib":
        camera = dataclasses.replace(camera, ocamcalib=ocamcalib_of_mirror(cfg.mirror,
                                                                           cfg.panorama))
    width, height = SIM_IMAGE_SIZE[model]
    sim = dataclasses.replace(camera.sim, image_width=width, image_height=height)
    panorama = cfg.panorama
    if model == "fisheye":  # the band within what a 220° lens sees (down to -20°)
        panorama = dataclasses.replace(panorama, elevation_bottom_deg=FISHEYE_BAND_BOTTOM_DEG)
    return dataclasses.replace(cfg, camera=dataclasses.replace(camera, model=model, sim=sim),
                               panorama=panorama)


def ocamcalib_of_mirror(mirror: MirrorSettings, panorama: PanoramaSettings,
                        degree: int = 4, inverse_degree: int = 10) -> OcamcalibSettings:
    """The mirror camera as OCamCalib's calibration would describe it: cam2world z = pol(ρ)
    (a1 = 0, as OCamCalib fits it) and world2cam ρ = invpol(θ), fitted by least squares
    to the mirror's elevation of each radius between its rims (kernel/mirror.py)."""
    model = MirrorModel(mirror, panorama)
    rho = np.linspace(mirror.r_inner_px, mirror.r_outer_px, 400)
    phi = model.elevation_of_radius(rho)
    ok = np.isfinite(phi)
    rho, phi = rho[ok], phi[ok]
    z = rho * np.tan(phi)  # the catadioptric's ray (x, y, z): elevation atan2(z, ρ)
    powers = [k for k in range(degree + 1) if k != 1]
    coeffs, *_ = np.linalg.lstsq(np.stack([rho**k for k in powers], axis=1), z, rcond=None)
    pol = np.zeros(degree + 1)
    pol[powers] = coeffs
    invpol = np.polynomial.polynomial.polyfit(phi, rho, inverse_degree)
    return OcamcalibSettings(
        lens="catadioptric", pol=[float(c) for c in pol], invpol=[float(c) for c in invpol],
        center_row_px=mirror.center_y_px, center_col_px=mirror.center_x_px,
        affine=[1.0, 0.0, 0.0], image_height_px=480, image_width_px=640,
        min_radius_px=mirror.r_inner_px, max_radius_px=mirror.r_outer_px,
        mirrored=mirror.mirrored, bearing_offset_rad=mirror.bearing_offset_rad)
