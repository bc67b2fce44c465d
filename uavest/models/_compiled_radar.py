"""Compiled (numba) kernels of :meth:`uavest.models.radar.RadarMeasurement.linearise_rows`
for the radar without range rate: :func:`linearise2` (2-D range / azimuth, described
below) and :func:`linearise3` (3-D range / azimuth / elevation, the same steps with the
elevation row; see its docstring). The optional fast path (``pip install
"uavest[fast]"``), dispatched through :data:`uavest.models.radar.RADAR_KERNELS`.

The composed default (:meth:`uavest.core.interfaces.Measurement.linearise_rows`: ``h_H_rows``,
one circular ``mean``, three ``residual`` calls) costs ~15 numpy calls on (M, 2) and
(M, 2, n) stacks of M = 585 members (the ``radar`` preset), each paying numpy's per-call
floor; here the same formulas (``_los``, ``h_H_rows``, ``_H2_rows``, ``residual``,
``mean`` of :mod:`uavest.models.radar`) run as a few loops over the members:

* the line of sight D_j = R_ws^T (p_j - position) (m, sensor frame), range |D_j| (m),
  azimuth atan2(D_y, D_x) (rad), the Jacobian rows D / r and [-D_y, D_x] / r^2 (r^2
  floored at ``eps2``; as products by 1 / r and its square, one division a member),
  times R_ws^T on the right unless the sensor axes are the world's;
* the weighted mean: sum_j w_j r_j and the circular atan2(sum_j w_j sin a_j, sum_j w_j
  cos a_j), with sin a_j = D_y / r_j and cos a_j = D_x / r_j (the same numbers to
  rounding; ``math.sin`` / ``math.cos`` of the angle where r_j^2 is outside [1e-300,
  1e300] or not finite, e.g. a member at the sensor, where the quotient is not the sine);
* the residuals, the azimuth wrapped to [-pi, pi) as (d + pi) mod 2 pi - pi with Python's
  (numpy's) modulo: exact for d + pi in [-2 pi, 4 pi) by one addition or (exact)
  subtraction of 2 pi, the modulo itself elsewhere.

The azimuth is :func:`atan2`, a branch-free rational approximation (Cephes' ``atan``)
that LLVM vectorises: libm's ``atan2`` costs ~20 ns a call, more than all the rest of
the kernel; within 1 ulp of the exact value, as libm's and numpy's (SIMD) are. Sums run
in index order (numpy's ``dot`` groups them differently): equal to the composed numpy
path to rounding (``tests/unit/test_radar_compiled.py``). Importing this module imports
numba and compiles nothing; the kernel compiles at its first call (cached on disk).

All arrays float64; units m (ranges, positions) and rad (angles).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..compiled.helpers import wrap_pi

__all__ = ["atan2", "linearise2", "linearise3"]

#: LLVM may fuse a * b + c into one rounding (FMA): the results stay equal to the numpy
#: path to rounding; no flag that assumes finite values. ``error_model="numpy"``: IEEE
#: division (no zero-division check, whose branch would stop the loops vectorising).
_FM = {"contract"}

# Cephes atan: atan(t) = t + t z P(z) / Q(z), z = t^2, for |t| <= 0.66 (relative error
# 1.8e-16); Q monic
_P0, _P1, _P2, _P3, _P4 = (-8.750608600031904122785e-1, -1.615753718733365076637e1,
                           -7.500855792314704667340e1, -1.228866684490136173410e2,
                           -6.485021904942025371773e1)
_Q0, _Q1, _Q2, _Q3, _Q4 = (2.485846490142306297962e1, 1.650270098316988542046e2,
                           4.328810604912902668951e2, 4.853903996359136964868e2,
                           1.945506571482613964425e2)
#: pi / 4 to 50 bits (k * _PIO4_A is exact for k = 0..4) and the rest of it
_PIO4_A = 0.7853981633974483
_PIO4_B = 3.061616997868383e-17
_PI = math.pi
_TWO_PI = 2.0 * math.pi
_FOUR_PI = 4.0 * math.pi
#: r^2 (m^2) between which sin a = D_y / r and cos a = D_x / r hold to rounding (no
#: underflow in the squares, no overflow); elsewhere math.sin / math.cos of the angle
_RR_LO, _RR_HI = 1e-300, 1e300


@njit(cache=True, fastmath=_FM, error_model="numpy", inline="always")
def atan2(y, x):  # pragma: no cover - compiled
    """atan2(y, x) (rad, in [-pi, pi]) for finite ``x``, ``y`` (m or any unit), without
    branches: within 1 ulp of the exact value; signed zeros (atan2(+-0, -0) = +-pi) and
    NaN as libm's. (Both infinite gives NaN: the caller takes ``math.atan2`` there.)

    t = min / max of |x|, |y| in [0, 1]; for t > 0.66, (min - max) / (min + max) and
    pi / 4 added; then the octant: the result is k pi / 4 +- atan(t) with k = 0..4, the
    multiple of pi / 4 in two parts so that it rounds once."""
    ax = abs(x)
    ay = abs(y)
    swap = ay > ax
    mn = ax if swap else ay
    mx = ay if swap else ax
    big = mn > 0.66 * mx
    num = mn - mx if big else mn
    den = mn + mx if big else mx
    t = num / den if den != 0.0 else num  # 0 / 0 at the origin: 0 (a NaN stays NaN)
    z = t * t
    p = (((_P0 * z + _P1) * z + _P2) * z + _P3) * z + _P4
    q = ((((z + _Q0) * z + _Q1) * z + _Q2) * z + _Q3) * z + _Q4
    v = t + t * (z * p / q)
    neg = math.copysign(1.0, x) < 0.0  # -0 counts as negative
    b = 1.0 if big else 0.0
    if swap:  # |y| > |x|: pi / 2 -+ atan(|x| / |y|)
        k = 2.0 + b if neg else 2.0 - b
        v = v if neg else -v
    else:  # pi - atan(|y| / |x|) for x < 0
        k = 4.0 - b if neg else b
        v = -v if neg else v
    return math.copysign(k * _PIO4_A + (k * _PIO4_B + v), y)


@njit(cache=True, fastmath=_FM, error_model="numpy", inline="always")
def _wrap_fast(d):  # pragma: no cover - compiled
    """:func:`~uavest.compiled.helpers.wrap_pi` for d + pi in [-2 pi, 4 pi) (the modulo
    is then t, t - 2 pi exactly or t + 2 pi rounded once, as fmod and the sign fix-up give
    it), without branches; and whether d was outside that range or NaN (the value is then
    not used)."""
    t = d + _PI
    m = t - _TWO_PI if t >= _TWO_PI else (t + _TWO_PI if t < 0.0 else t)
    return m - _PI, (t < -_TWO_PI) | (t >= _FOUR_PI) | (t != t)


@njit(cache=True, fastmath=_FM, error_model="numpy", inline="always")
def _range_azimuth(rg, az, sn, cs, w, z0, z1, nuF, dYF, m):  # pragma: no cover - compiled
    """The range and azimuth parts of the weighted mean and of the residuals, shared by
    :func:`linearise2` and :func:`linearise3`; returns (s0, m1), the mean range (m) and
    the circular mean azimuth (rad).

    ``rg``, ``az``, ``sn``, ``cs`` (M,): range (m), azimuth, its sine and cosine per
    member; ``w`` (M,): the weights; ``z0``, ``z1``: measured range (m) and azimuth
    (rad). ``nuF``, ``dYF`` (M m,): flat views of the (M, m) residual rows, whose
    columns 0 (range) and 1 (azimuth, wrapped to [-pi, pi)) are written (constant
    strides, so the stores vectorise; ``m`` a constant of the inlined caller). Sums in
    index order: s0 = sum_j w_j r_j, m1 = atan2(sum_j w_j sin a_j, sum_j w_j cos a_j)."""
    M = rg.shape[0]
    s0 = 0.0
    ss = 0.0
    sc = 0.0
    for j in range(M):
        wj = w[j]
        s0 += wj * rg[j]
        ss += wj * sn[j]
        sc += wj * cs[j]
    m1 = math.atan2(ss, sc)
    odd = 0
    for j in range(M):
        a = az[j]
        nuF[m * j] = z0 - rg[j]
        dYF[m * j] = rg[j] - s0
        e, out1 = _wrap_fast(z1 - a)
        nuF[m * j + 1] = e
        f, out2 = _wrap_fast(a - m1)
        dYF[m * j + 1] = f
        odd += out1 | out2
    if odd:  # an azimuth residual outside [-3 pi, 3 pi): the modulo
        for j in range(M):
            nuF[m * j + 1] = wrap_pi(z1 - az[j])
            dYF[m * j + 1] = wrap_pi(az[j] - m1)
    return s0, m1


@njit(cache=True, fastmath=_FM, error_model="numpy")
def linearise2(X, pose, z, w, Hs, nu, dY, nubar, tag):  # pragma: no cover - compiled
    """The range / azimuth radar's ``linearise_rows`` into the caller's arrays ``Hs``
    (M, 2, n), ``nu`` (M, 2), ``dY`` (M, 2), ``nubar`` (2,) (C-contiguous; arrays made
    here would cost numba ~0.4 us each to return).

    ``X`` (M, >= 2): target states (world ENU, positions in columns 0 and 1, m; the rest
    is not read). ``pose``: the tuple (px, py, R00, R01, R10, R11, aligned, eps2) of
    the antenna position (m, world), the world-from-sensor rotation R_ws, 1.0 if R_ws is
    the identity (the Jacobian rows are then not multiplied by it, as in ``_H2_rows``)
    else 0.0, and the floor of r^2 in the Jacobian (m^2). ``z`` (2,): measured range
    (m) and azimuth (rad). ``w`` (M,): the weights. ``tag``: any tuple of n floats, n
    the state's tangent dimension (the columns of ``Hs``; those past 2, velocity and any
    extra, are zero), a constant of each compiled version."""
    px, py, c00, c01, c10, c11, aligned, eps2 = pose
    z0 = z[0]
    z1 = z[1]
    n = len(tag)
    M = X.shape[0]
    T = np.empty((10, M))  # per member: D_x, D_y, range, azimuth, sin, cos, 4 H entries
    Dx = T[0]
    Dy = T[1]
    rg = T[2]
    az = T[3]
    sn = T[4]
    cs = T[5]
    for j in range(M):  # D = (p - s) @ R_ws, summed onto +0 as the BLAS product does
        ex = X[j, 0] - px
        ey = X[j, 1] - py
        Dx[j] = (0.0 + ex * c00) + ey * c10
        Dy[j] = (0.0 + ex * c01) + ey * c11
    iq_floor = 1.0 / math.sqrt(eps2)
    odd = 0
    for j in range(M):  # vectorised (no calls, no branches; the stores contiguous)
        dx = Dx[j]
        dy = Dy[j]
        rr = dx * dx + dy * dy
        r = math.sqrt(rr)
        ir = 1.0 / r
        rg[j] = r
        az[j] = atan2(dy, dx)
        sn[j] = dy * ir
        cs[j] = dx * ir
        odd += (rr < _RR_LO) | (rr > _RR_HI) | (rr != rr)
        # 1 / sqrt(max(r^2, eps2)) and its square (a NaN stays NaN, as np.maximum's)
        iq = iq_floor if rr < eps2 else ir
        ir2 = iq * iq
        g00 = dx * iq
        g01 = dy * iq
        g10 = -dy * ir2
        g11 = dx * ir2
        if aligned != 0.0:
            T[6, j] = g00
            T[7, j] = g01
            T[8, j] = g10
            T[9, j] = g11
        else:  # g @ R_ws^T
            T[6, j] = g00 * c00 + g01 * c01
            T[7, j] = g00 * c10 + g01 * c11
            T[8, j] = g10 * c00 + g11 * c01
            T[9, j] = g10 * c10 + g11 * c11
    if odd:  # members within 1e-150 m of the sensor, beyond 1e150 m or not finite
        for j in range(M):
            rr = Dx[j] * Dx[j] + Dy[j] * Dy[j]
            if not _RR_LO <= rr <= _RR_HI:
                a = math.atan2(Dy[j], Dx[j])
                az[j] = a
                sn[j] = math.sin(a)
                cs[j] = math.cos(a)
    # (M, 2) and (M, 2, n) through flat views: constant strides, so the stores vectorise
    nu2 = nu.reshape(2 * M)
    dY2 = dY.reshape(2 * M)
    s0, m1 = _range_azimuth(rg, az, sn, cs, w, z0, z1, nu2, dY2, 2)
    H2 = Hs.reshape(2 * n * M)
    for j in range(M):
        b = 2 * n * j
        H2[b] = T[6, j]
        H2[b + 1] = T[7, j]
        for k in range(2, n):
            H2[b + k] = 0.0
        H2[b + n] = T[8, j]
        H2[b + n + 1] = T[9, j]
        for k in range(n + 2, 2 * n):
            H2[b + k] = 0.0
    nubar[0] = z0 - s0
    nubar[1] = wrap_pi(z1 - m1)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def linearise3(X, pose, z, w, Hs, nu, dY, nubar, tag):  # pragma: no cover - compiled
    """The 3-D range / azimuth / elevation radar's ``linearise_rows`` (no range rate) into
    the caller's arrays ``Hs`` (M, 3, n), ``nu`` (M, 3), ``dY`` (M, 3), ``nubar`` (3,)
    (C-contiguous), the formulas of :meth:`~uavest.models.radar.RadarMeasurement.h`,
    ``H_rows``, ``mean`` and ``residual`` in 3-D:

    * D_j = R_ws^T (p_j - position) (m, sensor frame), range |D_j|, azimuth
      atan2(D_y, D_x), elevation atan2(D_z, rho_j), rho_j = |(D_x, D_y)| (rad);
    * the Jacobian rows (sensor frame, then times R_ws^T on the right) D / r,
      [-D_y, D_x, 0] / rho^2 and [-D_x D_z / (r^2 rho), -D_y D_z / (r^2 rho), rho / r^2]
      with r^2 and rho^2 floored at ``eps2``;
    * the weighted mean: the range and the elevation arithmetic, the azimuth circular
      from sin a_j = D_y / rho_j, cos a_j = D_x / rho_j (``math.sin`` / ``math.cos`` of
      the angle, and ``math.hypot`` for rho, where rho_j^2 is outside [1e-300, 1e300] or
      not finite);
    * the residuals with the azimuth wrapped to [-pi, pi) (:func:`_wrap_fast`, the
      modulo where it is outside its range).

    ``X`` (M, >= 3): target states (world ENU, positions in columns 0..2, m). ``pose``:
    the tuple (px, py, pz, R00, R01, R02, R10, ..., R22, eps2) of the antenna position
    (m, world), the world-from-sensor rotation R_ws row-major and the floor of r^2 and
    rho^2 (m^2). ``z`` (3,): range (m), azimuth, elevation (rad). ``w`` (M,): the
    weights. ``tag``: any tuple of n floats (n the tangent dimension; the columns past 2
    of ``Hs`` are zero)."""
    px, py, pz, c00, c01, c02, c10, c11, c12, c20, c21, c22, eps2 = pose
    z0 = z[0]
    z1 = z[1]
    z2 = z[2]
    n = len(tag)
    M = X.shape[0]
    T = np.empty((18, M))  # D (3), range, azimuth, elevation, sin, cos, 9 H entries, rho
    Dx = T[0]
    Dy = T[1]
    Dz = T[2]
    rg = T[3]
    az = T[4]
    el = T[5]
    sn = T[6]
    cs = T[7]
    rh = T[17]
    for j in range(M):  # D = (p - s) @ R_ws, summed onto +0 as the BLAS product does
        ex = X[j, 0] - px
        ey = X[j, 1] - py
        ez = X[j, 2] - pz
        Dx[j] = ((0.0 + ex * c00) + ey * c10) + ez * c20
        Dy[j] = ((0.0 + ex * c01) + ey * c11) + ez * c21
        Dz[j] = ((0.0 + ex * c02) + ey * c12) + ez * c22
    iq_floor = 1.0 / math.sqrt(eps2)
    odd = 0
    for j in range(M):  # no calls, no branches but selects
        dx = Dx[j]
        dy = Dy[j]
        dz = Dz[j]
        hh = dx * dx + dy * dy
        rr = hh + dz * dz
        rho = math.sqrt(hh)
        irho = 1.0 / rho
        rg[j] = math.sqrt(rr)
        rh[j] = rho
        az[j] = atan2(dy, dx)
        el[j] = atan2(dz, rho)
        sn[j] = dy * irho
        cs[j] = dx * irho
        odd += (hh < _RR_LO) | (hh > _RR_HI) | (hh != hh) | (rr > _RR_HI)
        # the floored r^2, rho^2 (a NaN stays NaN, as np.maximum's) and rho
        r2 = eps2 if rr < eps2 else rr
        q2 = eps2 if hh < eps2 else hh
        iqr = 1.0 / math.sqrt(r2)
        iq2 = 1.0 / q2
        qf = iq_floor if hh < eps2 else irho  # 1 / floored rho
        rf = q2 * qf  # floored rho = rho2 / rho
        ir2 = 1.0 / r2
        g0 = dx * iqr
        g1 = dy * iqr
        g2 = dz * iqr
        a0 = -dy * iq2
        a1 = dx * iq2
        t = dz * (ir2 * qf)
        e0 = -dx * t
        e1 = -dy * t
        e2 = rf * ir2
        # g @ R_ws^T: row i, column k = sum_l g_l R_kl
        T[8, j] = (g0 * c00 + g1 * c01) + g2 * c02
        T[9, j] = (g0 * c10 + g1 * c11) + g2 * c12
        T[10, j] = (g0 * c20 + g1 * c21) + g2 * c22
        T[11, j] = a0 * c00 + a1 * c01
        T[12, j] = a0 * c10 + a1 * c11
        T[13, j] = a0 * c20 + a1 * c21
        T[14, j] = (e0 * c00 + e1 * c01) + e2 * c02
        T[15, j] = (e0 * c10 + e1 * c11) + e2 * c12
        T[16, j] = (e0 * c20 + e1 * c21) + e2 * c22
    if odd:  # members on the sensor's z axis (within 1e-150 m), far or not finite
        for j in range(M):
            dx = Dx[j]
            dy = Dy[j]
            hh = dx * dx + dy * dy
            if not (_RR_LO <= hh <= _RR_HI and hh + Dz[j] * Dz[j] <= _RR_HI):
                a = math.atan2(dy, dx)
                rho = math.hypot(dx, dy)
                az[j] = a
                sn[j] = math.sin(a)
                cs[j] = math.cos(a)
                rh[j] = rho
                el[j] = math.atan2(Dz[j], rho)
    nu3 = nu.reshape(3 * M)
    dY3 = dY.reshape(3 * M)
    s0, m1 = _range_azimuth(rg, az, sn, cs, w, z0, z1, nu3, dY3, 3)
    s2 = 0.0  # the elevation's mean (arithmetic) and residuals
    for j in range(M):
        s2 += w[j] * el[j]
    for j in range(M):
        nu3[3 * j + 2] = z2 - el[j]
        dY3[3 * j + 2] = el[j] - s2
    H3 = Hs.reshape(3 * n * M)
    for j in range(M):
        for i in range(3):
            b = (3 * j + i) * n
            for k in range(3):
                H3[b + k] = T[8 + 3 * i + k, j]
            for k in range(3, n):
                H3[b + k] = 0.0
    nubar[0] = z0 - s0
    nubar[1] = wrap_pi(z1 - m1)
    nubar[2] = z2 - s2
