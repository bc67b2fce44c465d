"""Sage-Husa adaptive noise estimation with a forgetting factor (Sage and Husa, "Adaptive
filtering with unknown prior statistics", JACC 1969), as a wrapper usable with EKF, UKF
and the hybrid filter (any filter whose update returns an :class:`Innovation`).

With forgetting factor b (0 < b < 1) and d_k = (1 - b) / (1 - b^(k+1)):
    R_k = (1 - d_k) R_{k-1} + d_k (nu nu^T - (S - R_{k-1}))       (S - R = H P- H^T)
    Q_k = (1 - d_k) Q_{k-1} + d_k (dx dx^T + P+ - P- + Q_{k-1})    (dx = K nu = x+ (-) x-)
The raw Sage-Husa R estimate can lose positive definiteness; each estimate is projected
to the nearest PD matrix with eigenvalues at least ``floor`` times the initial noise's
smallest eigenvalue (documented safeguard). ``adapt`` chooses "R", "Q" or "RQ".

R is estimated per measurement kind (the model's class and dimension): a filter that sees
an accelerometer update on some steps and an accelerometer + magnetometer update on
others keeps one adapted R for each, never one R for both (whose shapes differ).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..geometry.spaces import Space
from .contract import Filter, FilterBase
from .gaussian import Gaussian
from .interfaces import Measurement, Transition
from .linalg import nearest_pd
from .spec import param
from .states import Innovation

Array = np.ndarray
Rng = np.random.Generator


@dataclass(frozen=True, slots=True)
class AdaptiveState:
    inner: Any
    R: dict[tuple[str, int], Array] | None  # measurement kind (class name, dim) -> adapted R
    Q: np.ndarray | None
    k: int
    prior: Gaussian | None = None  # predicted estimate (for the Q estimator)
    Qfix: np.ndarray | None = None  # Q the model would use (for the floor)


class _NoiseOverride:
    """A model proxy that substitutes adapted R or Q and delegates everything else."""

    def __init__(self, model: Any, R: Array | None = None, Q: Array | None = None) -> None:
        self._m = model
        self._R = R
        self._Q = Q

    def __getattr__(self, k: str) -> Any:
        return getattr(self._m, k)

    @property
    def R(self) -> Array:
        return self._m.R if self._R is None else self._R

    def Q(self, t: float, dt: float, u: Array | None = None) -> Array:
        return self._m.Q(t, dt, u) if self._Q is None else self._Q


@dataclass(frozen=True)
class SageHusa(FilterBase):
    """Adaptive wrapper. ``b`` forgetting factor (0.98), ``adapt`` in {"R", "Q", "RQ"},
    ``floor`` relative eigenvalue floor (0.1). Spec name: ``<filter>_sh``."""

    filter: Filter
    b: float = field(default=0.98, metadata=param(
        "float", lo=0.0, hi=1.0, lo_open=True, hi_open=True, doc="forgetting factor"))
    adapt: str = field(default="R", metadata=param(
        "choice", choices=("R", "Q", "RQ"), doc="which noise to adapt"))
    floor: float = field(default=0.1, metadata=param(
        "float", lo=0.0, lo_open=True, doc="eigenvalue floor relative to the model's"))

    @property
    def name(self) -> str:
        return f"{self.filter.name}_sh"

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> AdaptiveState:
        return AdaptiveState(self.filter.init(prior, space, rng), None, None, 0)

    def _d(self, k: int) -> float:
        return (1.0 - self.b) / (1.0 - self.b ** (k + 1))

    def predict(self, s: AdaptiveState, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Rng | None = None) -> AdaptiveState:
        Q0 = model.Q(t, dt, u)
        Q = s.Q if ("Q" in self.adapt and s.Q is not None) else None
        noisy: Any = _NoiseOverride(model, Q=Q)  # a Transition by delegation
        inner = self.filter.predict(s.inner, noisy, t, dt, u, rng)
        g = self.filter.estimate(inner)
        return AdaptiveState(inner, s.R, s.Q if s.Q is not None else Q0, s.k, g, Q0)

    def update(self, s: AdaptiveState, z: Array, model: Measurement, rng: Rng | None = None
               ) -> tuple[AdaptiveState, Innovation | None]:
        R0 = np.asarray(model.R, float)
        key = (type(model).__name__, R0.shape[0])
        R_prev = s.R.get(key, R0) if s.R is not None else R0
        m: Any = _NoiseOverride(model, R=R_prev if "R" in self.adapt else None)
        inner, got = self.filter.update(s.inner, z, m, rng)
        inn = cast(Innovation, got)  # the wrapped filters' updates return one
        d = self._d(s.k)
        R_new, Q_new = s.R, s.Q
        if "R" in self.adapt:
            raw = (1 - d) * R_prev + d * (np.outer(inn.nu, inn.nu) - (inn.S - R_prev))
            R_new = {**(s.R or {}), key: _floor(raw, R0, self.floor)}
        if "Q" in self.adapt and s.prior is not None:
            post = self.filter.estimate(inner)
            dx = model.space.local(s.prior.x, post.x)
            Qfix = cast(Array, s.Qfix)  # set with the prior by predict
            Qp = s.Q if s.Q is not None else Qfix
            raw = (1 - d) * Qp + d * (np.outer(dx, dx) + post.P - s.prior.P + Qp)
            Q_new = _floor(raw, Qfix, self.floor)
        return AdaptiveState(inner, R_new, Q_new, s.k + 1, None, s.Qfix), inn

    def estimate(self, s: AdaptiveState) -> Gaussian:
        return self.filter.estimate(s.inner)

    def rts_terms(self, s_prev: AdaptiveState, s_pred: AdaptiveState | None,
                  model: Transition, t: float, dt: float, u: Array | None = None,
                  prev: Gaussian | None = None) -> tuple[Gaussian, Array]:
        """The inner filter's, with the model as given (the smoother sees the nominal
        transition; with the default ``adapt="R"`` that is the one predict used)."""
        inner = None if s_pred is None else s_pred.inner
        return self.filter.rts_terms(s_prev.inner, inner, model, t, dt, u, prev)

    def mix(self, states: Sequence[AdaptiveState], w: Array, space: Space, rng: Rng
            ) -> AdaptiveState:
        """The inner filter's mixture; the adapted R and Q are the w-weighted means of
        the hypotheses' estimates (those that have one), the step count the largest."""
        w = np.asarray(w, float)
        inner = self.filter.mix([s.inner for s in states], w, space, rng)
        keys = {k for s in states if s.R for k in s.R}
        # (every key is some hypothesis's: its mean is never None)
        R = {k: v for k in keys
             if (v := _wmean([(s.R or {}).get(k) for s in states], w)) is not None} or None
        return AdaptiveState(inner, R, _wmean([s.Q for s in states], w),
                             max(s.k for s in states), None, states[0].Qfix)


def _wmean(As: Sequence[Array | None], w: Array) -> Array | None:
    idx = [i for i, A in enumerate(As) if A is not None]
    if not idx:
        return None
    ws = w[idx] / w[idx].sum()
    res: Array = sum(wi * As[i] for wi, i in zip(ws, idx, strict=True))
    return res


def _floor(P: np.ndarray, P0: np.ndarray, rel: float) -> np.ndarray:
    lo = rel * float(np.min(np.linalg.eigvalsh(P0)))
    out = nearest_pd(P)
    vals, vecs = np.linalg.eigh(out)
    vals = np.maximum(vals, lo)
    res: Array = (vecs * vals) @ vecs.T
    return res
