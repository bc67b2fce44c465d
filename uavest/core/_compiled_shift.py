"""Compiled (numba) kernels of the default hybrid (:class:`uavest.core.hybrid.HybridShift`,
shift update) on a vector state space, and its reinflated update on a manifold: the
optional fast path (``pip install "uavest[fast]"``), dispatched through
:data:`uavest.core.hybrid.SHIFT_KERNELS`.

On the UNGM (99 members) the hybrid's step was numpy's per-call floor (~60 calls of ~1 us,
docs/speed.md), not arithmetic. These kernels do the work between the model's ``f`` /
``h`` calls and the random draws in one call each, with the same formulas as the numpy
path in :mod:`uavest.core.hybrid` (which stays the reference and the fallback):

* :func:`regenerate`: the ensemble's moments, systematic selection with the uniform ``u``,
  the shrink kernel with the normals ``Z`` (``_HybridBase._regenerate``);
* :func:`shift_update`: the innovation record, the tempered confidence weights, the EnKF
  shift with the normals ``V`` and the moments of the result (``HybridShift.update`` with one
  stage and one shift, and ``ensemble_estimate`` of its result);
* :func:`shift_tangent`: the same update on a manifold with ``reinflate`` (the navigation
  preset's hybrid, 527 members of 16 components), up to the new members' tangent vectors
  at the prior's mean (the caller retracts them through the space's row kernels).

The random numbers are drawn by the caller in numpy, in the order and shapes the numpy path
draws them, so the random path is the numpy path's. Sums run in index order (numpy's
reductions and BLAS may group and fuse them differently), ``exp`` / ``log`` are libm's
(numpy's may be its SIMD ones): the kernels equal the numpy path to rounding
(tests/unit/test_fast_paths.py). Small factorisations are written out; 1 x 1 ones are the
square root and the products by its reciprocal that LAPACK performs (as
:mod:`uavest.core.linalg`'s shortcuts). Importing this module imports numba and compiles
nothing; each kernel compiles at its first call (cached on disk by numba).

Every kernel returns a status first: 0 on success, else the numpy path decides what
happens (see the callers).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..compiled.helpers import chol_into, factor, solve_lower, wrap_pi

__all__ = ["add_noise", "chol_jitter", "regenerate", "shift_tangent", "shift_update"]

_OK, _NONFINITE, _NOT_PD = 0, 1, 2

Array = np.ndarray


@njit(cache=True)
def chol_jitter(P: Array) -> tuple[int, Array]:  # pragma: no cover - compiled
    """(status, L): :func:`uavest.core.linalg.chol` of ``P`` (n, n): the plain factor, else
    non-finite entries (status 1), else diagonal jitter from 1e-12 * mean|diag| growing
    x100 over six tries (status 2 if all fail)."""
    n = P.shape[0]
    L = np.zeros((n, n))
    if n == 1:  # the 1 x 1 shortcut of linalg.chol
        p = P[0, 0]
        if 0.0 < p < math.inf:
            L[0, 0] = math.sqrt(p)
            return _OK, L
    elif chol_into(P, L):
        return _OK, L
    for i in range(n):
        for j in range(i + 1):
            if not math.isfinite(P[i, j]):
                return _NONFINITE, L
    S = 0.5 * (P + P.T)
    scale = 0.0
    for i in range(n):
        scale += abs(S[i, i])
    scale /= n
    if scale == 0.0:
        scale = 1.0
    jitter = 1e-12 * scale
    for _ in range(6):
        J = S.copy()
        for i in range(n):
            J[i, i] += jitter
        if chol_into(J, L):
            return _OK, L
        jitter *= 100.0
    return _NOT_PD, L


@njit(cache=True)
def _moments(X: Array, w: Array) -> tuple[Array, Array, Array]:  # pragma: no cover - compiled
    """Weighted mean x (n,), deviations dX (M, n) and the reliability-weighted covariance
    sum w dX dX^T / max(1 - sum w^2, 1e-12), symmetric (``base.ensemble_moments`` on a
    vector space, with ``ensemble_estimate``'s symmetrising)."""
    M, n = X.shape
    x = np.zeros(n)
    ww = 0.0
    for j in range(M):
        wj = w[j]
        ww += wj * wj
        for i in range(n):
            x[i] += wj * X[j, i]
    dX = np.empty((M, n))
    for j in range(M):
        for i in range(n):
            dX[j, i] = X[j, i] - x[i]
    P = np.zeros((n, n))
    for j in range(M):
        wj = w[j]
        for i in range(n):
            a = dX[j, i] * wj
            for k in range(i + 1):
                P[i, k] += a * dX[j, k]
    den = max(1.0 - ww, 1e-12)
    for i in range(n):
        for k in range(i + 1):
            P[i, k] = P[i, k] / den
            P[k, i] = P[i, k]
    return x, dX, P


@njit(cache=True)
def regenerate(X: Array, w: Array, u: float, Z: Array, h: float, out: Array
               ) -> int:  # pragma: no cover - compiled
    """Status; ``out`` (M, n) <- the members regenerated around the credible ones.
    Systematic selection idx_i = first j with cumsum(w)_j >= (u + i) / M (the last sum set
    to 1), then X'_i = x + (a dX_idx_i + Z_i (h L)^T) with a = sqrt(1 - h^2), L = chol(P),
    (x, dX, P) the weighted moments. Status 1 / 2: the covariance is not finite / not
    positive definite even with jitter (what ``chol`` raises)."""
    M, n = X.shape
    if n == 1:
        return _regenerate_1d(X, w, u, Z, h, out)
    x, dX, P = _moments(X, w)
    st, L = chol_jitter(P)
    if st != _OK:
        return st
    cs = np.empty(M)
    s = 0.0
    for j in range(M):
        s += w[j]
        cs[j] = s
    cs[M - 1] = 1.0
    a = math.sqrt(1.0 - h * h)
    hL = h * L
    inv = 1.0 / M
    j = 0
    for i in range(M):
        target = (u + i) * inv
        while j < M - 1 and cs[j] < target:
            j += 1
        for k in range(n):
            jit = 0.0
            for q in range(k + 1):
                jit += Z[i, q] * hL[k, q]
            out[i, k] = x[k] + (a * dX[j, k] + jit)
    return _OK


@njit(cache=True)
def add_noise(X: Array, Z: Array, L: Array, out: Array) -> None:  # pragma: no cover - compiled
    """``out`` <- X + Z L^T (``propagate_members``' process noise with the lower factor
    ``L`` of Q; 1-D: X + Z l, the one product per member that BLAS makes too)."""
    M, n = X.shape
    if n == 1:
        lq = L[0, 0]
        for j in range(M):
            out[j, 0] = X[j, 0] + Z[j, 0] * lq
        return
    for j in range(M):
        for i in range(n):
            s = 0.0
            for k in range(i + 1):
                s += Z[j, k] * L[i, k]
            out[j, i] = X[j, i] + s


@njit(cache=True)
def _regenerate_1d(X: Array, w: Array, u: float, Z: Array, h: float, out: Array
                   ) -> int:  # pragma: no cover - compiled
    """:func:`regenerate` of a 1-D state, on scalars (accumulators in registers)."""
    M = X.shape[0]
    x = 0.0
    ww = 0.0
    for j in range(M):
        x += w[j] * X[j, 0]
        ww += w[j] * w[j]
    p = 0.0
    for j in range(M):
        d = X[j, 0] - x
        p += d * w[j] * d
    p /= max(1.0 - ww, 1e-12)
    P = np.empty((1, 1))
    P[0, 0] = p
    st, L = chol_jitter(P)
    if st != _OK:
        return st
    hl = h * L[0, 0]
    a = math.sqrt(1.0 - h * h)
    inv = 1.0 / M
    j = 0
    cs = w[0]
    for i in range(M):
        target = (u + i) * inv
        while j < M - 1 and cs < target:
            j += 1
            cs = 1.0 if j == M - 1 else cs + w[j]
        out[i, 0] = x + (a * (X[j, 0] - x) + Z[i, 0] * hl)
    return _OK


#: ``hybrid._PHI_GRID``: the tempering exponents as fractions of the share, 0 to 1
_GRID = np.linspace(0.0, 1.0, 17)


@njit(cache=True)
def _normalised(logw0: Array, ll: Array, phi: float, W: Array
                ) -> None:  # pragma: no cover - compiled
    """``W`` <- exp(L - max L) / sum, L = logw0 + phi ll (non-finite entries propagate:
    the caller checks the sum)."""
    M = logw0.shape[0]
    top = -math.inf
    for j in range(M):
        W[j] = logw0[j] + phi * ll[j]
        if W[j] > top:
            top = W[j]
    s = 0.0
    for j in range(M):
        W[j] = math.exp(W[j] - top)
        s += W[j]
    for j in range(M):
        W[j] /= s


@njit(cache=True)
def _tempered(w: Array, ll: Array, phi_max: float, min_ess: float, W: Array
              ) -> float:  # pragma: no cover - compiled
    """phi; ``W`` <- ``hybrid.tempered_weights``: w p^phi for the largest phi =
    phi_max * grid_g whose ESS stays >= min_ess M (the full share first, then the grid
    with its own test, as there; phi = 0 if none).

    The grid is not evaluated point by point (99 exps each, 11 points on average on the
    UNGM): the sums of squares of all 17 points come from one set of exps by the
    recursion a(g) = a(g-1) base / sum, base_j = exp(phi_max / 16 (ll_j - max ll)), a(0)
    the normalised w, which equals the direct evaluation to ~1e-13 (exponents of up to
    ~700 are the only ones with weight); a point whose test is that close to its
    threshold (1e-9) is evaluated directly, as numpy does. The chosen point's weights are
    then computed directly."""
    M = w.shape[0]
    logw0 = np.empty(M)
    for j in range(M):
        logw0[j] = math.log(max(w[j], 1e-300))
    floor = min_ess * M
    _normalised(logw0, ll, phi_max, W)
    q = 0.0
    for j in range(M):
        q += W[j] * W[j]
    if 1.0 / q >= floor:
        return phi_max
    G = _GRID.shape[0] - 1  # 16 steps of phi_max / 16 (the grid is g / 16 exactly)
    top = -math.inf
    for j in range(M):
        if ll[j] > top:
            top = ll[j]
    step = phi_max / G
    base = np.empty(M)
    a = np.empty(M)
    s1 = 0.0
    for j in range(M):
        base[j] = math.exp(step * (ll[j] - top))
        a[j] = max(w[j], 1e-300)
        s1 += a[j]
    ok = np.zeros(G + 1, np.bool_)
    if not (math.isfinite(s1) and s1 > 0.0):
        return _tempered_direct(logw0, ll, phi_max, floor, W)
    scale = 1.0 / s1
    for g in range(1, G + 1):
        s1 = 0.0
        s2 = 0.0
        for j in range(M):
            v = a[j] * base[j] * scale
            a[j] = v
            s1 += v
            s2 += v * v
        if not (math.isfinite(s1) and s1 > 0.0):
            return _tempered_direct(logw0, ll, phi_max, floor, W)
        scale = 1.0 / s1
        t = s2 * scale * scale * floor  # sum of squares of the normalised weights * floor
        if abs(t - 1.0) <= 1e-9:  # too close to call: as numpy does
            _normalised(logw0, ll, phi_max * _GRID[g], W)
            q = 0.0
            for j in range(M):
                q += W[j] * W[j]
            t = q * floor
        ok[g] = t <= 1.0
    for g in range(G, 0, -1):
        if ok[g]:
            phi: float = phi_max * _GRID[g]
            _normalised(logw0, ll, phi, W)
            return phi
    _normalised(logw0, ll, 0.0, W)
    return 0.0


@njit(cache=True)
def _tempered_direct(logw0: Array, ll: Array, phi_max: float, floor: float, W: Array
                     ) -> float:  # pragma: no cover - compiled
    """The grid of :func:`_tempered` point by point (the reference form; used when the
    recursion's sums are not usable)."""
    M = logw0.shape[0]
    for g in range(_GRID.shape[0] - 1, 0, -1):
        phi: float = phi_max * _GRID[g]
        _normalised(logw0, ll, phi, W)
        q = 0.0
        for j in range(M):
            q += W[j] * W[j]
        if q * floor <= 1.0:
            return phi
    _normalised(logw0, ll, 0.0, W)
    return 0.0


@njit(cache=True)
def _diff(a: float, b: float, angle: bool) -> float:  # pragma: no cover - compiled
    """A measurement's residual a - b, wrapped to [-pi, pi) for an angle."""
    return wrap_pi(a - b) if angle else a - b


@njit(cache=True)
def _mean_into(Y: Array, w: Array, angle: bool, out: Array
               ) -> None:  # pragma: no cover - compiled
    """``out`` <- the weighted mean of the rows of ``Y`` (M, m): sum w Y, or for angles
    ``MagHeading.mean``'s wrap(Y_0 + sum w wrap(Y - Y_0))."""
    M, m = Y.shape
    out[:] = 0.0
    for j in range(M):
        for a in range(m):
            out[a] += w[j] * (wrap_pi(Y[j, a] - Y[0, a]) if angle else Y[j, a])
    if angle:
        for a in range(m):
            out[a] = wrap_pi(Y[0, a] + out[a])


@njit(cache=True)
def _innovation(Y: Array, z: Array, w: Array, R: Array, nu: Array, S: Array,
                angle: bool) -> tuple[int, float]:  # pragma: no cover - compiled
    """(status, nis): the innovation ``nu`` (m,) and its covariance ``S`` (m, m) of the
    members' images ``Y`` (M, m) under their weights ``w``, and its NIS (``angle``: each
    component an angle, residuals wrapped)."""
    M, m = Y.shape
    ybar = np.zeros(m)
    _mean_into(Y, w, angle, ybar)
    S[:, :] = 0.0
    for j in range(M):
        for a in range(m):
            d = _diff(Y[j, a], ybar[a], angle) * w[j]
            for b in range(m):
                S[a, b] += d * _diff(Y[j, b], ybar[b], angle)
    for a in range(m):
        nu[a] = _diff(z[a], ybar[a], angle)
        for b in range(m):
            S[a, b] += R[a, b]
    ok, cS = factor(S)
    if not ok:
        return _NOT_PD, 0.0
    if m == 1:  # innovation()'s float form: v (v i i), i = 1 / sqrt(S)
        i1 = 1.0 / cS[0, 0]
        nis = nu[0] * (nu[0] * i1 * i1)
    else:
        v = solve_lower(cS, nu)
        nis = 0.0
        for a in range(m):
            nis += v[a] * v[a]
    if not math.isfinite(nis):
        return _NONFINITE, nis
    return _OK, nis


@njit(cache=True)
def _weights(r: Array, w: Array, R: Array, tau: float, min_ess: float, confidence: bool,
             W: Array) -> tuple[int, float]:  # pragma: no cover - compiled
    """(status, share): ``W`` <- the tempered confidence weights of the residuals ``r``
    (M, m) under ``R`` (or ``w`` itself without confidence weights), and the share of the
    measurement left to the EnKF shift."""
    M, m = r.shape
    ok, LR = factor(R)
    if not ok:
        return _NOT_PD, 1.0
    if not confidence:
        W[:] = w
        return _OK, 1.0
    ll = np.empty(M)
    u = np.empty(m)
    for j in range(M):
        if m == 1:
            t = r[j, 0] * (1.0 / LR[0, 0])
            ll[j] = -0.5 * (t * t)
        else:  # solve_lower(LR, r[j]) into one scratch row (not an array per member)
            q = 0.0
            for a in range(m):
                t = r[j, a]
                for k in range(a):
                    t -= LR[a, k] * u[k]
                u[a] = t / LR[a, a]
                q += u[a] * u[a]
            ll[j] = -0.5 * q
    phi_max = 1.0 - tau
    phi = _tempered(w, ll, phi_max, min_ess, W)
    if not math.isfinite(W.sum()):
        return _NONFINITE, 1.0
    return _OK, tau + (phi_max - phi)


@njit(cache=True)
def _solve(cS: Array, b: Array, out: Array) -> None:  # pragma: no cover - compiled
    """``out`` <- S^-1 b through the lower factor ``cS`` of S (m, m): forward, then back
    substitution with cS^T (1 x 1: b times i i, i = 1 / cS_00, as gain() does)."""
    m = b.shape[0]
    if m == 1:
        i1 = 1.0 / cS[0, 0]
        out[0] = b[0] * i1 * i1
        return
    y1 = solve_lower(cS, b)
    for a in range(m - 1, -1, -1):
        t = y1[a]
        for k in range(a + 1, m):
            t -= cS[k, a] * out[k]
        out[a] = t / cS[a, a]


@njit(cache=True)
def _gain(cS: Array, Pyx: Array) -> Array:  # pragma: no cover - compiled
    """K (n, m) = Pxy S^-1 (gain()) from Pyx = Pxy^T (m, n) and the lower factor of S."""
    m, n = Pyx.shape
    K = np.empty((n, m))
    for i in range(n):
        _solve(cS, Pyx[:, i].copy(), K[i])
    return K


@njit(cache=True)
def _perturbed(r: Array, V: Array, Lr: Array, j: int, out: Array
               ) -> None:  # pragma: no cover - compiled
    """``out`` <- member j's perturbed residual r_j + chol(R') V_j (the shift's input)."""
    for a in range(out.shape[0]):
        pv = 0.0
        for b in range(a + 1):
            pv += V[j, b] * Lr[a, b]
        out[a] = r[j, a] + pv


@njit(cache=True)
def _prelude(Y: Array, z: Array, w: Array, R: Array, tau: float, min_ess: float,
             confidence: bool, W: Array, nu: Array, S: Array, angle: bool
             ) -> tuple[int, float, Array, float, float, Array, Array]:  # pragma: no cover
    """(status, nis, r, ww, c, R', chol(R')): what both updates do before the shift: the
    innovation of the predicted ensemble under its own weights (``nu``, ``S``, its NIS),
    the residuals r_j = z - Y_j (wrapped for an ``angle``), the tempered weights ``W``,
    ww = sum W^2, c = 1 / max(1 - ww, 1e-12), R' = R / share and its factor."""
    M, m = Y.shape
    r = np.empty((M, m))
    Lr = np.zeros((m, m))
    st, nis = _innovation(Y, z, w, R, nu, S, angle)
    if st:
        return st, nis, r, 0.0, 1.0, R * 1.0, Lr
    for j in range(M):
        for a in range(m):
            r[j, a] = _diff(z[a], Y[j, a], angle)
    st, share = _weights(r, w, R, tau, min_ess, confidence, W)
    if st:
        return st, nis, r, 0.0, 1.0, R * 1.0, Lr
    ww = 0.0
    for j in range(M):
        ww += W[j] * W[j]
    c = 1.0 / max(1.0 - ww, 1e-12)
    Rt = R * (1.0 / share)
    ok, Lr = factor(Rt)
    return (_OK if ok else _NOT_PD), nis, r, ww, c, Rt, Lr


@njit(cache=True)
def shift_update(X: Array, Y: Array, z: Array, w: Array, R: Array, V: Array, tau: float,
                 min_ess: float, confidence: bool, Xn: Array, W: Array, nu: Array, S: Array,
                 x: Array, P: Array) -> tuple[int, float]:  # pragma: no cover - compiled
    """(status, nis): one ``HybridShift.update`` with ``stages`` = 1 and ``shifts`` = 1 on a
    vector space with a plain measurement model, into the caller's arrays.

    ``X`` (M, n) members, ``Y`` = h(X) (M, m), ``z`` (m,), ``w`` (M,) their weights, ``R``
    (m, m), ``V`` (M, m) standard normals of the perturbed observations, ``tau`` the
    shift's share, ``min_ess`` the ESS floor / M, ``confidence`` False for equal weights
    (no tempering, the whole measurement shifted). Writes the shifted members ``Xn``
    (M, n), their weights ``W`` (M,), the innovation ``nu`` (m,) and ``S`` (m, m) of the
    predicted ensemble (its NIS returned) and the weighted mean ``x`` (n,) and covariance
    ``P`` (n, n) of the result (its estimate). (An array made here and returned costs
    numba ~1 us of boxing, one passed in ~0.1 us.) Status 1: a non-finite innovation
    variance, weight or result; 2: S, R or the shift's S not positive definite; the
    caller then runs the numpy path."""
    M, n = X.shape
    m = Y.shape[1]
    if n == 1 and m == 1:
        return _shift_1d(X, Y, z[0], w, R[0, 0], V, tau, min_ess, confidence, Xn, W, nu,
                         S, x, P)
    st, nis, r, _, c, Rt, Lr = _prelude(Y, z, w, R, tau, min_ess, confidence, W, nu, S,
                                        False)
    if st:
        return st, nis
    # the EnKF shift with R / share: K = Pxy S'^-1, Pxy = c sum w_j X_j dY_j^T (the
    # weighted dY sum to zero, so the mean of X is not needed)
    yb = np.zeros(m)
    for j in range(M):
        for a in range(m):
            yb[a] += W[j] * Y[j, a]
    Pyx = np.zeros((m, n))
    St = Rt.copy()
    St[:, :] = 0.0
    for j in range(M):
        cw = c * W[j]
        for a in range(m):
            A = (Y[j, a] - yb[a]) * cw
            for i in range(n):
                Pyx[a, i] += A * X[j, i]
            for b in range(m):
                St[a, b] += A * (Y[j, b] - yb[b])
    St += Rt
    ok, cSt = factor(St)
    if not ok:
        return _NOT_PD, nis
    K = _gain(cSt, Pyx)
    d = np.empty(m)
    for j in range(M):
        _perturbed(r, V, Lr, j, d)
        for i in range(n):
            s = 0.0
            for a in range(m):
                s += d[a] * K[i, a]
            Xn[j, i] = X[j, i] + s
    xm, _, Pm = _moments(Xn, W)
    for i in range(n):
        x[i] = xm[i]
        for k in range(n):
            P[i, k] = Pm[i, k]
        if not (math.isfinite(x[i]) and math.isfinite(P[i, i])):
            return _NONFINITE, nis
    return _OK, nis


@njit(cache=True)
def shift_tangent(L0: Array, Y: Array, z: Array, w: Array, R: Array, V: Array, tau: float,
                  min_ess: float, confidence: bool, T: Array, W: Array, nu: Array,
                  S: Array, angle: bool) -> tuple[int, float]:  # pragma: no cover - compiled
    """(status, nis): one ``HybridShift.update`` with ``reinflate``, ``stages`` = 1 and
    ``shifts`` = 1 on a manifold with a plain measurement model, up to the retraction:
    the members' new tangent vectors ``T`` (M, n) at the prior's mean x (the new members
    are retract(x, T_j)).

    ``L0`` (M, n): the prior members' deviations local(x, X_j) centred under ``w`` (the
    prior's memoised moments); the rest as :func:`shift_update`. With the weights ``W``
    after tempering, c = 1 / (1 - sum W^2), dY the images' deviations centred under W and
    dX = L0 - sum W L0: K = Pxy (Pyy + R')^-1, D_j = K (r_j + chol(R') V_j) + L0_j,
    d = sum W D, T_j = d + a (D_j - d) with a = sqrt(1 + tr((Pyy + R')^-1 Pyy) sum W^2)
    (``hybrid.sampling_shrink``). ``angle``: every component of the measurement is an
    angle (``Measurement.arithmetic`` "angle": residuals wrapped to [-pi, pi), the mean
    about the first row). Status 1: a non-finite innovation, weight or tangent; 2: a
    factor failed; the caller then runs the numpy path."""
    M, n = L0.shape
    m = Y.shape[1]
    st, nis, r, ww, c, Rt, Lr = _prelude(Y, z, w, R, tau, min_ess, confidence, W, nu, S,
                                         angle)
    if st:
        return st, nis
    # the images' deviations under W, centred exactly (as the numpy path on a manifold)
    yb = np.zeros(m)
    _mean_into(Y, W, angle, yb)
    dY = np.empty((M, m))
    e = np.zeros(m)
    for j in range(M):
        for a in range(m):
            dY[j, a] = _diff(Y[j, a], yb[a], angle)
            e[a] += W[j] * dY[j, a]
    l0 = np.zeros(n)
    for j in range(M):
        for i in range(n):
            l0[i] += W[j] * L0[j, i]
    Pyx = np.zeros((m, n))
    Pyy = np.zeros((m, m))
    dx = np.empty(n)
    for j in range(M):
        cw = c * W[j]
        for a in range(m):
            dY[j, a] -= e[a]
        for i in range(n):
            dx[i] = L0[j, i] - l0[i]
        for a in range(m):
            A = dY[j, a] * cw
            for i in range(n):
                Pyx[a, i] += A * dx[i]
            for b in range(m):
                Pyy[a, b] += A * dY[j, b]
    St = Pyy + Rt
    ok, cSt = factor(St)
    if not ok:
        return _NOT_PD, nis
    K = _gain(cSt, Pyx)
    tr = 0.0  # tr(St^-1 Pyy)
    col = np.empty(m)
    for b in range(m):
        _solve(cSt, Pyy[:, b].copy(), col)
        tr += col[b]
    amp = math.sqrt(1.0 + tr * ww)
    Kt = np.ascontiguousarray(K.T)  # (m, n): the loop over the state runs along a row
    dv = np.empty(m)
    dm = np.zeros(n)
    sv = np.empty(n)
    for j in range(M):
        _perturbed(r, V, Lr, j, dv)
        sv[:] = 0.0
        for a in range(m):
            da = dv[a]
            for i in range(n):
                sv[i] += da * Kt[a, i]
        wj = W[j]
        for i in range(n):
            t = sv[i] + L0[j, i]
            T[j, i] = t
            dm[i] += wj * t
    for j in range(M):
        for i in range(n):
            t = dm[i] + amp * (T[j, i] - dm[i])
            if not math.isfinite(t):
                return _NONFINITE, nis
            T[j, i] = t
    return _OK, nis


@njit(cache=True)
def _shift_1d(X: Array, Y: Array, z: float, w: Array, R: float, V: Array, tau: float,
              min_ess: float, confidence: bool, Xn: Array, W: Array, nu: Array, S: Array,
              x: Array, P: Array) -> tuple[int, float]:  # pragma: no cover - compiled
    """:func:`shift_update` of a 1-D state and measurement, on scalars (accumulators in
    registers: several times faster than the general loops on 99 members)."""
    M = X.shape[0]
    yb = 0.0
    for j in range(M):
        yb += w[j] * Y[j, 0]
    s = 0.0
    for j in range(M):
        d = Y[j, 0] - yb
        s += d * w[j] * d
    s += R
    nu0 = z - yb
    nu[0] = nu0
    S[0, 0] = s
    if not 0.0 < s < math.inf:
        return _NOT_PD, 0.0
    i1 = 1.0 / math.sqrt(s)
    nis = nu0 * (nu0 * i1 * i1)
    if not math.isfinite(nis):
        return _NONFINITE, nis
    if not 0.0 < R < math.inf:
        return _NOT_PD, nis
    share = 1.0
    if confidence:
        ir = 1.0 / math.sqrt(R)
        ll = np.empty(M)
        for j in range(M):
            t = (z - Y[j, 0]) * ir
            ll[j] = -0.5 * (t * t)
        phi_max = 1.0 - tau
        phi = _tempered(w, ll, phi_max, min_ess, W)
        if not math.isfinite(W.sum()):
            return _NONFINITE, nis
        share = tau + (phi_max - phi)
    else:
        for j in range(M):
            W[j] = w[j]
    ww = 0.0
    yb = 0.0
    for j in range(M):
        ww += W[j] * W[j]
        yb += W[j] * Y[j, 0]
    c = 1.0 / max(1.0 - ww, 1e-12)
    rt = R * (1.0 / share)
    if not 0.0 < rt < math.inf:
        return _NOT_PD, nis
    lr = math.sqrt(rt)
    pyx = 0.0
    st = 0.0
    for j in range(M):
        d = Y[j, 0] - yb
        A = d * (c * W[j])
        pyx += A * X[j, 0]
        st += A * d
    st += rt
    if not 0.0 < st < math.inf:
        return _NOT_PD, nis
    i2 = 1.0 / math.sqrt(st)
    K = pyx * i2 * i2
    xm = 0.0
    for j in range(M):
        v = X[j, 0] + ((z - Y[j, 0]) + V[j, 0] * lr) * K
        Xn[j, 0] = v
        xm += W[j] * v
    p = 0.0
    for j in range(M):
        d = Xn[j, 0] - xm
        p += d * W[j] * d
    p /= max(1.0 - ww, 1e-12)
    x[0] = xm
    P[0, 0] = p
    if not (math.isfinite(xm) and math.isfinite(p)):
        return _NONFINITE, nis
    return _OK, nis
