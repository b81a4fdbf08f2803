"""SE(2) and its covariance propagation (kernel/se2.py) against numbers and sampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kernel.se2 import SE2, UncertainSE2


def test_compose_and_inverse_by_hand() -> None:
    a = SE2(1.0, 2.0, math.pi / 2)
    b = SE2(0.5, 0.0, math.pi / 2)
    ab = a.compose(b)
    assert ab.as_tuple() == pytest.approx((1.0, 2.5, math.pi))
    identity = a.compose(a.inverse())
    assert identity.as_tuple() == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert a.between(ab).as_tuple() == pytest.approx(b.as_tuple())


@pytest.mark.parametrize("which", ["compose1", "compose2", "inverse"])
def test_jacobians_match_finite_differences(which: str) -> None:
    rng = np.random.default_rng(4)
    a = SE2.of(rng.normal(size=3))
    b = SE2.of(rng.normal(size=3))

    def f(v: np.ndarray) -> np.ndarray:
        p = SE2(*v)
        out = {"compose1": lambda: p.compose(b), "compose2": lambda: a.compose(p),
               "inverse": lambda: p.inverse()}[which]()
        return np.array(out.as_tuple())

    point = np.array((b if which == "compose2" else a).as_tuple())
    numeric = np.zeros((3, 3))
    for k in range(3):
        h = np.zeros(3)
        h[k] = 1e-6
        d = f(point + h) - f(point - h)
        d[2] = math.remainder(d[2], 2 * math.pi)
        numeric[:, k] = d / 2e-6
    j1, j2 = a.compose_jacobians(b)
    analytic = {"compose1": j1, "compose2": j2, "inverse": a.inverse_jacobian()}[which]
    np.testing.assert_allclose(analytic, numeric, atol=1e-6)


def test_propagated_covariance_matches_monte_carlo() -> None:
    rng = np.random.default_rng(7)
    a = UncertainSE2(SE2(1.0, -0.5, 0.3), np.diag([0.01, 0.02, 0.001]))
    b = UncertainSE2(SE2(2.0, 1.0, -0.7), np.diag([0.005, 0.001, 0.002]))
    predicted = a.compose(b).inverse()
    samples = []
    for _ in range(20000):
        pa = SE2.of(np.array(a.mean.as_tuple()) + rng.multivariate_normal(np.zeros(3),
                                                                          a.covariance))
        pb = SE2.of(np.array(b.mean.as_tuple()) + rng.multivariate_normal(np.zeros(3),
                                                                          b.covariance))
        samples.append(pa.compose(pb).inverse().as_tuple())
    empirical = np.cov(np.array(samples).T)
    np.testing.assert_allclose(predicted.covariance, empirical, rtol=0.1, atol=2e-4)


def test_covariance_must_be_3x3_and_finite() -> None:
    with pytest.raises(ValueError, match="3 x 3"):
        UncertainSE2(SE2(), np.eye(2))
    with pytest.raises(ValueError, match="finite"):
        UncertainSE2(SE2(), np.full((3, 3), np.nan))
