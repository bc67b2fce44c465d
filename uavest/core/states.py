"""Shared filter vocabulary: the innovation record and the ensemble state (the states
filters carry between predict and update)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..geometry.spaces import Space, VectorSpace
from .gaussian import Gaussian
from .linalg import chol, nis_from_factor

Array = np.ndarray


@dataclass(frozen=True, slots=True)
class Innovation:
    """What an update saw: residual ``nu`` = z - predicted z (m,), its covariance ``S``
    (m, m, including R) and the normalised innovation squared ``nis`` = nu^T S^-1 nu."""

    nu: Array
    S: Array
    nis: float


@dataclass(frozen=True, slots=True)
class Ensemble:
    """A (weighted) ensemble of states ``X`` (M, size) on ``space``.

    ``w`` are normalised positive weights (M,) or None for equal weights.
    """

    X: Array
    space: Space
    w: Array | None = None
    # memo of ensemble_moments / ensemble_estimate (pure functions of this immutable
    # value): the guard's check, the filter's update and the caller's estimate of one
    # state share one computation instead of repeating the manifold mean
    moments: tuple[Array, Array, Array, Array] | None = field(  # (x, dX, w, P)
        default=None, compare=False, repr=False)
    gaussian: Gaussian | None = field(default=None, compare=False, repr=False)

    @property
    def M(self) -> int:
        res: int = self.X.shape[0]
        return res


@lru_cache(maxsize=32)
def equal_weights(M: int) -> Array:
    """The equal weights 1/M (M,), one shared read-only array per M."""
    w = np.full(M, 1.0 / M)
    w.flags.writeable = False
    return w


def ensemble_moments(E: Ensemble) -> tuple[Array, Array, Array, Array]:
    """Weighted mean ``x``, tangent deviations ``dX`` (M, n), weights ``w`` and covariance.

    Equal weights use the unbiased 1/(M-1) covariance; unequal weights the
    reliability-weighted unbiased form 1/(1 - sum w^2).
    """
    if E.moments is not None:
        return E.moments
    w = equal_weights(E.M) if E.w is None else E.w
    # np.dot: the same numbers as ``@`` here, with less per-call overhead
    if type(E.space) is VectorSpace:  # X - (w X) is centred under w up to rounding
        x = np.dot(w, E.X)
        dX = E.X - x
    else:
        # a space may compute all three in one (compiled) call: the quaternion rows
        fused = getattr(E.space, "weighted_moments", None)
        got = fused(E.X, w) if fused is not None else None
        if got is not None:  # (P symmetrised: it is the estimate's covariance too)
            x, dX, P = got
            out = (x, dX, w, P)
            object.__setattr__(E, "moments", out)
            if E.gaussian is None:
                object.__setattr__(E, "gaussian", Gaussian(x, P))
            return out
        x = E.space.mean(E.X, w, mean_start(E.space, E.X, w))
        dX = E.space.local(x, E.X)
        dX = dX - np.dot(w, dX)  # centre exactly (tangent linearisation on manifolds)
    denom = 1.0 - float(np.dot(w, w))
    P = np.dot(dX.T * w, dX) / max(denom, 1e-12)
    out = (x, dX, w, P)
    object.__setattr__(E, "moments", out)  # memo (see Ensemble); callers never mutate
    return out


def mean_start(space: Space, X: Array, w: Array) -> Array | None:
    """Starting point for an iterated manifold mean: the heaviest member (None, i.e.
    unused, on vector spaces, where the mean is a plain weighted sum)."""
    if isinstance(space, VectorSpace):
        return None
    res: Array | None = X[int(np.argmax(w))]
    return res


def ensemble_estimate(E: Ensemble) -> Gaussian:
    if E.gaussian is not None:
        return E.gaussian
    x, _, _, P = ensemble_moments(E)
    if E.gaussian is not None:  # (a space's fused moments give the estimate too)
        return E.gaussian
    # (P + P^T) / 2 is P itself for a 1 x 1 covariance (p + p = 2p exactly)
    g = Gaussian(x, P if P.shape[0] == 1 else 0.5 * (P + P.T))
    object.__setattr__(E, "gaussian", g)
    return g


def sample_gaussian(g: Gaussian, space: Space, M: int, rng: np.random.Generator) -> Array:
    """M iid draws from N(g.x, g.P) on ``space`` (tangent-space sampling)."""
    L = chol(g.P)
    return space.retract(g.x, rng.standard_normal((M, space.dim)) @ L.T)


def innovation(nu: Array, S: Array) -> Innovation:
    """Innovation record with its NIS (Cholesky solve through LAPACK)."""
    if S.shape[0] == 1:  # chol + nis_from_factor of a 1 x 1, on floats
        s = float(S[0, 0])
        if 0.0 < s < math.inf:
            i = 1.0 / math.sqrt(s)
            v = float(nu[0])
            return Innovation(nu, S, v * (v * i * i))
    return Innovation(nu, S, nis_from_factor(chol(S), nu))
