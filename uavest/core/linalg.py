"""Numerically careful small linear algebra: Cholesky with jitter, solves, symmetrising.

Rules used everywhere in the core: solve, never invert; symmetrise every covariance that
is the result of a subtraction; factor with a jitter fallback so that a covariance that is
PSD up to rounding still yields a factor.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

Array = np.ndarray


def _lapack(name: str) -> Callable[..., Any]:
    """LAPACK routine ``name`` through scipy, imported at its first call rather than at
    import (importing scipy.linalg costs 0.3-0.8 s, which every command, even ``--help``,
    paid). The stub replaces itself in this module's globals, so later calls go straight
    to LAPACK with no per-call overhead."""

    def stub(*args: Any, **kwargs: Any) -> Any:
        from scipy.linalg import lapack

        fn = getattr(lapack, name)
        globals()[name] = fn
        return fn(*args, **kwargs)

    stub.__name__ = name
    return stub


dposv = _lapack("dposv")
dpotrf = _lapack("dpotrf")
dpotrs = _lapack("dpotrs")
dtrtrs = _lapack("dtrtrs")
_LAPACK = ("dposv", "dpotrf", "dpotrs", "dtrtrs")


def bind_lapack() -> None:
    """Bind the LAPACK routines now (scipy's import, 0.3-0.8 s once per process): for a
    caller that times its steps and should not charge that to the first one."""
    from scipy.linalg import lapack

    g = globals()
    for name in _LAPACK:
        g[name] = getattr(lapack, name)


class NumericalError(np.linalg.LinAlgError):
    """A numerical failure of a filter step (non-finite values, lost positive
    definiteness, degenerate weights). A ``LinAlgError``, so that the divergence guard
    (:class:`uavest.core.Guarded`) recovers from it, while shape/type errors (ValueError,
    TypeError...) keep propagating as programming errors."""


class NotPositiveDefinite(NumericalError):
    """A covariance could not be factored even with jitter."""


def symmetrize(P: Array) -> Array:
    """(P + P^T) / 2."""
    res: Array = 0.5 * (P + P.T)
    return res


def chol(P: Array, max_tries: int = 6) -> Array:
    """Lower Cholesky factor of ``P``, adding growing diagonal jitter if needed.

    Jitter starts at 1e-12 * mean(diag) and grows x100 per try. Raises
    :class:`NotPositiveDefinite` if ``P`` is not finite or stays indefinite.
    """
    if P.shape[0] == 1:  # 1 x 1: LAPACK's factor is the square root; skip the call
        p = float(P[0, 0])
        if 0.0 < p < math.inf:
            return np.array([[math.sqrt(p)]])
    L, info = dpotrf(P, lower=1)  # LAPACK directly: ~7x less overhead than np.linalg
    if info == 0:
        res: Array = L
        return res
    if not np.isfinite(P).all():
        raise NotPositiveDefinite("covariance has non-finite entries")
    P = symmetrize(P)
    scale = float(np.mean(np.abs(np.diag(P)))) or 1.0
    jitter = 1e-12 * scale
    eye = np.eye(P.shape[0])
    for _ in range(max_tries):
        try:
            return np.linalg.cholesky(P + jitter * eye)
        except np.linalg.LinAlgError:
            jitter *= 100.0
    raise NotPositiveDefinite("covariance is not positive definite")


def is_pd(P: Array) -> bool:
    """True if ``P`` is finite and Cholesky-factorable without jitter."""
    if not math.isfinite(float(P.sum())):
        return False
    res: bool = dpotrf(P, lower=1)[1] == 0
    return res


def gain(Pxy: Array, S: Array) -> Array:
    """Kalman gain K = Pxy S^-1 computed by a solve (S symmetric PD)."""
    if S.shape[0] == 1:  # as gain_factor, without building the unused factor
        s = float(S[0, 0])
        if 0.0 < s < math.inf:
            i = 1.0 / math.sqrt(s)
            return Pxy * i * i
    return gain_factor(Pxy, S)[0]


def gain_factor(Pxy: Array, S: Array) -> tuple[Array, Array]:
    """Kalman gain K = Pxy S^-1 by a Cholesky solve, and the factor of S (for NIS).

    Falls back to a jittered factor when S is not numerically PD.
    """
    if S.shape[0] == 1:  # 1 x 1 S: the solve LAPACK does, without the call (see below)
        s = float(S[0, 0])
        if 0.0 < s < math.inf:
            r = math.sqrt(s)
            i = 1.0 / r
            return Pxy * i * i, np.array([[r]])
    c, X, info = dposv(S, Pxy.T, lower=1)
    if info != 0:
        c = chol(S)
        X = dpotrs(c, Pxy.T, lower=1)[0]
    return X.T, c


def nis_from_factor(c: Array, nu: Array) -> float:
    """nu^T S^-1 nu given the lower Cholesky factor ``c`` of S."""
    if c.shape[0] == 1:  # 1 x 1: the solve LAPACK does, without the call (see below)
        i = 1.0 / float(c[0, 0])
        v = float(nu[0])
        return v * (v * i * i)
    return float(np.dot(nu, dpotrs(c, nu, lower=1)[0]))


# The 1 x 1 shortcuts above (and in ``particle.log_likelihood``) do what LAPACK does for
# a 1 x 1 system: the factor is sqrt(s) and the triangular solves multiply by the
# reciprocal of the diagonal, 1 / sqrt(s), once per solve (OpenBLAS's trsm kernels; the
# results were checked equal bit for bit to dpotrf / dposv / dpotrs / dtrtrs). They save
# a LAPACK call (~1-2 us) per factor or solve on 1-D states and measurements (the UNGM).


def nearest_pd(P: Array, floor: float = 1e-12) -> Array:
    """Symmetric matrix with eigenvalues clipped below at ``floor * max(|eig|, 1)``."""
    P = symmetrize(P)
    vals, vecs = np.linalg.eigh(P)
    lo = floor * max(float(np.max(np.abs(vals))), 1.0)
    vals = np.maximum(vals, lo)
    return symmetrize((vecs * vals) @ vecs.T)
