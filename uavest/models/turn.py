"""Coordinated-turn (CT) motion with an unknown turn rate, 2-D and 3-D.

World frame ENU (m, m/s, rad/s). State layouts (positions first, then velocities, so the
radar model reads them exactly as for :class:`~uavest.models.motion.NearlyConstantVelocity`):

* 2-D: ``[x, y, vx, vy, omega]``
* 3-D: ``[x, y, z, vx, vy, vz, omega]``: CT in the horizontal plane, nearly constant
  velocity vertically.

``omega`` is the turn rate (rad/s, positive counter-clockwise seen from above). Over a
step ``T`` (Bar-Shalom, Li, Kirubarajan 2001, sec. 11.7):

    x' = x + sin(wT)/w vx - (1 - cos wT)/w vy      vx' = cos(wT) vx - sin(wT) vy
    y' = y + (1 - cos wT)/w vx + sin(wT)/w vy      vy' = sin(wT) vx + cos(wT) vy
    omega' = omega

with the w -> 0 limit taken smoothly (series for |wT| < 1e-6) and (1 - cos wT)/w computed
as 2 sin^2(wT/2)/w (no cancellation for small wT). Process noise: continuous
white-noise acceleration of intensity ``q`` (m^2/s^3) on every axis, discretised exactly
for the step as in the NCV model (``q [[T^3/3, T^2/2], [T^2/2, T]]`` per axis), plus a
turn-rate random walk of intensity ``q_omega`` (rad^2/s^3): variance ``q_omega T``.
(The exact CT discretisation depends on the state; the NCV form is the standard
approximation.) The Jacobian ``F`` is left to central finite differences.
"""

from __future__ import annotations

import numpy as np

from ..core.interfaces import Transition
from ..errors import InputError
from ..geometry.spaces import VectorSpace
from .motion import ncv_matrices

Array = np.ndarray


def _ct_coeffs(w: Array, T: float) -> tuple[Array, Array, Array, Array]:
    """sin(wT)/w, (1-cos wT)/w, cos wT, sin wT, smooth at w = 0.

    (1 - cos wT)/w is evaluated as 2 sin^2(wT/2)/w: the direct form cancels
    catastrophically for small wT (relative error ~1e-16/(wT)^2, i.e. 1e-4 just above the
    series cut-off), which corrupted the finite-difference d/d omega of ``F``."""
    wT = w * T
    small = np.abs(wT) < 1e-6
    ws = np.where(small, 1.0, w)
    a = np.where(small, T * (1.0 - wT**2 / 6.0), np.sin(wT) / ws)
    b = np.where(small, T * wT / 2.0, 2.0 * np.sin(wT / 2.0) ** 2 / ws)
    return a, b, np.cos(wT), np.sin(wT)


def ct_step(P: Array, V: Array, w: Array, T: float) -> tuple[Array, Array]:
    """Horizontal CT step of positions ``P`` (M, 2) and velocities ``V`` (M, 2)."""
    a, b, c, s = _ct_coeffs(w, T)
    vx, vy = V[:, 0], V[:, 1]
    Pn = np.stack([P[:, 0] + a * vx - b * vy, P[:, 1] + b * vx + a * vy], axis=1)
    Vn = np.stack([c * vx - s * vy, s * vx + c * vy], axis=1)
    return Pn, Vn


class CoordinatedTurn(Transition):
    """Coordinated turn in ``ndim`` = 2 or 3 axes (see module docstring).

    Args:
      ndim: 2 (state [x, y, vx, vy, omega]) or 3 (state [x, y, z, vx, vy, vz, omega]).
      q: acceleration noise intensity (m^2/s^3) per axis.
      q_omega: turn-rate noise intensity (rad^2/s^3).
    """

    def __init__(self, ndim: int = 2, q: float = 0.5, q_omega: float = 1e-4) -> None:
        if ndim not in (2, 3):
            raise InputError("ndim must be 2 or 3")
        self.ndim, self.q, self.q_omega = ndim, float(q), float(q_omega)
        self.space = VectorSpace(2 * ndim + 1)

    def f(self, X: Array, t: float, dt: float, u: Array | None = None) -> Array:
        d = self.ndim
        X = np.atleast_2d(X)
        w = X[:, -1]
        Ph, Vh = ct_step(X[:, 0:2], X[:, d : d + 2], w, dt)
        out = X.copy()
        out[:, 0:2] = Ph
        out[:, d : d + 2] = Vh
        if d == 3:
            out[:, 2] = X[:, 2] + dt * X[:, 5]
        return out

    def Q(self, t: float, dt: float, u: Array | None = None) -> Array:
        d = self.ndim
        _, Qn = ncv_matrices(d, dt, self.q)
        Q = np.zeros((2 * d + 1, 2 * d + 1))
        Q[: 2 * d, : 2 * d] = Qn
        Q[-1, -1] = self.q_omega * dt
        return Q
