"""Compiled (numba) attitude-manifold kernels: the optional fast path of
:mod:`uavest.geometry.rotation` (``pip install "uavest[fast]"``).

The same formulas as the fused numpy kernels there (``retract_rows``, ``local_rows``,
``gyro_propagate``, ``AttitudeSpace.mean``) and in :mod:`uavest.geometry.navigation`
(``nav_retract_rows``, ``nav_local_rows``, ``nav_mean``), as loops over rows compiled by
numba: the filters call these on 13 sigma points or 221 members a few times per step, where numpy's
cost is its per-call floor, not arithmetic (``benchmarks/numba_kernels.py`` measures
both side by side; docs/speed.md). Equal to the numpy kernels to 1e-12
(``tests/unit/test_speed_kernels.py``). Importing this module imports numba and compiles
nothing; each kernel compiles at its first call (cached on disk by numba).

All arrays are float64; ``x`` is always 2-D here, (1, n) for one state or (M, n): n = 7
for the attitude space, 16 or more for the navigation space (:mod:`uavest.geometry.navigation`),
whose rows are a quaternion and Euclidean components as the attitude's.
``error_model="numpy"``: a division by zero (a zero quaternion) gives inf / NaN, as the
numpy kernels do, for the filter guard to see, not a ZeroDivisionError.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["gyro_propagate", "local_rows", "mean", "moments", "retract_rows",
           "rotate_inv_rows", "rotate_rows"]

Array = np.ndarray


@njit(cache=True, error_model="numpy")
def _qexp(vx: float, vy: float, vz: float
          ) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    th = math.sqrt(vx * vx + vy * vy + vz * vz)
    h = 0.5 * th
    s = 0.5 - th * th / 48.0 if th < 1e-5 else math.sin(h) / th
    return math.cos(h), s * vx, s * vy, s * vz


@njit(cache=True, error_model="numpy")
def _qmul(aw: float, ax: float, ay: float, az: float, bw: float, bx: float, by: float,
          bz: float) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


@njit(cache=True, error_model="numpy")
def retract_rows(x: Array, dx: Array) -> Array:  # pragma: no cover - compiled
    """q_i * Exp(dx_i[:3]) normalised, b_i + dx_i[3:]; ``x`` (1, 7) or (M, 7) (or any
    width: a quaternion, then Euclidean components; ``dx`` one column fewer)."""
    M = dx.shape[0]
    one = x.shape[0] == 1
    ne = dx.shape[1] - 3
    out = np.empty((M, ne + 4))
    for i in range(M):
        r = 0 if one else i
        ew, ex, ey, ez = _qexp(dx[i, 0], dx[i, 1], dx[i, 2])
        w, a, b, c = _qmul(x[r, 0], x[r, 1], x[r, 2], x[r, 3], ew, ex, ey, ez)
        n = math.sqrt(w * w + a * a + b * b + c * c)
        out[i, 0] = w / n
        out[i, 1] = a / n
        out[i, 2] = b / n
        out[i, 3] = c / n
        for j in range(ne):
            out[i, 4 + j] = x[r, 4 + j] + dx[i, 3 + j]
    return out


@njit(cache=True, error_model="numpy")
def local_rows(x: Array, y: Array) -> Array:  # pragma: no cover - compiled
    """Log(q_x^-1 q_y) the short way, b_y - b_x; ``x`` (1, 7) or (M, 7) (or any width, as
    :func:`retract_rows`)."""
    M = y.shape[0]
    one = x.shape[0] == 1
    ne = y.shape[1] - 4
    out = np.empty((M, ne + 3))
    for i in range(M):
        r = 0 if one else i
        w, a, b, c = _qmul(x[r, 0], -x[r, 1], -x[r, 2], -x[r, 3],
                           y[i, 0], y[i, 1], y[i, 2], y[i, 3])
        sg = -1.0 if w < 0.0 else 1.0
        aw = abs(w)
        n = math.sqrt(a * a + b * b + c * c)
        k = 2.0 / max(aw, 1e-300) if n < 1e-8 else 2.0 * math.atan2(n, aw) / n
        k *= sg
        out[i, 0] = k * a
        out[i, 1] = k * b
        out[i, 2] = k * c
        for j in range(ne):
            out[i, 3 + j] = y[i, 4 + j] - x[r, 4 + j]
    return out


@njit(cache=True, error_model="numpy")
def gyro_propagate(X: Array, u: Array, dt: float) -> Array:  # pragma: no cover - compiled
    """q_i <- q_i * Exp((u - b_i) dt) normalised, b_i <- b_i."""
    M = X.shape[0]
    out = np.empty((M, 7))
    for i in range(M):
        ew, ex, ey, ez = _qexp((u[0] - X[i, 4]) * dt, (u[1] - X[i, 5]) * dt,
                               (u[2] - X[i, 6]) * dt)
        w, a, b, c = _qmul(X[i, 0], X[i, 1], X[i, 2], X[i, 3], ew, ex, ey, ez)
        n = math.sqrt(w * w + a * a + b * b + c * c)
        out[i, 0] = w / n
        out[i, 1] = a / n
        out[i, 2] = b / n
        out[i, 3] = c / n
        out[i, 4] = X[i, 4]
        out[i, 5] = X[i, 5]
        out[i, 6] = X[i, 6]
    return out


@njit(cache=True, error_model="numpy")
def mean(X: Array, w: Array, ref: Array) -> Array:  # pragma: no cover - compiled
    """Sign-aligned chordal mean, then one Gauss-Newton (Karcher) step
    (``AttitudeSpace.mean``, ``NavSpace.mean``: any width, as :func:`retract_rows`)."""
    M, n = X.shape
    s = np.zeros(n)
    for i in range(M):
        d = X[i, 0] * ref[0] + X[i, 1] * ref[1] + X[i, 2] * ref[2] + X[i, 3] * ref[3]
        ws = -w[i] if d < 0.0 else w[i]
        for j in range(4):
            s[j] += ws * X[i, j]
        for j in range(4, n):
            s[j] += w[i] * X[i, j]
    nq = math.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2] + s[3] * s[3])
    start = np.empty((1, n))
    for j in range(4):
        start[0, j] = s[j] / nq if nq > 1e-9 else ref[j]
    for j in range(4, n):
        start[0, j] = s[j]
    d = local_rows(start, X)
    step = np.zeros((1, n - 1))
    for i in range(M):
        for j in range(n - 1):
            step[0, j] += w[i] * d[i, j]
    out: Array = retract_rows(start, step)[0]
    return out


@njit(cache=True, error_model="numpy")
def moments(X: Array, w: Array) -> tuple[Array, Array, Array]:  # pragma: no cover - compiled
    """(x, dX, P) of the members ``X`` (M, n) under the weights ``w`` (M,): :func:`mean`
    started from the heaviest member (the first of equals), the deviations
    local(x, X_j) centred exactly under ``w``, and the reliability-weighted covariance
    sum_j w_j dX_j dX_j^T / max(1 - sum w^2, 1e-12), symmetrised as
    ``uavest.core.states.ensemble_estimate`` does it, (P + P^T) / 2 (what
    ``uavest.core.states.ensemble_moments`` and ``ensemble_estimate`` compute on these
    spaces, in one call)."""
    M, k = X.shape
    top = 0
    for i in range(1, M):
        if w[i] > w[top]:
            top = i
    x = mean(X, w, X[top])
    dX = local_rows(x.reshape(1, k), X)
    n = k - 1
    c = np.zeros(n)
    ww = 0.0
    for i in range(M):
        ww += w[i] * w[i]
        for j in range(n):
            c[j] += w[i] * dX[i, j]
    Wd = np.empty((M, n))
    for i in range(M):
        for j in range(n):
            dX[i, j] -= c[j]
            Wd[i, j] = w[i] * dX[i, j]
    # BLAS, as numpy's np.dot(dX.T * w, dX) (the same operands: twice the speed of loops)
    P = np.dot(Wd.T, dX) / max(1.0 - ww, 1e-12)
    for a in range(n):  # (P + P^T) / 2, ensemble_estimate's symmetrising
        for b in range(a):
            s = 0.5 * (P[a, b] + P[b, a])
            P[a, b] = s
            P[b, a] = s
    return x, dX, P


@njit(cache=True, error_model="numpy")
def rotate_rows(Q: Array, V: Array) -> Array:  # pragma: no cover - compiled
    """R(q_i) v_i for every row q_i of ``Q`` (M, 4) and v_i of ``V`` (M, 3) (body FRD ->
    NED): :func:`~uavest.geometry.rotation.quat_to_dcm` applied, summed j = 0..2."""
    M = Q.shape[0]
    out = np.empty((M, 3))
    for i in range(M):
        w, x, y, z = Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3]
        v0, v1, v2 = V[i, 0], V[i, 1], V[i, 2]
        out[i, 0] = ((1 - 2 * (y * y + z * z)) * v0 + 2 * (x * y - w * z) * v1
                     + 2 * (x * z + w * y) * v2)
        out[i, 1] = (2 * (x * y + w * z) * v0 + (1 - 2 * (x * x + z * z)) * v1
                     + 2 * (y * z - w * x) * v2)
        out[i, 2] = (2 * (x * z - w * y) * v0 + 2 * (y * z + w * x) * v1
                     + (1 - 2 * (x * x + y * y)) * v2)
    return out


@njit(cache=True, error_model="numpy")
def rotate_inv_rows(Q: Array, v: Array) -> Array:  # pragma: no cover - compiled
    """R(q_i)^T v for every row q_i of ``Q`` (M, 4) (NED -> body FRD), ``v`` (3,): the
    transposed :func:`~uavest.geometry.rotation.quat_to_dcm` applied, summed j = 0..2."""
    M = Q.shape[0]
    out = np.empty((M, 3))
    v0, v1, v2 = v[0], v[1], v[2]
    for i in range(M):
        w, x, y, z = Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3]
        r00 = 1 - 2 * (y * y + z * z)
        r01 = 2 * (x * y - w * z)
        r02 = 2 * (x * z + w * y)
        r10 = 2 * (x * y + w * z)
        r11 = 1 - 2 * (x * x + z * z)
        r12 = 2 * (y * z - w * x)
        r20 = 2 * (x * z - w * y)
        r21 = 2 * (y * z + w * x)
        r22 = 1 - 2 * (x * x + y * y)
        out[i, 0] = r00 * v0 + r10 * v1 + r20 * v2
        out[i, 1] = r01 * v0 + r11 * v1 + r21 * v2
        out[i, 2] = r02 * v0 + r12 * v1 + r22 * v2
    return out
