"""Nearly-constant-velocity motion with continuous white-noise acceleration, discretised
exactly for the real time step (Bar-Shalom, Li, Kirubarajan 2001, sec. 6.2.2).

State layout for ``ndim`` spatial axes: [p_1..p_ndim, v_1..v_ndim] (m, m/s). Per axis:
    F = [[1, dt], [0, 1]],  Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]
with q the acceleration noise power spectral density (m^2/s^3).
"""

from __future__ import annotations

import numpy as np

from ..core.interfaces import Transition
from ..geometry.spaces import VectorSpace


def ncv_matrices(ndim: int, dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of the NCV model for ``ndim`` axes, state [positions, velocities]."""
    I = np.eye(ndim)
    F = np.block([[I, dt * I], [np.zeros((ndim, ndim)), I]])
    Q = q * np.block([[dt**3 / 3 * I, dt**2 / 2 * I], [dt**2 / 2 * I, dt * I]])
    return F, Q


class NearlyConstantVelocity(Transition):
    """NCV in ``ndim`` (1, 2 or 3) axes with noise intensity ``q`` (m^2/s^3). Linear."""

    linear = True

    def __init__(self, ndim: int = 2, q: float = 0.5) -> None:
        self.ndim, self.q = int(ndim), float(q)
        self.space = VectorSpace(2 * self.ndim)
        self._cache: tuple[float, np.ndarray, np.ndarray] | None = None

    def _mats(self, dt: float):
        if self._cache is None or self._cache[0] != dt:
            self._cache = (dt, *ncv_matrices(self.ndim, dt, self.q))
        return self._cache[1], self._cache[2]

    def f(self, X, t, dt, u=None):
        return np.dot(X, self._mats(dt)[0].T)  # = X @ F^T, less per-call overhead

    def F(self, x, t, dt, u=None):
        return self._mats(dt)[0]

    def Q(self, t, dt, u=None):
        return self._mats(dt)[1]
