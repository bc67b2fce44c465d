"""Bootstrap particle filter with systematic resampling (accuracy reference on
non-Gaussian problems such as the UNGM).

predict: resample (systematic) if ESS < ``resample_threshold`` * N, then
         X_j <- retract(f(X_j), w_j), w_j ~ N(0, Q)
update:  log w_j += -1/2 (z (-) h(X_j))^T R^-1 (z (-) h(X_j)), normalised (log-sum-exp)
Resampling is deferred to the next predict so that the estimate uses the weighted set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..geometry.spaces import Space
from . import linalg as _linalg
from .contract import EnsembleFilter
from .ensemble import propagate_members
from .gaussian import Gaussian
from .interfaces import Measurement, Transition
from .linalg import chol, symmetrize
from .resample import systematic_resample
from .spec import param
from .states import Ensemble, Innovation, ensemble_estimate, innovation, sample_gaussian

Array = np.ndarray


def ess(w: Array) -> float:
    """Effective sample size 1 / sum w^2 of normalised weights."""
    return 1.0 / float(np.dot(w, w))  # = w @ w, less per-call overhead


def log_likelihood(r: Array, R: Array) -> Array:
    """Gaussian log-likelihood (up to a constant) of residuals ``r`` (M, m) under ``R``.
    Raises ValueError if the residuals do not have R's dimension (LAPACK would not)."""
    if r.shape[-1] != R.shape[0]:
        raise ValueError(f"residuals have {r.shape[-1]} components, the measurement "
                         f"noise {R.shape[0]}")
    if R.shape[0] == 1 and 0.0 < float(R[0, 0]) < math.inf:
        # 1 x 1: the factor and triangular solve as LAPACK does them (linalg.py)
        u = r[:, 0] * (1.0 / math.sqrt(float(R[0, 0])))
        return -0.5 * (u * u)
    u = _linalg.dtrtrs(chol(R), r.T, lower=1)[0]  # LAPACK, bound at the first call
    res: Array = -0.5 * np.add.reduce(u * u, axis=0)  # = .sum(axis=0), one call less
    return res


def normalise_log(logw: Array) -> Array:
    """Normalised weights from log-weights, robust to underflow."""
    w = np.exp(logw - np.max(logw))
    s = w.sum()
    if not np.isfinite(s) or s <= 0:
        return np.full(logw.shape[0], 1.0 / logw.shape[0])
    res: Array = w / s
    return res


@dataclass(frozen=True)
class PF(EnsembleFilter):
    """Bootstrap particle filter. ``particles`` N (default 2000), resample when the
    effective sample size falls below ``resample_threshold`` * N (1.0: every step).

    RTS smoothing: a predict that resamples does not keep member j as row j, and one
    that does not is rare with the default threshold, so the PF always uses the
    documented sigma-point fallback (:mod:`uavest.core.contract`)."""

    particles: int = field(default=2000, metadata=param("int", lo=2, doc="particles N"))
    resample_threshold: float = field(default=1.0, metadata=param(
        "float", lo=0.0, hi=1.0, doc="resample when ESS < this * N"))
    name: str = "pf"

    def keeps_members(self, E: Ensemble) -> bool:
        return False

    def init(  # type: ignore[override]  # (a generator is required here)
        self, prior: Gaussian, space: Space, rng: np.random.Generator
    ) -> Ensemble:
        return Ensemble(sample_gaussian(prior, space, self.particles, rng), space)

    def predict(self, E: Ensemble, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Any = None) -> Ensemble:
        if E.w is not None and ess(E.w) < self.resample_threshold * E.M:
            E = Ensemble(E.X[systematic_resample(E.w, rng)], E.space)
        return propagate_members(E, model, t, dt, u, rng)

    def update(self, E: Ensemble, z: Array, model: Measurement, rng: Any = None
               ) -> tuple[Ensemble, Innovation]:
        M = E.M
        w = np.full(M, 1.0 / M) if E.w is None else E.w
        Y = model.h(E.X)
        ybar = model.mean(Y, w)
        dY = model.residual(Y, ybar)
        S = symmetrize((dY.T * w) @ dY + model.R)
        logw = np.log(np.maximum(w, 1e-300)) + log_likelihood(model.residual(z, Y), model.R)
        return Ensemble(E.X, E.space, normalise_log(logw)), innovation(
            model.residual(z, ybar), S
        )

    def estimate(self, E: Ensemble) -> Gaussian:
        return ensemble_estimate(E)
