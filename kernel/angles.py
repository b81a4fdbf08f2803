"""Angles: radians, wrapped to (-pi, pi] (SI units in code and on the wire; degrees only
where a person reads or types them)."""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi


def wrap_angle(a: float | np.ndarray) -> float | np.ndarray:
    """Wrap to (-pi, pi]."""
    w = np.mod(np.asarray(a) + math.pi, TWO_PI) - math.pi
    w = np.where(w == -math.pi, math.pi, w)
    return float(w) if np.ndim(w) == 0 else w
