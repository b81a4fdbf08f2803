"""Visual landmark pieces (issue 5, point 5): valley measure, sector balance, NCC
invariance, seam crossing, EKF convergence and honesty on synthetic bearings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daemon.vision.depth_ekf import (
    BearingOnlyEKF,
    camera_increment_jacobian,
    observation_variance,
)
from daemon.vision.landmarks import TEMPLATE, centre_bearing
from daemon.vision.ncc import PreparedImage, ncc, ncc_map, ncc_under_light, subpixel_peak
from daemon.vision.recognition import (
    FastMatcher,
    PreparedPanorama,
    PreparedTemplates,
    best_ncc_bruteforce,
    best_ncc_elsewhere,
)
from daemon.vision.selection import select_static, valley_measure
from daemon.vision.tracking import predict_column, track
from kernel.panorama import add_wrap_margin
from kernel.se2 import SE2, compose_many


def _textured(shape: tuple[int, int], seed: int, smooth: int = 3) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, shape).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), smooth / 2)
    img = (img - img.min()) / (img.max() - img.min()) * 255
    return img.astype(np.uint8)


def test_valley_measure_prefers_distinctive_texture() -> None:
    # Left half: a unique blob on flat grey; right half: a periodic stripe pattern
    # (its SAD valley is shallow: the pattern matches itself one period away).
    img = np.full((64, 128), 120, np.uint8)
    img[20:36, 20:36] = _textured((16, 16), 1, smooth=1)
    img[:, 64:] = np.where((np.arange(64) // 2) % 2 == 0, 60, 190).astype(np.uint8)[None, :]
    noisy = np.clip(img.astype(int) + np.random.default_rng(2).integers(-2, 3, img.shape),
                    0, 255).astype(np.uint8)
    r, _ = valley_measure(img, noisy)
    assert r[20, 20] > 0.9  # the blob's self match is a deep, steep valley
    assert r[20, 90] < 0.2  # stripes two pixels apart match themselves at distance 2
    assert r[20, 90] < r[20, 20]


def test_static_selection_is_sector_balanced_and_non_overlapping() -> None:
    W, margin = 720, 16
    core = _textured((120, W), 3)
    core[:, 180:540] //= 3  # most contrast in front and behind...
    core[:, 180:540] += 80  # ...but every sector must still give 8
    noisy = np.clip(core.astype(int) + np.random.default_rng(4).integers(-2, 3, core.shape),
                    0, 255).astype(np.uint8)
    sel = select_static(add_wrap_margin(core, margin), add_wrap_margin(noisy, margin), margin)
    assert len(sel.landmarks) == 32
    sectors = [int(((lm.bearing + math.pi / 4) % (2 * math.pi)) // (math.pi / 2))
               for lm in sel.landmarks]
    assert [sectors.count(s) for s in range(4)] == [8, 8, 8, 8]
    for a in sel.landmarks:
        for b in sel.landmarks:
            if a is not b:
                dc = min(abs(a.col - b.col), W - abs(a.col - b.col))
                assert abs(a.row - b.row) >= TEMPLATE or dc >= TEMPLATE
    for lm in sel.landmarks:  # templates are the panorama's pixels at their place
        assert np.array_equal(lm.template, add_wrap_margin(core, TEMPLATE)[
            lm.row:lm.row + TEMPLATE, lm.col + TEMPLATE:lm.col + 2 * TEMPLATE])


def test_flat_regions_are_never_selected() -> None:
    core = np.full((120, 720), 128, np.uint8)
    core[40:80, 100:140] = _textured((40, 40), 5)
    sel = select_static(core, core, 0, min_texture=6.0)
    assert sel.landmarks
    # every template overlaps the textured patch
    assert all(24 < lm.row < 80 and 84 < lm.col < 140 for lm in sel.landmarks)


def test_ncc_is_invariant_to_gain_and_offset() -> None:
    a = _textured((16, 16), 6).astype(float)
    assert ncc(a, 0.5 * a + 40) == pytest.approx(1.0)
    assert ncc(a, 1.5 * a - 20) == pytest.approx(1.0)
    img = _textured((60, 200), 7)
    tpl = img[20:36, 50:66]
    brighter = np.clip(img.astype(float) * 1.3 + 10, 0, 255).astype(np.uint8)
    score, x, y = subpixel_peak(ncc_map(brighter, tpl))
    assert score > 0.97 and abs(x - 50) < 0.5 and abs(y - 20) < 0.5


def test_tracking_across_the_seam() -> None:
    W, margin = 720, 16
    core = _textured((120, W), 8)
    tpl = add_wrap_margin(core, TEMPLATE)[50:66, 712 + TEMPLATE: 728 + TEMPLATE]  # crosses
    rotated = np.roll(core, 5, axis=1)  # the robot turned: everything moved 5 columns
    t = track(add_wrap_margin(rotated, margin), margin, tpl[None], np.array([712.0]),
              np.array([50.0]))
    assert t.scores[0] > 0.99
    assert abs(t.cols[0] - (717 % W)) < 0.3 and abs(t.rows[0] - 50) < 0.3
    # and a prediction that itself wraps
    t2 = track(add_wrap_margin(rotated, margin), margin, tpl[None], np.array([-3.0]),
               np.array([50.0]))
    assert abs(t2.cols[0] - 717) < 0.3


def test_prediction_follows_the_observation_model() -> None:
    W = 720
    col = predict_column(math.pi / 2, 1.0, (0.0, 0.0, 0.0), W)
    assert centre_bearing(col, W) == pytest.approx(math.pi / 2, abs=1e-9)
    col = predict_column(math.pi / 2, 1.0, (1.0, 0.0, 0.0), W)  # moved 1 m forward
    assert centre_bearing(col, W) == pytest.approx(3 * math.pi / 4, abs=1e-9)


CROSS = [(0.5, 0.0), (0.0, 0.0), (-0.5, 0.0), (0.0, 0.0), (0.0, 0.5), (0.0, 0.0),
         (0.0, -0.5), (0.0, 0.0)]


def _run_tbl(rng: np.random.Generator, depths: np.ndarray, bearings: np.ndarray,
             score: float = 0.95) -> BearingOnlyEKF:
    L = np.c_[depths * np.cos(bearings), depths * np.sin(bearings)]
    ekf = BearingOnlyEKF(bearings + rng.normal(0, math.radians(1), len(depths)))
    pose = np.zeros(2)
    prev = np.zeros(2)
    for target in CROSS:
        for k in range(1, 26):  # 0.5 m at 0.2 m/s, 10 frames/s
            p = prev + (np.array(target) - prev) * k / 25
            step, pose = p - pose, p
            # odometry noise as the filter models it: 1 % of the distance, and a heading
            # error of 0.002 rad per metre
            dist = float(np.hypot(*step))
            ekf.predict(step[0] + rng.normal(0, 0.01 * dist),
                        step[1] + rng.normal(0, 0.01 * dist), rng.normal(0, 0.002 * dist))
            sigma = math.sqrt(observation_variance(score))
            for i, (lx, ly) in enumerate(L):
                ekf.update(i, math.atan2(ly - p[1], lx - p[0]) + rng.normal(0, sigma), score)
        prev = np.array(target, float)
    return ekf


def test_ekf_converges_on_near_landmarks() -> None:
    rng = np.random.default_rng(9)
    depths = np.array([0.7, 0.7, 1.0, 1.2, 0.8, 0.9])
    bearings = np.array([1.57, -1.57, 0.3, 2.5, -2.0, -0.7])
    ekf = _run_tbl(rng, depths, bearings, score=0.98)
    for i, d in enumerate(depths):
        est = ekf.estimate(i)
        assert abs(est.depth - d) < 0.1
        assert abs(math.remainder(est.bearing - bearings[i], 2 * math.pi)) < math.radians(2)
    assert np.hypot(*ekf.pose[:2]) < 0.05  # back at the reference


def test_ekf_covariance_is_honest() -> None:
    """The true (d, γ) lies inside the 2-sigma ellipse (Mahalanobis <= 2) about as often as
    for a Gaussian (0.86), over many landmarks at 0.6-5 m."""
    rng = np.random.default_rng(10)
    inside = []
    for _ in range(40):
        depths = rng.uniform(0.6, 5.0, 8)
        bearings = rng.uniform(-math.pi, math.pi, 8)
        ekf = _run_tbl(rng, depths, bearings)
        for i in range(8):
            e = ekf.estimate(i)
            diff = np.array([e.depth - depths[i],
                             math.remainder(e.bearing - bearings[i], 2 * math.pi)])
            inside.append(float(diff @ np.linalg.solve(e.covariance, diff)) <= 4.0)
    assert 0.80 <= np.mean(inside) <= 0.97


def test_zoomed_observations_count_for_less() -> None:
    """R = s σ²(c) + (k ln z)²: a landmark seen larger than in the reference (its template
    slides) informs less; at the reference scale the zoom term vanishes."""
    def after(zoom_noise: float, log_zoom: float) -> BearingOnlyEKF:
        ekf = BearingOnlyEKF(np.array([1.0]), observation_variance_scale=0.015,
                             zoom_noise_rad=zoom_noise)
        ekf.predict(0.3, 0.0, 0.0)
        ekf.update(0, 1.2, 0.95, log_zoom)
        return ekf
    plain, unzoomed, zoomed = after(0.0, 0.0), after(0.7, 0.0), after(0.7, 0.3)
    assert np.array_equal(plain.P, unzoomed.P) and np.array_equal(plain.x, unzoomed.x)
    var = [e.estimate(0).inverse_depth_var for e in (unzoomed, zoomed)]
    assert var[1] > 1.5 * var[0]
    # The update's gain shrinks as R grows by (0.7 * 0.3)²: the state moves less.
    assert abs(zoomed.x[3] - 0.4) < abs(unzoomed.x[3] - 0.4)


def test_camera_increment_jacobian_matches_finite_differences() -> None:
    mount = (0.15, 0.03, 0.4)
    m = SE2(*mount)

    def camera(robot: np.ndarray) -> np.ndarray:
        return np.array(m.inverse().compose(SE2(*robot)).compose(m).as_tuple())

    for robot in (np.array([0.02, -0.01, 0.3]), np.array([0.0, 0.0, -1.2])):
        numeric = np.zeros((3, 3))
        for k in range(3):
            step = np.zeros(3)
            step[k] = 1e-6
            numeric[:, k] = (camera(robot + step) - camera(robot - step)) / 2e-6
        assert np.allclose(camera_increment_jacobian(float(robot[2]), mount), numeric,
                           atol=1e-8)


def test_a_mounted_cameras_turn_carries_the_wheels_noise_through_the_lever_arm() -> None:
    """A turn in place with the camera 0.15 m ahead: the camera's pose covariance the EKF
    predicts is the one the robot's noisy turn gives the camera (sampled), with its
    position tied to its heading; the robot-frame noise taken at the camera (no mount
    given) puts the spread along the arc's chord instead of across the lever arm."""
    mount = (0.15, 0.0, 0.0)
    m = SE2(*mount)
    steps, turn = 30, math.pi / 2
    camera_step = m.inverse().compose(SE2(0.0, 0.0, turn / steps)).compose(m).as_tuple()
    mounted, naive = (BearingOnlyEKF(np.array([1.0])) for _ in range(2))
    for _ in range(steps):
        mounted.predict(*camera_step, mount=mount)
        naive.predict(*camera_step)
    rng = np.random.default_rng(5)
    n = 20000
    robot = (np.zeros(n), np.zeros(n), np.zeros(n))
    for _ in range(steps):  # the robot's noisy increments, as the EKF's noise model says
        dtheta = turn / steps + rng.normal(0.0, mounted.rotation_noise * turn / steps, n)
        robot = compose_many(robot, (np.full(n, 0.0), np.full(n, 0.0), dtheta))
    cameras = compose_many(compose_many(m.inverse().as_tuple(), robot), mount)
    sampled = np.cov(np.stack(cameras))
    predicted = mounted.P[:3, :3]
    assert np.allclose(np.diag(predicted), np.diag(sampled), rtol=0.15, atol=1e-8)
    correlation = predicted[0, 2] / math.sqrt(predicted[0, 0] * predicted[2, 2])
    sampled_correlation = sampled[0, 2] / math.sqrt(sampled[0, 0] * sampled[2, 2])
    assert correlation == pytest.approx(sampled_correlation, abs=0.1)
    assert abs(correlation) > 0.9
    assert naive.P[0, 0] < 0.3 * sampled[0, 0]  # across the lever arm (it points +y)
    assert naive.P[1, 1] > 100 * sampled[1, 1]  # along it


def test_far_landmarks_stay_uncertain() -> None:
    rng = np.random.default_rng(11)
    ekf = _run_tbl(rng, np.array([12.0]), np.array([0.8]))
    e = ekf.estimate(0)
    assert math.sqrt(e.covariance[0, 0]) > 2.0  # little information beyond 6-7x the extent


def test_fast_recognition_agrees_with_bruteforce() -> None:
    pano = _textured((120, 752), 12)
    templates = np.stack([pano[r:r + 16, c:c + 16] for r, c in
                          [(10, 40), (50, 300), (90, 600), (30, 700), (70, 100)]])
    shifted = np.roll(pano, 7, axis=1)
    shifted[40:56] = np.roll(shifted[40:56], 3, axis=0)
    brute = best_ncc_bruteforce(shifted, templates)
    fast = FastMatcher().best_ncc(PreparedPanorama.of(shifted), PreparedTemplates.of(templates))
    assert np.allclose(brute, fast, atol=1e-4)
    assert brute[[0, 2, 4]].min() > 0.99  # templates that moved only sideways are found
    assert 0.5 < brute[1] < 0.9  # the one whose rows were cut apart is found worse


def test_fast_recognition_of_another_place_never_overestimates() -> None:
    # Templates of another place: their best NCC is some mediocre window anywhere, the
    # case where coarse to fine can miss the best peak; it may fall short, never exceed.
    pano = _textured((120, 752), 21)
    other = _textured((120, 752), 22)
    rng = np.random.default_rng(5)
    corners = zip(rng.integers(0, 104, 32), rng.integers(0, 736, 32), strict=True)
    templates = np.stack([other[r:r + 16, c:c + 16] for r, c in corners])
    templates[0] = 77  # a flat template matches nothing
    brute = best_ncc_bruteforce(pano, templates)
    fast = FastMatcher().best_ncc(PreparedPanorama.of(pano), PreparedTemplates.of(templates))
    assert fast[0] == 0.0  # (OpenCV's normalised matchTemplate says 1.0 for a flat one)
    brute, fast = brute[1:], fast[1:]
    assert np.all(fast <= brute + 1e-4)
    assert abs(fast.mean() - brute.mean()) < 0.02  # the LRP agrees
    assert np.median(brute - fast) < 1e-4  # most maxima are found exactly


def test_exact_ncc_block_matches_opencv() -> None:
    # The climb's compiled 3 x 3 block must give OpenCV's NCC wherever it is placed,
    # up to the last window of the panorama.
    from daemon.vision.ncc import FLAT_RMS
    from daemon.vision.recognition import _block

    pano = _textured((120, 752), 31)
    prepared = PreparedPanorama.of(pano)
    template = PreparedTemplates.of(pano[60:76, 200:216][None])
    reference = ncc_map(pano, pano[60:76, 200:216])
    acc = np.empty((3, 3), np.float32)
    h, w = prepared.window_norm.shape
    for r0, c0 in [(59, 199), (0, 0), (h - 3, w - 3), (17, 401)]:
        _block(prepared.image.ravel(), pano.shape[1], prepared.window_norm,
               template.zero_mean[0].ravel(), float(template.norms[0]), r0, c0,
               FLAT_RMS * TEMPLATE, TEMPLATE, acc)
        assert np.allclose(acc, reference[r0:r0 + 3, c0:c0 + 3], atol=1e-4)
    assert acc.max() < 0.9 and reference[60, 200] > 0.999  # not a trivially equal map


def test_best_look_alike_elsewhere_leaves_out_the_landmark_itself() -> None:
    """A template pasted twice (once across the seam) has a look-alike of NCC 1 there; a
    unique one's best look-alike is poor; windows overlapping the landmark never count."""
    margin = 16
    core = _textured((120, 720), 21)
    twin = core[40:56, 100:116].copy()
    core[70:86, 712:720], core[70:86, 0:8] = twin[:, :8], twin[:, 8:]  # across the seam
    pano = add_wrap_margin(core, margin)
    templates = np.stack([twin, core[10:26, 400:416]])
    elsewhere = best_ncc_elsewhere(pano, margin, templates, np.array([100, 400]),
                                   np.array([40, 10]))
    assert elsewhere[0] == pytest.approx(1.0, abs=1e-4)  # its twin, found across the seam
    assert elsewhere[1] < 0.8  # unique: its own spot (NCC 1) left out
    # The twin's own spot is left out too: looked for from there, the original is found.
    assert best_ncc_elsewhere(pano, margin, templates[:1], np.array([712]),
                              np.array([70]))[0] == pytest.approx(1.0, abs=1e-4)
    # Left out is exactly what overlaps: from 15 px away the original still overlaps the
    # spot, from 16 px it no longer does.
    def from_(col: int, row: int) -> float:
        return float(best_ncc_elsewhere(pano, margin, templates[1:], np.array([col]),
                                        np.array([row]))[0])
    assert from_(400 - 15, 10 + 15) < 0.99
    assert from_(400 - 16, 10 + 15) == pytest.approx(1.0, abs=1e-4)
    assert from_(400 - 15, 10 + 16) == pytest.approx(1.0, abs=1e-4)


def test_light_that_saturates_a_template_takes_its_pattern() -> None:
    rng = np.random.default_rng(22)
    pattern = rng.uniform(0.0, 1.0, (16, 16))
    dark = (20 + 100 * pattern).astype(np.uint8)  # 20..120: x1.5 stays below 255
    bright = (175 + 75 * pattern).astype(np.uint8)  # 175..250: x1.5 clips every pixel
    assert ncc_under_light(dark, (0.5, 1.5)) > 0.99
    assert ncc_under_light(bright, (0.5,)) > 0.99  # dimmer: nothing clips
    assert ncc_under_light(bright, (0.5, 1.5)) < 0.5


def test_a_prepared_image_gives_opencvs_best_ncc_flat_parts_and_templates_included() -> None:
    """PreparedImage.best_ncc (the feature search's, design §5) is the maximum of
    ncc_map (TM_CCOEFF_NORMED) to float rounding, whatever the template's size."""
    import cv2

    rng = np.random.default_rng(11)
    worst = 0.0
    for k in range(20):
        image = cv2.GaussianBlur(rng.integers(0, 256, (120, 752)).astype(np.uint8), (5, 5),
                                 1.0 + k % 3)
        image[:, 300:340] = 77  # a flat part: its windows match nothing
        prepared = PreparedImage(image)
        for size in (16, 24, 32):
            r, c = int(rng.integers(0, 120 - size)), int(rng.integers(0, 752 - size))
            template = np.ascontiguousarray(image[r:r + size, c:c + size]) if k % 2 else \
                rng.integers(0, 256, (size, size)).astype(np.uint8)
            worst = max(worst, abs(prepared.best_ncc(template)
                                   - float(ncc_map(image, template).max())))
    assert worst < 1e-4
    assert prepared.best_ncc(np.full((16, 16), 9, np.uint8)) == 1.0  # OpenCV's flat rule


def test_the_ncc_near_a_coarse_peak_is_one_the_template_has_and_finds_a_cut_patch() -> None:
    """PreparedImage.ncc_near_coarse_peak (the feature search's pruning, design §5) is an
    NCC the template has somewhere in the image, so never above best_ncc; a patch cut from
    the image is found where it was cut (NCC 1)."""
    import cv2

    rng = np.random.default_rng(12)
    found, above = 0, 0.0
    for k in range(20):
        image = cv2.GaussianBlur(rng.integers(0, 256, (120, 752)).astype(np.uint8), (5, 5),
                                 1.0 + k % 3)
        prepared = PreparedImage(image)
        for size in (16, 24, 32):
            r, c = int(rng.integers(0, 120 - size)), int(rng.integers(0, 752 - size))
            cut = np.ascontiguousarray(image[r:r + size, c:c + size])
            other = rng.integers(0, 256, (size, size)).astype(np.uint8)
            for template in (cut, other):
                above = max(above, prepared.ncc_near_coarse_peak(template)
                            - prepared.best_ncc(template))
            found += prepared.ncc_near_coarse_peak(cut) > 0.9999
    assert above < 1e-5
    assert found == 60
    assert prepared.ncc_near_coarse_peak(np.full((16, 16), 9, np.uint8)) == 1.0
