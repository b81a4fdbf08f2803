"""Rigid motions of the plane, SE(2), with first-order covariance propagation.

A pose ``T_a_b = SE2(x, y, yaw)`` is frame b expressed in frame a: b's origin at (x, y) in
a, its x axis turned by yaw. Composition follows the frames, ``T_a_c = T_a_b ∘ T_b_c``
(:meth:`SE2.compose`), and ``T_b_a = T_a_b⁻¹`` (:meth:`SE2.inverse`). Uncertain poses
(:class:`UncertainSE2`) carry a 3 x 3 covariance of (x, y, yaw) and propagate it through
the Jacobians below (the usual first-order rule Σ = J₁ Σ₁ J₁ᵀ + J₂ Σ₂ J₂ᵀ, as for the
transitions of the topological map, docs/design.md §6, thesis §7.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from kernel.angles import wrap_angle


@dataclass(frozen=True)
class SE2:
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0

    def __repr__(self) -> str:  # plain floats, whatever numpy type was passed in
        return f"SE2(x={float(self.x)!r}, y={float(self.y)!r}, yaw={float(self.yaw)!r})"

    def __str__(self) -> str:  # as logs show a pose: metres and degrees
        return (f"x {float(self.x):+.3f} m, y {float(self.y):+.3f} m, "
                f"yaw {math.degrees(float(self.yaw)):+.1f} deg")

    @classmethod
    def of(cls, xyyaw: tuple[float, float, float] | np.ndarray) -> SE2:
        x, y, yaw = (float(v) for v in xyyaw)
        return cls(x, y, float(wrap_angle(yaw)))

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.yaw)

    def compose(self, other: SE2) -> SE2:
        """self ∘ other:  x = x₁ + c₁x₂ − s₁y₂,  y = y₁ + s₁x₂ + c₁y₂,  θ = θ₁ + θ₂."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return SE2(self.x + c * other.x - s * other.y, self.y + s * other.x + c * other.y,
                   float(wrap_angle(self.yaw + other.yaw)))

    def inverse(self) -> SE2:
        """T⁻¹ = (−c x − s y,  s x − c y,  −θ)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return SE2(-c * self.x - s * self.y, s * self.x - c * self.y,
                   float(wrap_angle(-self.yaw)))

    def between(self, other: SE2) -> SE2:
        """self⁻¹ ∘ other: ``other`` seen from ``self`` (both in one frame)."""
        return self.inverse().compose(other)

    def apply(self, px: float | np.ndarray, py: float | np.ndarray
              ) -> tuple[float | np.ndarray, float | np.ndarray]:
        """A point of frame b in frame a."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.x + c * px - s * py, self.y + s * px + c * py

    def compose_jacobians(self, other: SE2) -> tuple[np.ndarray, np.ndarray]:
        """∂(self ∘ other)/∂self and ∂(self ∘ other)/∂other."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        j1 = np.array([[1.0, 0.0, -s * other.x - c * other.y],
                       [0.0, 1.0, c * other.x - s * other.y],
                       [0.0, 0.0, 1.0]])
        j2 = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return j1, j2

    def inverse_jacobian(self) -> np.ndarray:
        """∂(T⁻¹)/∂T."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[-c, -s, s * self.x - c * self.y],
                         [s, -c, c * self.x + s * self.y],
                         [0.0, 0.0, -1.0]])


Poses = tuple[np.ndarray, np.ndarray, np.ndarray]  # x, y, yaw of many poses at once


def compose_many(a: Poses | tuple[float, float, float], b: Poses | tuple[float, float, float]
                 ) -> Poses:
    """a ∘ b pose by pose (:meth:`SE2.compose` over arrays that broadcast; the yaw is
    not wrapped)."""
    ax, ay, at = a
    bx, by, bt = b
    c, s = np.cos(at), np.sin(at)
    return ax + c * bx - s * by, ay + s * bx + c * by, np.add(at, bt)


def turned_covariance(covariance: np.ndarray, yaw: float) -> np.ndarray:
    """A 3 x 3 covariance of (x, y, yaw) expressed in a frame turned by ``yaw``
    (R Σ Rᵀ, R the rotation by yaw about the vertical; the yaw variance is unchanged)."""
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(R @ covariance @ R.T)


# The χ² value with 3 degrees of freedom that 99.9 % of consistent differences stay below.
CHI2_3_DOF_999 = 16.27


def _zeros() -> np.ndarray:
    return np.zeros((3, 3))


@dataclass(frozen=True)
class UncertainSE2:
    """An SE(2) pose with the 3 x 3 covariance of (x, y, yaw)."""

    mean: SE2
    covariance: np.ndarray = field(default_factory=_zeros)

    def __post_init__(self) -> None:
        cov = np.asarray(self.covariance, dtype=float)
        if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
            raise ValueError(f"an SE(2) covariance is a finite 3 x 3 matrix, got {cov.shape}")
        object.__setattr__(self, "covariance", 0.5 * (cov + cov.T))

    def compose(self, other: UncertainSE2) -> UncertainSE2:
        """Independent uncertainties: Σ = J₁ Σ₁ J₁ᵀ + J₂ Σ₂ J₂ᵀ."""
        j1, j2 = self.mean.compose_jacobians(other.mean)
        return UncertainSE2(self.mean.compose(other.mean),
                            j1 @ self.covariance @ j1.T + j2 @ other.covariance @ j2.T)

    def inverse(self) -> UncertainSE2:
        """Σ' = J Σ Jᵀ with J = ∂(T⁻¹)/∂T."""
        j = self.mean.inverse_jacobian()
        return UncertainSE2(self.mean.inverse(), j @ self.covariance @ j.T)

    def fuse(self, other: UncertainSE2) -> UncertainSE2:
        """Two independent estimates of one pose, information-weighted (first order, yaw
        unwrapped next to this one's):  Σ = (Σ₁⁻¹ + Σ₂⁻¹)⁻¹,  x = Σ (Σ₁⁻¹ x₁ + Σ₂⁻¹ x₂)."""
        a = np.array(self.mean.as_tuple())
        b = np.array(other.mean.as_tuple())
        b[2] = a[2] + float(wrap_angle(b[2] - a[2]))
        info_a, info_b = np.linalg.inv(self.covariance), np.linalg.inv(other.covariance)
        cov = np.linalg.inv(info_a + info_b)
        return UncertainSE2(SE2.of(cov @ (info_a @ a + info_b @ b)), cov)

    def agrees_with(self, other: UncertainSE2, chi2: float = CHI2_3_DOF_999) -> bool:
        """Whether two independent estimates of one pose can be the same pose: their
        difference within the ``chi2`` gate of Σ₁ + Σ₂ (default: 99.9 %, 3 dof)."""
        both = UncertainSE2(self.mean, self.covariance + other.covariance)
        return both.mahalanobis2(other.mean) <= chi2

    def mahalanobis2(self, truth: SE2) -> float:
        """Squared Mahalanobis distance of ``truth`` from this estimate (yaw wrapped)."""
        e = np.array([truth.x - self.mean.x, truth.y - self.mean.y,
                      float(wrap_angle(truth.yaw - self.mean.yaw))])
        return float(e @ np.linalg.solve(self.covariance, e))
