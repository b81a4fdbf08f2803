"""Floor detection and local space profiles (daemon/vision/floor.py, local_space.py) on
crafted panoramas: a textured floor reaching a known row in every column, a wall above."""

from __future__ import annotations

import json

import numpy as np
import pytest

from daemon.localisation.global_localisation import near_best
from daemon.vision.floor import ColourModel, FloorGrid, gradient_floor, texture_threshold
from daemon.vision.local_space import LocalSpace, match, match_many, profile, profile_m
from tools.eval.cli import main as eval_main

H, W, HORIZON = 120, 720, 43
FLOOR_BGR = (60, 90, 150)  # brownish
WALL_BGR = (170, 160, 150)  # grey-blue


def _boundary(shift: int = 0) -> np.ndarray:
    """The top floor row of each column: 70-110, varying along azimuth."""
    c = np.arange(W)
    return np.roll((90 + 20 * np.sin(2 * np.pi * c / W * 3)).astype(int), shift)


def _scene(rng: np.random.Generator, boundary: np.ndarray, gain: float = 1.0) -> np.ndarray:
    rows = np.arange(H)[:, None]
    floor = rows >= boundary[None, :]
    img = np.where(floor[..., None], np.array(FLOOR_BGR, float), np.array(WALL_BGR, float))
    img = img + rng.normal(0.0, 3.0, img.shape)  # texture well below the boundary's step
    return np.clip(img * gain, 0, 255).astype(np.uint8)


def _truth(boundary: np.ndarray) -> np.ndarray:
    return np.arange(H)[:, None] >= boundary[None, :]


def test_the_colour_model_tells_floor_from_wall_under_any_light() -> None:
    rng = np.random.default_rng(0)
    b = _boundary()
    img = _scene(rng, b)
    model = ColourModel.learn(img[112:, :])  # the region right in front of the robot
    truth = _truth(b)
    for gain in (0.5, 1.0, 1.5):
        lik = model.likelihood(_scene(rng, b, gain))
        assert lik[truth].mean() > 0.5 and lik[~truth].mean() < 0.05, gain
    with pytest.raises(ValueError, match="at least one sample"):
        ColourModel.learn(np.zeros((0, 3), np.uint8))


def test_the_gradient_boundary_is_found_and_nothing_above_the_horizon_is_floor() -> None:
    rng = np.random.default_rng(1)
    b = _boundary()
    for gain in (0.5, 1.0, 1.5):  # on the log intensity: the light changes nothing
        grey = _scene(rng, b, gain).mean(axis=2)
        assert np.mean(gradient_floor(grey, HORIZON, 0.2) == _truth(b)) > 0.999, gain
    flat = np.full((H, W), 100.0)  # no step below the horizon: no floor (thesis §5.1.2)
    assert not gradient_floor(flat, HORIZON, 0.2).any()
    step = np.where(np.arange(H)[:, None] >= 20, 100.0, 30.0) * np.ones((1, W))
    assert not gradient_floor(step, HORIZON, 0.2).any()  # a step above the horizon


def test_a_patterned_carpet_is_no_boundary_once_its_texture_is_learned() -> None:
    """Dark stripes across the carpet (a motif) stop a fixed threshold short; the
    threshold learned from the floor in front of the robot passes them."""
    rng = np.random.default_rng(3)
    b = _boundary()
    img = _scene(rng, b).astype(float)
    motif = (np.arange(H) % 8 < 2)[:, None] & _truth(b)  # every 8th row pair 25 % darker
    img[motif] *= 0.75
    grey = np.clip(img, 0, 255).astype(np.uint8).mean(axis=2)
    assert np.mean(gradient_floor(grey, HORIZON, 0.12) == _truth(b)) < 0.95
    learned = texture_threshold(grey[111:, :])  # the bottom rows: floor everywhere
    assert 0.12 < learned < 0.4, learned
    assert np.mean(gradient_floor(grey, HORIZON, learned) == _truth(b)) > 0.99
    with pytest.raises(ValueError, match="more than 6 rows"):
        texture_threshold(grey[-5:, :])


def test_a_person_walking_past_does_not_rewrite_the_grid_a_lasting_change_does() -> None:
    rng = np.random.default_rng(2)
    b = _boundary()
    model = ColourModel.learn(_scene(rng, b)[112:, :])
    grid = FloorGrid((H, W), HORIZON)
    for _ in range(5):
        grid.update(_scene(rng, b), model)
    assert np.mean(grid.mask() == _truth(b)) > 0.99
    person = _scene(rng, b)
    person[50:118, 300:330] = (70, 60, 140)  # in front of the floor for two frames
    for _ in range(2):
        grid.update(person, model)
    patch = (slice(50, H), slice(300, 330))  # the grid there still shows the floor
    assert np.mean(grid.mask()[patch] == _truth(b)[patch]) > 0.99
    moved = b.copy()
    moved[300:330] = 117  # the robot moved: that direction's floor is now short
    for _ in range(12):
        grid.update(_scene(rng, moved), model)
    assert np.mean(grid.mask() == _truth(moved)) > 0.99


def test_a_floor_the_camera_does_not_see_is_not_learned_and_a_plain_one_is() -> None:
    """An upward fisheye sees nothing at the panorama's bottom rows (black): no floor is
    learned from them and the frames go on (a floor learned from black had a zero
    threshold and stopped the localiser); a floor without texture gets a positive one."""
    space = LocalSpace((120, 720), 45, np.linspace(5.0, 0.5, 120))
    unseen = np.full((120, 720, 3), 120, np.uint8)
    unseen[90:] = 0
    space.update(unseen)
    assert space.floor is None
    plain = np.full((120, 720, 3), 120, np.uint8)
    space.update(plain)
    assert space.floor is not None and space.floor.gradient_threshold > 0
    assert texture_threshold(np.full((12, 40), 90, np.uint8)) > 0


def test_profiles_match_turned_views_and_tell_other_spots_apart() -> None:
    b = _boundary()
    here = profile(_truth(b))
    assert here.shape == (16,)
    assert here[0] == pytest.approx(np.mean(H - b[:45]))
    turned = profile(_truth(_boundary(shift=3 * 45)))  # 3 bins round
    assert match(here, turned, float(H)) == pytest.approx(1.0)
    elsewhere = profile(_truth(np.full(W, 100)))
    assert match(here, elsewhere, float(H)) < 0.95
    profiles = np.stack([elsewhere, turned, profile(_truth(np.full(W, 60)))])
    assert np.argmax(match_many(here, profiles, float(H))) == 1
    matches = dict(enumerate(match_many(here, profiles, float(H)).tolist()))
    assert near_best(matches, 0.01) == {1}
    with pytest.raises(ValueError, match="cannot be cut"):
        profile(np.zeros((H, 100), bool))


def test_profiles_in_metres_read_the_farthest_floor_row_capped() -> None:
    rows = np.arange(H)
    with np.errstate(divide="ignore"):
        distance = np.where(rows > HORIZON, 100.0 / (rows - HORIZON), np.inf)
    near = profile_m(_truth(np.full(W, 90)), distance)  # floor up to row 90: 100/47 m
    assert near == pytest.approx(np.full(16, 100.0 / 47))
    assert profile_m(_truth(np.full(W, HORIZON + 2)), distance) == pytest.approx(
        np.full(16, 5.0))  # 50 m seen, capped at 5 m
    assert not profile_m(np.zeros((H, W), bool), distance).any()  # no floor: 0 m
    b = _boundary()
    here, turned = (profile_m(_truth(x), distance) for x in (b, _boundary(shift=2 * 45)))
    assert match(here, turned, 5.0) == pytest.approx(1.0)
    assert match(here, near, 5.0) < 0.95


def test_the_floor_experiment_on_two_hard_floors(capsys: pytest.CaptureFixture[str]) -> None:
    """A small ``placecell-eval floor`` (design §4): on a patterned carpet and on glossy
    tiles, with shadows, in the office, the fused grid beats both methods alone; a
    person walking past hardly moves the local space profile, a 1 m move does."""
    assert eval_main(["floor", "--poses", "2", "--floors", "carpet,glossy-tiles",
                      "--json"]) == 0
    m = json.loads(capsys.readouterr().out)["metrics"]
    for after in (1, 5):
        fused = m[f"mae_fused_{after}"]
        assert fused < m[f"mae_colour_{after}"] and fused < m[f"mae_gradient_{after}"], m
    assert m["mae_fused_5"] < 0.15, m
    assert m["person_match_change_max"] < 0.1 < m["move_1m_match_change_median"], m
    # Seeded: every 1 m move changes the profile by more than 0.1, with the true floor too.
    assert m["move_1m_over_0p1"] == 1.0 and m["move_1m_over_0p1_true_floor"] == 1.0, m
    assert set(m["by_floor"]) == {"carpet", "glossy-tiles"}
