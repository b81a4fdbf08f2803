"""Floor detection and local space profiles (daemon/vision/floor.py, local_space.py) on
crafted panoramas: a textured floor reaching a known row in every column, a wall above."""

from __future__ import annotations

import numpy as np
import pytest

from daemon.vision.floor import ColourModel, FloorGrid, gradient_floor
from daemon.vision.local_space import local_space_set, match, match_many, profile

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
    grey = _scene(rng, b).mean(axis=2)
    assert np.array_equal(gradient_floor(grey, HORIZON, 18.0), _truth(b))
    flat = np.full((H, W), 100.0)  # no step below the horizon: no floor (thesis §5.1.2)
    assert not gradient_floor(flat, HORIZON, 18.0).any()
    step = np.where(np.arange(H)[:, None] >= 20, 100.0, 30.0) * np.ones((1, W))
    assert not gradient_floor(step, HORIZON, 18.0).any()  # a step above the horizon


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
    assert list(local_space_set(here, profiles, float(H), 0.01)) == [1]
    with pytest.raises(ValueError, match="cannot be cut"):
        profile(np.zeros((H, 100), bool))
