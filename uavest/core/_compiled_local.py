"""Compiled (numba) kernels of :meth:`uavest.core.hybrid.HybridLocal.update` on a vector
space: the optional fast path (``pip install "uavest[fast]"``), chosen by measurement
(docs/speed.md, "Radar hybrid").

The numpy update costs a few dozen array operations per step on (M, m, n) stacks of
M = 585 members (the ``radar`` preset), each paying numpy's per-call floor; here each
stage is one loop over the members. The formulas are those of the numpy path in
:mod:`uavest.core.hybrid` (``_innovation_stack`` and ``HybridLocal.update``): S_j's
inverse and log-determinant in closed form for m <= 2 (from the shared Cholesky factor
for m >= 3, where the numpy path takes LAPACK's ``inv`` and ``slogdet``: the 3-D radar's
range / azimuth / elevation), the local gains, the
log-likelihood weights, the posterior draw, the predict's process noise, and the
ensemble moments of ``ensemble_moments`` (:mod:`uavest.core.states`). The kernels draw
their normals and uniforms from the caller's ``numpy.random.Generator`` itself, through
numba's implementation of numpy's algorithms: the numpy path's values in its order,
about 3.5x faster per normal than numpy's own call here (docs/speed.md). Equal to the
numpy path to rounding (``tests/unit/test_hybrid_local_compiled.py``). Importing this
module imports numba and compiles nothing; each kernel compiles at its first call
(cached on disk by numba).

Shapes: M members, n state (tangent) dimension, m >= 1 measurement components; all
arrays float64 (``idx`` int64). Units are the state's and the measurement's own (the
radar: m, m/s, rad).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np
from numba import njit
from numba.np.random.distributions import random_standard_normal
from numba.np.random.generator_core import next_double

from ..compiled.helpers import bitgen, chol_n

__all__ = ["add_noise", "centres", "local_draw", "local_gains", "local_update", "moments",
           "prior_moments",
           "systematic_indices", "tag"]

#: LLVM may fuse a * b + c into one rounding (FMA): the results stay equal to the numpy
#: path to rounding; no flag that assumes finite values (the NaN checks must hold).
_FM = {"contract"}

Array = np.ndarray
#: local_update's outputs: members, moments (x, dX, P), weights, Pyy, resampled, status
_Update = tuple[Array, Array, Array, Array, Array, Array, bool, int]


@lru_cache(maxsize=16)
def tag(n: int) -> tuple[float, ...]:
    """The tuple of n zeros that the kernels take as their ``tag`` argument (and of m
    zeros as ``mtag``, the measurement's size): its length is part of its numba type, so
    each kernel compiles once per state dimension n (and m) with n a constant (its loops
    over the state components unrolled), not once per call."""
    return (0.0,) * n


@njit(cache=True, fastmath=_FM)
def moments(X: Array, w: Array, tag: tuple[float, ...]
            ) -> tuple[Array, Array, Array]:  # pragma: no cover - compiled
    """Weighted mean ``x`` (n,), deviations ``dX`` = X - x (M, n) and covariance
    ``P`` = sum_j w_j dX_j dX_j^T / max(1 - sum_j w_j^2, 1e-12) (n, n), symmetric by
    construction (:func:`uavest.core.states.ensemble_moments` on a vector space). ``tag``:
    any tuple of n floats (see :func:`tag`). The sum of outer products is one BLAS
    product (w dX)^T dX, as the numpy path forms it: half the time of the loop here."""
    n = len(tag)
    M = X.shape[0]
    x = np.zeros(n)
    for j in range(M):
        for k in range(n):
            x[k] += w[j] * X[j, k]
    dX = np.empty((M, n))
    dW = np.empty((n, M))  # (w dX)^T
    s2 = 0.0
    for j in range(M):
        wj = w[j]
        s2 += wj * wj
        for k in range(n):
            d = X[j, k] - x[k]
            dX[j, k] = d
            dW[k, j] = wj * d
    P = np.dot(dW, dX)
    den = max(1.0 - s2, 1e-12)
    for k in range(n):
        for i in range(k + 1):
            P[k, i] /= den
            P[i, k] = P[k, i]
    return x, dX, P


@njit(cache=True, fastmath=_FM)
def centres(x: Array, dX: Array, a: float, tag: tuple[float, ...]
            ) -> Array:  # pragma: no cover - compiled
    """Mixture centres C_j = x + a dX_j (M, n) (the kernel's shrink towards the mean)."""
    n = len(tag)
    M = dX.shape[0]
    C = np.empty((M, n))
    for j in range(M):
        for k in range(n):
            C[j, k] = x[k] + a * dX[j, k]
    return C


@njit(cache=True, fastmath=_FM)
def prior_moments(X: Array, w: Array, a: float, tag: tuple[float, ...]
                  ) -> tuple[Array, Array, Array, Array]:  # pragma: no cover - compiled
    """:func:`moments` and :func:`centres` of them in one call: x, dX, P, C."""
    x, dX, P = moments(X, w, tag)
    return x, dX, P, centres(x, dX, a, tag)


@njit(cache=True, fastmath=_FM)
def local_gains(Hs: Array, B: Array, R: Array, nu: Array, dY: Array, w: Array,
                confidence: bool, tag: tuple[float, ...], mtag: tuple[float, ...]
                ) -> tuple[Array, Array, Array, Array, int]:  # pragma: no cover - compiled
    """Innovation covariances and confidence weights of the Gaussian-mixture update
    (any m >= 1).

    Per member j: ``HB`` (M, m, n) = H_j B and S_j = H_j B H_j^T + R, returned as its
    inverse's entries ``Si`` (M, max(3, m^2)): for m = 1 and 2 (closed form, as the
    numpy path's ``_innovation_stack``) (S^-1)_00, (S^-1)_11, (S^-1)_01 (m = 1: the
    first only); for m >= 3 the full inverse row-major, (S^-1)_ab at a m + b, from the
    Cholesky factor S_j = L L^T of :func:`uavest.compiled.helpers.chol_n` (S^-1 =
    L^-T L^-1, det S_j = prod L_aa^2). The local gain is K_j = (H_j B)^T S_j^-1. If
    ``confidence``, the weights w_j N(nu_j; 0, S_j), normalised (``wu`` (M,); otherwise
    a copy of ``w``). ``Pyy`` (m, m) = sum_j w_j (dY_j dY_j^T + S_j) with the prior
    weights: the innovation covariance. ``status`` is 1 if B is not finite or some S_j
    not positive definite (variance or determinant <= 0, or NaN; m >= 3: a Cholesky
    pivot not in (0, inf)), else 0; the other outputs are then meaningless. Terms with
    H_j entries equal to zero are skipped (the radar's velocity columns): the same sums.
    ``tag`` / ``mtag``: tuples of n and m floats (:func:`tag`; m = Hs.shape[1]), so that
    n and m are constants of each compiled version (the loops over the components
    unrolled, the branches on m folded)."""
    n = len(tag)
    m = len(mtag)
    M = Hs.shape[0]
    HB = np.empty((M, m, n))
    Si = np.empty((M, max(3, m * m)))
    t = np.empty(M)  # -1/2 nu_j^T S_j^-1 nu_j
    r = np.empty(M)  # max(w_j, 1e-300) / sqrt(det S_j)
    Pyy = np.zeros((m, m))
    S = np.empty((m, m))  # m >= 3: S_j, its factor and the factor's inverse
    L = np.empty((m, m))
    Li = np.empty((m, m))
    status = 0
    for c in range(n):
        for k in range(n):
            if not math.isfinite(B[c, k]):
                status = 1
    mx = -np.inf
    for j in range(M):
        for a in range(m):
            for k in range(n):
                HB[j, a, k] = 0.0
            for c in range(n):
                h = Hs[j, a, c]
                if h != 0.0:
                    for k in range(n):
                        HB[j, a, k] += h * B[c, k]
        s00 = R[0, 0]
        for k in range(n):
            s00 += HB[j, 0, k] * Hs[j, 0, k]
        wj = w[j]
        if m == 1:
            det = s00
            if not det > 0.0:
                status = 1
                det = 1.0
            i00 = 1.0 / det
            Si[j, 0] = i00
            n0 = nu[j, 0]
            q = n0 * n0 * i00
            d0 = dY[j, 0]
            Pyy[0, 0] += wj * (d0 * d0 + s00)
            sq = math.sqrt(det)
        elif m == 2:
            s11 = R[1, 1]
            s01 = R[0, 1]
            for k in range(n):
                s11 += HB[j, 1, k] * Hs[j, 1, k]
                s01 += HB[j, 0, k] * Hs[j, 1, k]
            det = s00 * s11 - s01 * s01
            if not det > 0.0:
                status = 1
                det = 1.0
            i = 1.0 / det
            i00 = s11 * i
            i11 = s00 * i
            i01 = -s01 * i
            Si[j, 0] = i00
            Si[j, 1] = i11
            Si[j, 2] = i01
            n0 = nu[j, 0]
            n1 = nu[j, 1]
            q = n0 * (i00 * n0 + i01 * n1) + n1 * (i01 * n0 + i11 * n1)
            d0 = dY[j, 0]
            d1 = dY[j, 1]
            Pyy[0, 0] += wj * (d0 * d0 + s00)
            Pyy[1, 1] += wj * (d1 * d1 + s11)
            Pyy[0, 1] += wj * (d0 * d1 + s01)
            sq = math.sqrt(det)
        else:  # m >= 3: the Cholesky factor, its inverse, S^-1 = Li^T Li
            for a in range(m):
                for b in range(a + 1):
                    s = R[a, b]
                    for k in range(n):
                        s += HB[j, a, k] * Hs[j, b, k]
                    S[a, b] = s
                    S[b, a] = s
            # the shared factor: a failed pivot is set to 1, so the inverse below cannot
            # divide by zero (the outputs are then not read: the caller raises)
            if not chol_n(S, L, m):
                status = 1
            sq = 1.0
            for a in range(m):  # Li = L^-1 (lower), column by column
                sq *= L[a, a]
                for b in range(a + 1):
                    s = 1.0 if a == b else 0.0
                    for k in range(b, a):
                        s -= L[a, k] * Li[k, b]
                    Li[a, b] = s / L[a, a]
                for b in range(a + 1, m):
                    Li[a, b] = 0.0
            q = 0.0
            for a in range(m):
                for b in range(a + 1):
                    s = 0.0
                    for k in range(a, m):  # (Li^T Li)_ab = sum_k Li_ka Li_kb, k >= a
                        s += Li[k, a] * Li[k, b]
                    Si[j, a * m + b] = s
                    Si[j, b * m + a] = s
            for a in range(m):
                na = nu[j, a]
                da = dY[j, a]
                s = 0.0
                for b in range(m):
                    s += Si[j, a * m + b] * nu[j, b]
                    Pyy[a, b] += wj * (da * dY[j, b] + S[a, b])
                q += na * s
        if confidence:
            tj = -0.5 * q
            t[j] = tj
            r[j] = max(wj, 1e-300) / sq
            if tj > mx or tj != tj:  # a NaN sticks (tj > NaN is False), as in numpy
                mx = tj
    if m == 2:
        Pyy[1, 0] = Pyy[0, 1]
    if not confidence:
        return HB, Si, Pyy, w.copy(), status
    # w_j |S_j|^-1/2 exp(t_j) normalised: the numpy path's exp(log w + loglik - max) with
    # one exponential per member and no logarithm; the log domain if that under/overflows
    wu = np.empty(M)
    tot = 0.0
    for j in range(M):
        e = r[j] * math.exp(t[j] - mx)
        wu[j] = e
        tot += e
    if not 1e-250 < tot < 1e250:
        mx = -np.inf
        for j in range(M):
            t[j] += math.log(r[j])
            if t[j] > mx or t[j] != t[j]:
                mx = t[j]
        tot = 0.0
        for j in range(M):
            e = math.exp(t[j] - mx)
            wu[j] = e
            tot += e
    for j in range(M):
        wu[j] /= tot
    return HB, Si, Pyy, wu, status


@njit(cache=True)
def systematic_indices(w: Array, u: float) -> Array:  # pragma: no cover - compiled
    """:func:`uavest.core.resample.systematic_resample`'s indices for the uniform draw
    ``u``: the first j with cs_j >= (u + i) / M, cs the running sum of ``w`` (its last
    entry set to 1), by one merge of the two sorted sequences instead of M binary
    searches (the same sums in the same order, no fast-math: the same indices).
    Returns -1 in the first entry if the weights are not finite."""
    M = w.shape[0]
    cs = np.empty(M)
    s = 0.0
    for j in range(M):
        s += w[j]
        cs[j] = s
    idx = np.empty(M, dtype=np.int64)
    if not math.isfinite(s):
        idx[0] = -1
        return idx
    cs[M - 1] = 1.0
    step = 1.0 / M
    j = 0
    for i in range(M):
        t = (u + i) * step
        while j < M and cs[j] < t:
            j += 1
        idx[i] = j
    return idx


@njit(cache=True, fastmath=_FM)
def local_draw(C: Array, HB: Array, Si: Array, Hs: Array, nu: Array, En: Array, Lb: Array,
               Vn: Array, Lr: Array, idx: Array, resample: bool, wp: Array,
               tag: tuple[float, ...], mtag: tuple[float, ...]
               ) -> tuple[Array, Array, Array, Array]:  # pragma: no cover - compiled
    """Posterior members and their moments.

    Member i is drawn from component j (j = idx[i] if ``resample`` else i) as
    X_i = C_j + e_i + K_j (nu_j + v_i - H_j e_i), K_j = (H_j B)^T S_j^-1 (``HB``, ``Si``
    of :func:`local_gains`), with e_i = Lb En_i ~ N(0, B) and v_i = Lr Vn_i ~ N(0, R)
    from the caller's standard normals ``En`` (M, n), ``Vn`` (M, m) and lower factors
    ``Lb``, ``Lr``: a draw from N(C_j + K_j nu_j, B - K_j H_j B). Returns ``X`` (M, n) and
    :func:`moments` of it under the posterior weights ``wp`` (M,). ``tag``, ``mtag``: as
    :func:`local_gains`."""
    n = len(tag)
    m = len(mtag)
    M = HB.shape[0]
    X = np.empty((M, n))
    e = np.empty(n)
    dv = np.empty(m)  # m > 2: d and S^-1 d
    gv = np.empty(m)
    for i in range(M):
        j = idx[i] if resample else i
        for k in range(n):
            s = 0.0
            for c in range(k + 1):
                s += En[i, c] * Lb[k, c]
            e[k] = s
        # d = nu_j + v_i - H_j e_i, then g = S_j^-1 d
        if m > 2:  # the full inverse (local_gains): d, g = S^-1 d, X_i
            for a in range(m):
                s = 0.0
                for c in range(n):
                    h = Hs[j, a, c]
                    if h != 0.0:
                        s += h * e[c]
                v = 0.0
                for b in range(a + 1):
                    v += Vn[i, b] * Lr[a, b]
                dv[a] = nu[j, a] + v - s
            for a in range(m):
                s = 0.0
                for b in range(m):
                    s += Si[j, a * m + b] * dv[b]
                gv[a] = s
            for k in range(n):
                s = 0.0
                for a in range(m):
                    s += gv[a] * HB[j, a, k]
                X[i, k] = C[j, k] + (e[k] + s)
            continue
        s = 0.0
        for c in range(n):
            h = Hs[j, 0, c]
            if h != 0.0:
                s += h * e[c]
        d0 = nu[j, 0] + Vn[i, 0] * Lr[0, 0] - s
        if m == 1:
            g0 = Si[j, 0] * d0
            for k in range(n):
                X[i, k] = C[j, k] + (e[k] + g0 * HB[j, 0, k])
        else:
            s = 0.0
            for c in range(n):
                h = Hs[j, 1, c]
                if h != 0.0:
                    s += h * e[c]
            d1 = nu[j, 1] + (Vn[i, 0] * Lr[1, 0] + Vn[i, 1] * Lr[1, 1]) - s
            g0 = Si[j, 0] * d0 + Si[j, 2] * d1
            g1 = Si[j, 2] * d0 + Si[j, 1] * d1
            for k in range(n):
                X[i, k] = C[j, k] + (e[k] + (g0 * HB[j, 0, k] + g1 * HB[j, 1, k]))
    x, dX, P = moments(X, wp, tag)
    return X, x, dX, P


@njit(cache=True)
def _no_draw(n: int, wu: Array, Pyy: Array, resampled: bool, status: int
             ) -> _Update:  # pragma: no cover
    """:func:`local_update`'s outputs when it stops before drawing (empty members and
    moments, not read: the caller raises on ``status``)."""
    X = np.empty((0, n))
    return X, np.empty(n), X, np.empty((n, n)), wu, Pyy, resampled, status


@njit(cache=True, fastmath=_FM)
def local_update(bits: Array, C: Array, Hs: Array, B: Array, R: Array, nu: Array, dY: Array,
                 w: Array, confidence: bool, regen_ess: float, Lb: Array, Lr: Array,
                 tag: tuple[float, ...], mtag: tuple[float, ...]
                 ) -> _Update:  # pragma: no cover
    """The whole update after the model's terms, the draws included: :func:`local_gains`,
    the effective sample size of the updated weights, :func:`systematic_indices` if it is
    < ``regen_ess`` M, and :func:`local_draw` with the standard normals ``En`` (M, n)
    then ``Vn`` (M, m) drawn here from the caller's ``numpy.random.Generator`` (``bits``:
    its :func:`uavest.compiled.bitgen_pointers`; numba's draws are numpy's,
    value for value, and leave the generator in the same state). The draws come in the
    numpy path's order: the resampling uniform (if any), ``En``, ``Vn``.

    Returns ``X``, ``x``, ``dX``, ``P`` (the posterior members and their moments under the
    posterior weights), ``wu`` (the updated weights), ``Pyy`` (the innovation covariance),
    ``resampled`` and ``status``: 0, 1 if B is not finite or some S_j is not positive
    definite, 2 if the weights to resample are not finite (nothing drawn then).
    ``tag``, ``mtag``: tuples of n and m floats (:func:`local_gains`)."""
    n = len(tag)
    m = len(mtag)
    M = Hs.shape[0]
    HB, Si, Pyy, wu, status = local_gains(Hs, B, R, nu, dY, w, confidence, tag, mtag)
    if status:
        return _no_draw(n, wu, Pyy, False, status)
    s2 = 0.0
    for j in range(M):
        s2 += wu[j] * wu[j]
    resample = 1.0 / s2 < regen_ess * M
    bg: Any = bitgen(bits[0], bits[1], bits[2], bits[3])  # type: ignore[call-arg]
    if resample:
        idx = systematic_indices(wu, next_double(bg))
        if idx[0] < 0:
            return _no_draw(n, wu, Pyy, True, 2)
    else:
        idx = np.zeros(0, dtype=np.int64)
    En = np.empty((M, n))
    for i in range(M):
        for k in range(n):
            En[i, k] = random_standard_normal(bg)
    Vn = np.empty((M, m))
    for i in range(M):
        for k in range(m):
            Vn[i, k] = random_standard_normal(bg)
    if resample or not confidence:
        wp = np.full(M, 1.0 / M)
    else:
        wp = wu
    X, x, dX, P = local_draw(C, HB, Si, Hs, nu, En, Lb, Vn, Lr, idx, resample, wp, tag,
                              mtag)
    return X, x, dX, P, wu, Pyy, resample, 0


@njit(cache=True, fastmath=_FM)
def add_noise(bits: Array, X: Array, L: Array, tag: tuple[float, ...]
              ) -> Array:  # pragma: no cover - compiled
    """X_j + L z_j with z_j ~ N(0, I) (n,) drawn here from the generator of ``bits``
    (:func:`uavest.compiled.bitgen_pointers`), member after member
    (numpy's ``rng.standard_normal((M, n))`` values in its order): the process noise of
    :func:`uavest.core.ensemble.propagate_members` on a vector space, ``L`` its lower
    factor (n, n)."""
    n = len(tag)
    M = X.shape[0]
    out = np.empty((M, n))
    z = np.empty(n)
    bg: Any = bitgen(bits[0], bits[1], bits[2], bits[3])  # type: ignore[call-arg]
    for j in range(M):
        for k in range(n):
            z[k] = random_standard_normal(bg)
        for k in range(n):
            s = 0.0
            for c in range(k + 1):
                s += L[k, c] * z[c]
            out[j, k] = X[j, k] + s
    return out
