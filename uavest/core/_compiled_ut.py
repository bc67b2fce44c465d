"""Compiled (numba) kernels of the unscented transform's algebra on a vector state space:
the optional fast path of :class:`uavest.core.unscented.UKF` (``pip install
"uavest[fast]"``), dispatched through :data:`uavest.core.unscented.UT_KERNELS`.

A UKF step on a few sigma points costs numpy's per-call floor (~35 calls of ~1 us), not
arithmetic. These kernels do the algebra between the model's calls in one call each,
with the formulas of ``UKF._predict`` / ``UKF._update`` (the reference and the fallback):

* :func:`sigma`: the factor L of P, the offsets D = U L^T and the points X = x + D;
* :func:`moments`: x = Wm Y, P = sum Wc (Y - x)(Y - x)^T + Q (the prediction);
* :func:`update`: Pxz = sum Wc D E^T, S = sum Wc E E^T + R, K = Pxz S^-1 through the
  factor of S, x + K nu, P - K Pxz^T and the NIS, given the model's residuals E and nu.

The model's ``f``, ``h``, ``mean`` and ``residual`` (angle wrapping, circular means) stay
Python calls between them. Sums run in index order (BLAS may group and fuse them
differently): equal to the array path to rounding (tests/unit/test_fast_paths.py).
Outputs are the caller's arrays (an array made and returned here costs numba ~1 us of
boxing). A factor that fails (no jitter here) returns status 1 and the caller takes the
array path, which jitters or raises as it always has.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..compiled.helpers import chol_into

__all__ = ["moments", "sigma", "update"]

Array = np.ndarray


@njit(cache=True)
def sigma(x: Array, P: Array, U: Array, D: Array, X: Array) -> int:  # pragma: no cover - compiled
    """Status; ``D`` (J, n) <- U L^T and ``X`` <- x + D for L = chol(P) and the unit
    offsets ``U`` (J, n). 1: P has no plain factor."""
    J, n = U.shape
    L = np.empty((n, n))
    if not chol_into(P, L):
        return 1
    for j in range(J):
        for i in range(n):
            s = 0.0
            for k in range(i + 1):
                s += U[j, k] * L[i, k]
            D[j, i] = s
            X[j, i] = x[i] + s
    return 0


@njit(cache=True)
def moments(Y: Array, Wm: Array, Wc: Array, Q: Array, x: Array, P: Array
            ) -> None:  # pragma: no cover - compiled
    """``x`` <- Wm Y, ``P`` <- sum_j Wc_j (Y_j - x)(Y_j - x)^T + Q."""
    J, n = Y.shape
    for i in range(n):
        s = 0.0
        for j in range(J):
            s += Wm[j] * Y[j, i]
        x[i] = s
    d = np.empty((J, n))
    for j in range(J):
        for i in range(n):
            d[j, i] = Y[j, i] - x[i]
    for i in range(n):
        for k in range(n):
            s = 0.0
            for j in range(J):
                s += d[j, i] * Wc[j] * d[j, k]
            P[i, k] = s + Q[i, k]


@njit(cache=True)
def update(x0: Array, P0: Array, D: Array, E: Array, Wc: Array, R: Array, nu: Array,
           x: Array, P: Array, S: Array) -> tuple[int, float]:  # pragma: no cover - compiled
    """(status, nis); ``x`` <- x0 + K nu, ``P`` <- P0 - K Pxz^T, ``S`` <- the innovation
    covariance, given the sigma offsets ``D`` (J, n), the measurement residuals ``E``
    (J, m) of the sigma points and ``nu`` (m,) of z. Status 1: S has no plain factor."""
    J, n = D.shape
    m = E.shape[1]
    Pxz = np.empty((n, m))
    for i in range(n):
        for a in range(m):
            s = 0.0
            for j in range(J):
                s += D[j, i] * Wc[j] * E[j, a]
            Pxz[i, a] = s
    for a in range(m):
        for b in range(m):
            s = 0.0
            for j in range(J):
                s += E[j, a] * Wc[j] * E[j, b]
            S[a, b] = s + R[a, b]
    L = np.empty((m, m))
    if not chol_into(S, L):
        return 1, 0.0
    # K = Pxz S^-1: rows k_i solve S k_i = Pxz_i by L y = Pxz_i, L^T k_i = y
    K = np.empty((n, m))
    y = np.empty(m)
    for i in range(n):
        for a in range(m):
            t = Pxz[i, a]
            for b in range(a):
                t -= L[a, b] * y[b]
            y[a] = t / L[a, a]
        for a in range(m - 1, -1, -1):
            t = y[a]
            for b in range(a + 1, m):
                t -= L[b, a] * K[i, b]
            K[i, a] = t / L[a, a]
    for i in range(n):
        s = 0.0
        for a in range(m):
            s += K[i, a] * nu[a]
        x[i] = x0[i] + s
        for k in range(n):
            t = 0.0
            for a in range(m):
                t += K[i, a] * Pxz[k, a]
            P[i, k] = P0[i, k] - t
    nis = 0.0  # |L^-1 nu|^2
    for a in range(m):
        t = nu[a]
        for b in range(a):
            t -= L[a, b] * y[b]
        y[a] = t / L[a, a]
        nis += y[a] * y[a]
    return 0, nis
