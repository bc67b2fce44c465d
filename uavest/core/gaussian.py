"""Immutable Gaussian state ``Gaussian(x, P)``.

``x`` is the state on its space (ambient size), ``P`` the covariance of the tangent-space
error (n x n). Filters never mutate a Gaussian; they return new ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True, slots=True)
class Gaussian:
    """Mean ``x`` (ambient size,) and tangent covariance ``P`` (n, n)."""

    x: np.ndarray
    P: np.ndarray

    @staticmethod
    def of(x: ArrayLike, P: ArrayLike) -> Gaussian:
        """Build from array-likes (scalars allowed for 1-D states)."""
        xa = np.atleast_1d(np.asarray(x, dtype=float))
        Pa = np.atleast_2d(np.asarray(P, dtype=float))
        if Pa.shape == (1, 1) and xa.shape[0] > 1:
            Pa = Pa[0, 0] * np.eye(xa.shape[0])
        return Gaussian(xa, Pa)

    def finite(self) -> bool:
        """True if no entry of x or P is NaN or infinite (one scalar check)."""
        return math.isfinite(float(self.x.sum()) + float(self.P.sum()))
