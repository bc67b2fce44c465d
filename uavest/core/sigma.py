"""The unscented transform on any :class:`~uavest.geometry.spaces.Space`: the sigma-point
weights, their tangent offsets and one unscented prediction with its cross-covariance.

Below both the filter contract (whose RTS fallback is the unscented prediction) and the
UKF (:mod:`.unscented`, which builds its predict on it), so neither imports the other.
Formulas in :mod:`.unscented`'s docstring.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .gaussian import Gaussian
from .interfaces import Transition
from .linalg import chol
from .spec import SpecError

Array = np.ndarray
_dot = np.dot  # the same BLAS products as @ without the gufunc's per-call cost


@lru_cache(maxsize=64)
def sigma_weights(
    n: int, alpha: float, beta: float, kappa: float, points: str
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(c, Wm, Wc, U) for ``points`` in {"merwe", "cubature"}; U is the unit offset
    template so that the sigma offsets are U @ L.T. Arrays are read-only."""
    if points == "cubature":
        c = np.sqrt(n)
        Wm = np.full(2 * n, 1.0 / (2 * n))
        Wc = Wm.copy()
    elif points == "merwe":
        lam = alpha**2 * (n + kappa) - n
        if n + lam <= 0:
            raise SpecError(f"UKF: n + lambda = {n + lam} must be > 0 (alpha, kappa)")
        c = np.sqrt(n + lam)
        Wm = np.full(2 * n + 1, 1.0 / (2 * (n + lam)))
        Wc = Wm.copy()
        Wm[0] = lam / (n + lam)
        Wc[0] = Wm[0] + 1.0 - alpha**2 + beta
    else:
        raise ValueError(f"unknown sigma points {points!r}: 'merwe' or 'cubature'")
    U = sigma_offsets(np.eye(n), c, points)
    for a in (Wm, Wc, U):
        a.flags.writeable = False
    return float(c), Wm, Wc, U


def sigma_offsets(L: Array, c: float, points: str) -> Array:
    """Tangent offsets (2n+1, n) (merwe, first row zero) or (2n, n) (cubature)."""
    cL = c * L.T
    if points == "cubature":
        return np.vstack([cL, -cL])
    return np.vstack([np.zeros((1, L.shape[0])), cL, -cL])


def unscented_predict(
    g: Gaussian, model: Transition, t: float, dt: float, u: Array | None,
    weights: tuple[float, Array, Array, Array],
) -> tuple[Gaussian, Array, Array, Array]:
    """Unscented prediction of ``g`` through ``model`` with ``weights`` (a
    :func:`sigma_weights` tuple): (prediction, tangent offsets D, deviations dY of the
    propagated points about the predicted mean, Wc). ``t``, ``dt`` in s."""
    space = model.space
    _, Wm, Wc, U = weights
    D = _dot(U, chol(g.P).T)
    Y = model.f(space.retract(g.x, D), t, dt, u)
    x = space.mean(Y, Wm, Y[0])
    dY = space.local(x, Y)
    # sum of w_j d_j d_j^T + Q: symmetric PSD by construction for Wc >= 0
    return Gaussian(x, _dot(dY.T * Wc, dY) + model.Q(t, dt, u)), D, dY, Wc


def unscented_cross(
    g: Gaussian, model: Transition, t: float, dt: float, u: Array | None = None,
    alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, points: str = "merwe",
) -> tuple[Gaussian, Array]:
    """Unscented prediction of ``g`` and the cross-covariance C = Cov(x_k, x_{k+1}) (n, n)
    in tangent coordinates (what ``UKF(alpha, beta, kappa, points).predict_cross``
    returns)."""
    w = sigma_weights(model.space.dim, alpha, beta, kappa, points)
    gp, D, dY, Wc = unscented_predict(g, model, t, dt, u, w)
    return gp, (D.T * Wc) @ dY
