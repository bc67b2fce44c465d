"""Compiled (numba) kernels of the navigation model's IMU mechanisation: the optional fast
path of :class:`uavest.models.navigation.ImuTransition` (``pip install "uavest[fast]"``).

The same formulas as its numpy ``f`` (the mechanisation over rows) and ``F`` (the
tangent Jacobian of one state), as loops over rows and 3x3 blocks on floats: numpy's
per-call floor made the EKF's F and f some 350 us of a 25 Hz step (about 40 numpy calls
each on 3-vectors and 3x3 blocks), where the arithmetic is a few hundred flops.
``benchmarks/nav_speed.py`` measures the replay; docs/navigation.md. Equal to the numpy
forms to 1e-12 (the registry's self-check and ``tests/unit/test_nav_compiled.py``).

State rows: ``[q (4), v NED (3), p NED (3), b_g (3), b_a (3), GNSS bias (extra), magnetic
reference errors (the rest)]``; ``u`` = (gyro rad/s, specific force m/s^2), body FRD.
Importing this module imports numba and compiles nothing. ``error_model="numpy"``: a
division by zero (a zero quaternion of a diverged state) gives inf / NaN, as numpy does,
for the filter guard to see, not a ZeroDivisionError.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# (the attitude kernels' quaternion exponential and product; numba's cache does not see an
# edit there: remove this module's __pycache__/*.nb[ic] after changing them)
from uavest.geometry._compiled import _qexp, _qmul

__all__ = ["back_q_rows", "mag_h_H", "mech_F", "mech_rows"]

Array = np.ndarray


@njit(cache=True, error_model="numpy")
def _qstep(qw: float, qx: float, qy: float, qz: float, wx: float, wy: float, wz: float,
           dt: float) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """q * Exp(w dt), normalised (``navigation._qstep``)."""
    ew, ex, ey, ez = _qexp(wx * dt, wy * dt, wz * dt)
    w, a, b, c = _qmul(qw, qx, qy, qz, ew, ex, ey, ez)
    n = math.sqrt(w * w + a * a + b * b + c * c)
    return w / n, a / n, b / n, c / n


@njit(cache=True, error_model="numpy")
def _dcm(qw: float, qx: float, qy: float, qz: float, R: Array) -> None:  # pragma: no cover
    """R(q) (body FRD -> NED) into ``R`` (3, 3) (``quat_to_dcm``)."""
    R[0, 0] = 1 - 2 * (qy * qy + qz * qz)
    R[0, 1] = 2 * (qx * qy - qw * qz)
    R[0, 2] = 2 * (qx * qz + qw * qy)
    R[1, 0] = 2 * (qx * qy + qw * qz)
    R[1, 1] = 1 - 2 * (qx * qx + qz * qz)
    R[1, 2] = 2 * (qy * qz - qw * qx)
    R[2, 0] = 2 * (qx * qz - qw * qy)
    R[2, 1] = 2 * (qy * qz + qw * qx)
    R[2, 2] = 1 - 2 * (qx * qx + qy * qy)


@njit(cache=True, error_model="numpy")
def _rates(x: Array, u: Array, w_ie: Array, earth: bool, R: Array, w: Array, fb: Array
           ) -> None:  # pragma: no cover - compiled
    """The bias-corrected gyro rate ``w`` (less the Earth's rate in body axes when
    ``earth``; ``R`` scratch) and specific force ``fb`` of the state row ``x``."""
    for j in range(3):
        w[j] = u[j] - x[10 + j]
        fb[j] = u[3 + j] - x[13 + j]
    if earth:
        _dcm(x[0], x[1], x[2], x[3], R)
        for j in range(3):
            w[j] -= R[0, j] * w_ie[0] + R[1, j] * w_ie[1] + R[2, j] * w_ie[2]


@njit(cache=True, error_model="numpy")
def mech_rows(X: Array, u: Array, dt: float, g: float, w_ie: Array, earth: bool,
              phi: float, extra: int) -> Array:  # pragma: no cover - compiled
    """The mechanisation of every row of ``X`` (M, n) over ``dt`` s: attitude q Exp((w -
    b_g) dt); the specific force rotated with the mid-step attitude, plus gravity ``g``
    (m/s^2, down), integrated into velocity and position; the ``extra`` GNSS bias states
    times ``phi``; the rest constant."""
    M, n = X.shape
    out = np.empty((M, n))
    R = np.empty((3, 3))
    w = np.empty(3)
    fb = np.empty(3)
    hdt = 0.5 * dt
    for i in range(M):
        x = X[i]
        _rates(x, u, w_ie, earth, R, w, fb)
        hw, hx, hy, hz = _qstep(x[0], x[1], x[2], x[3], w[0], w[1], w[2], hdt)
        _dcm(hw, hx, hy, hz, R)
        o = out[i]
        for j in range(n):
            o[j] = x[j]
        qw, qx, qy, qz = _qstep(x[0], x[1], x[2], x[3], w[0], w[1], w[2], dt)
        o[0], o[1], o[2], o[3] = qw, qx, qy, qz
        for j in range(3):
            a = R[j, 0] * fb[0] + R[j, 1] * fb[1] + R[j, 2] * fb[2]
            if j == 2:
                a += g
            o[4 + j] = x[4 + j] + a * dt
            o[7 + j] = x[7 + j] + x[4 + j] * dt + 0.5 * dt * dt * a
        for j in range(16, 16 + extra):
            o[j] = x[j] * phi
    return out


@njit(cache=True, error_model="numpy")
def _jr(px: float, py: float, pz: float, J: Array) -> None:  # pragma: no cover - compiled
    """The SO(3) right Jacobian at ``phi`` into ``J`` (3, 3) (``right_jacobian``)."""
    th2 = px * px + py * py + pz * pz
    if th2 < 1e-10:
        a, c = 0.5, 1.0 / 6.0
    else:
        th = math.sqrt(th2)
        a, c = (1 - math.cos(th)) / th2, (th - math.sin(th)) / (th2 * th)
    # J = I - a K + c K^2, K = [phi]x, K^2 = phi phi^T - th2 I
    J[0, 0] = 1 + c * (px * px - th2)
    J[1, 1] = 1 + c * (py * py - th2)
    J[2, 2] = 1 + c * (pz * pz - th2)
    J[0, 1] = a * pz + c * px * py
    J[1, 0] = -a * pz + c * px * py
    J[0, 2] = -a * py + c * px * pz
    J[2, 0] = a * py + c * px * pz
    J[1, 2] = a * px + c * py * pz
    J[2, 1] = -a * px + c * py * pz


@njit(cache=True, error_model="numpy")
def mech_F(x: Array, u: Array, dt: float, w_ie: Array, earth: bool, phi: float,
           extra: int, dim: int) -> Array:  # pragma: no cover - compiled
    """The tangent Jacobian (dim, dim) of :func:`mech_rows` at the state ``x`` (n,), for
    the right attitude error (the Earth rate's dependence on q neglected)."""
    R = np.empty((3, 3))
    Rh = np.empty((3, 3))
    J = np.empty((3, 3))
    w = np.empty(3)
    fb = np.empty(3)
    _rates(x, u, w_ie, earth, R, w, fb)
    F = np.zeros((dim, dim))
    for j in range(dim):
        F[j, j] = 1.0
    for j in range(15, 15 + extra):
        F[j, j] = phi
    # the attitude block: Exp(-w dt) as a DCM, and -dt J_r(w dt) on the gyro bias
    ew, ex, ey, ez = _qexp(-w[0] * dt, -w[1] * dt, -w[2] * dt)
    _dcm(ew, ex, ey, ez, Rh)
    _jr(w[0] * dt, w[1] * dt, w[2] * dt, J)
    for r in range(3):
        for c in range(3):
            F[r, c] = Rh[r, c]
            F[r, 9 + c] = -dt * J[r, c]
    _dcm(x[0], x[1], x[2], x[3], R)
    hdt = 0.5 * dt
    hw, hx, hy, hz = _qstep(x[0], x[1], x[2], x[3], w[0], w[1], w[2], hdt)
    _dcm(hw, hx, hy, hz, Rh)
    # s = R^T Rh fb; da/dth = -R [s]x
    t0 = Rh[0, 0] * fb[0] + Rh[0, 1] * fb[1] + Rh[0, 2] * fb[2]
    t1 = Rh[1, 0] * fb[0] + Rh[1, 1] * fb[1] + Rh[1, 2] * fb[2]
    t2 = Rh[2, 0] * fb[0] + Rh[2, 1] * fb[1] + Rh[2, 2] * fb[2]
    s0 = R[0, 0] * t0 + R[1, 0] * t1 + R[2, 0] * t2
    s1 = R[0, 1] * t0 + R[1, 1] * t1 + R[2, 1] * t2
    s2 = R[0, 2] * t0 + R[1, 2] * t1 + R[2, 2] * t2
    # da/dbg = Rh [fb]x J_r(w dt / 2) dt / 2
    _jr(w[0] * hdt, w[1] * hdt, w[2] * hdt, J)
    h2 = 0.5 * dt * dt
    for r in range(3):
        # row r of -R [s]x: (-(R[r,1] s2 - R[r,2] s1), -(R[r,2] s0 - R[r,0] s2), ...)
        d0 = -(R[r, 1] * s2 - R[r, 2] * s1)
        d1 = -(R[r, 2] * s0 - R[r, 0] * s2)
        d2 = -(R[r, 0] * s1 - R[r, 1] * s0)
        # row r of Rh [fb]x
        k0 = Rh[r, 1] * fb[2] - Rh[r, 2] * fb[1]
        k1 = Rh[r, 2] * fb[0] - Rh[r, 0] * fb[2]
        k2 = Rh[r, 0] * fb[1] - Rh[r, 1] * fb[0]
        for c in range(3):
            dth = d0 if c == 0 else (d1 if c == 1 else d2)
            dbg = (k0 * J[0, c] + k1 * J[1, c] + k2 * J[2, c]) * hdt
            F[3 + r, c] = dth * dt
            F[3 + r, 12 + c] = -Rh[r, c] * dt
            F[3 + r, 9 + c] = dbg * dt
            F[6 + r, c] = h2 * dth
            F[6 + r, 9 + c] = h2 * dbg
            F[6 + r, 12 + c] = -h2 * Rh[r, c]
        F[6 + r, 3 + r] = dt
    return F


@njit(cache=True, error_model="numpy")
def mag_h_H(x: Array, vec: Array, w: Array, back: float, heading: bool
            ) -> tuple[Array, Array]:  # pragma: no cover - compiled
    """(h, H) of a magnetometer sample on the navigation state ``x`` (n,), the attitude
    taken ``back`` s before the state's time, ``q_b = q Exp(-(w - b_g) back)`` (``w`` the
    step's mean gyro rate, rad/s, body FRD): ``heading``: the heading (rad) of the body
    field ``vec`` (gauss) rotated to NED, ``atan2(m_E, m_N)``, H (1, n - 1); else the unit
    reference field ``vec`` (NED) in body axes, ``R(q_b)^T vec``, H (3, n - 1)
    (``navigation.OnNav`` over ``attitude.MagHeading`` / ``MagField``)."""
    dim = x.shape[0] - 1
    qw, qx, qy, qz = x[0], x[1], x[2], x[3]
    px = (w[0] - x[10]) * back
    py = (w[1] - x[11]) * back
    pz = (w[2] - x[12]) * back
    if back != 0.0:
        qw, qx, qy, qz = _qstep(qw, qx, qy, qz, w[0] - x[10], w[1] - x[11], w[2] - x[12],
                                -back)
    Rb = np.empty((3, 3))
    _dcm(qw, qx, qy, qz, Rb)
    m = 1 if heading else 3
    h = np.empty(m)
    Hq = np.zeros((m, 3))
    f0, f1, f2 = vec[0], vec[1], vec[2]
    if heading:
        m0 = Rb[0, 0] * f0 + Rb[0, 1] * f1 + Rb[0, 2] * f2
        m1 = Rb[1, 0] * f0 + Rb[1, 1] * f1 + Rb[1, 2] * f2
        h[0] = math.atan2(m1, m0)
        hn2 = m0 * m0 + m1 * m1
        if hn2 >= 1e-12:
            d0, d1 = -m1 / hn2, m0 / hn2
            for r in range(2):
                dr = d0 if r == 0 else d1
                # row r of -R [f]x
                Hq[0, 0] -= dr * (Rb[r, 1] * f2 - Rb[r, 2] * f1)
                Hq[0, 1] -= dr * (Rb[r, 2] * f0 - Rb[r, 0] * f2)
                Hq[0, 2] -= dr * (Rb[r, 0] * f1 - Rb[r, 1] * f0)
    else:
        for j in range(3):
            h[j] = Rb[0, j] * f0 + Rb[1, j] * f1 + Rb[2, j] * f2
        Hq[0, 1], Hq[0, 2] = -h[2], h[1]
        Hq[1, 0], Hq[1, 2] = h[2], -h[0]
        Hq[2, 0], Hq[2, 1] = -h[1], h[0]
    H = np.zeros((m, dim))
    if back == 0.0:
        for r in range(m):
            for c in range(3):
                H[r, c] = Hq[r, c]
        return h, H
    # q Exp(d) Exp(-phi) = q Exp(-phi) Exp(Exp(phi) d); the gyro bias through J_r(-phi)
    E = np.empty((3, 3))
    ew, ex, ey, ez = _qexp(px, py, pz)
    _dcm(ew, ex, ey, ez, E)
    J = np.empty((3, 3))
    _jr(-px, -py, -pz, J)
    for r in range(m):
        for c in range(3):
            H[r, c] = Hq[r, 0] * E[0, c] + Hq[r, 1] * E[1, c] + Hq[r, 2] * E[2, c]
            H[r, 9 + c] = (Hq[r, 0] * J[0, c] + Hq[r, 1] * J[1, c]
                           + Hq[r, 2] * J[2, c]) * back
    return h, H


@njit(cache=True, error_model="numpy")
def back_q_rows(X: Array, w: Array, dt: float) -> Array:  # pragma: no cover - compiled
    """q_i * Exp((w - b_g,i) dt) normalised for every row of ``X`` (M, n): the attitude
    of each member ``-dt`` s before (``OnNav._q``; ``w`` the step's gyro rate, rad/s)."""
    M = X.shape[0]
    out = np.empty((M, 4))
    for i in range(M):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = _qstep(
            X[i, 0], X[i, 1], X[i, 2], X[i, 3], w[0] - X[i, 10], w[1] - X[i, 11],
            w[2] - X[i, 12], dt)
    return out
