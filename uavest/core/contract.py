"""The filter contract: what every core filter (and wrapper) provides.

A filter is a small frozen configuration object; its *state* is an immutable value
(``Gaussian``, ``SqrtGaussian``, ``Ensemble``, a wrapper state...) that only the filter
interprets. Callers never look inside a state: everything they need goes through these
methods::

    s  = f.init(prior, space, rng)                      # state from a Gaussian prior
    s  = f.predict(s, transition, t, dt, u, rng)        # to time t (end of the step)
    s, innov = f.update(s, z, measurement, rng)         # innov: Innovation(nu, S, nis)
    g  = f.estimate(s)                                  # Gaussian(x, P)
    C  = f.cross_covariance(s0, s1, transition, t, dt, u)      # RTS smoothing
    gp, C = f.rts_terms(s0, s1, transition, t, dt, u, prev)    # RTS smoothing, paired
    s  = f.mix(states, w, space, rng)                   # JPDA hypothesis mixture

Units and frames are the models' (the core is model-agnostic); covariances and
cross-covariances live in the tangent space of the state space (``space.local`` around
the means).

Cross-covariance for smoothing: C = Cov(e_{k-1}, e_k) between the tangent error of the
filtered state *before* a predict (``s_prev``) and of the predicted state (``s_pred``),
as each filter best knows it (n x n):

* KF/EKF: P F^T, F the transition's tangent Jacobian at the prior mean.
* UKF/CKF/SRUKF: the sigma-point cross-covariance sum_j Wc_j D_j dY_j^T.
* EnKF/ETKF/hybrid: the member-wise weighted cross-covariance when the predict kept
  member j as row j (:meth:`EnsembleFilter.keeps_members`), else the sigma-point
  fallback below.
* PF (resamples inside predict) and the literal hybrid (resamples every step): the
  sigma-point fallback.

The sigma-point fallback runs an unscented prediction (Van der Merwe points, alpha=1,
beta=2, kappa=0) of the filtered Gaussian and returns *that* prediction together with its
C, because an RTS smoother must pair C with the prediction it belongs to: this is why
:meth:`rts_terms` returns the pair (predicted Gaussian, C); :meth:`cross_covariance` is
its second element. ``s_pred=None`` asks for the fallback explicitly (a wrapper's
predicted state that is not a propagation of ``s_prev``, e.g. after the guard
re-initialised the filter).

Mixtures (:meth:`mix`): Gaussian states are moment-matched (mixture mean on the space,
covariance including the spread of the means) and re-initialised through ``init``;
ensembles of equal size M are pooled with weights w_h * w_hj and systematically redrawn
to M members (unequal sizes fall back to moment matching and ``init``).

New filters inherit :class:`FilterBase` (Gaussian-like states) or
:class:`EnsembleFilter` (persistent ensembles) and get these defaults; they override
what they know better.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..geometry.spaces import Space
from .gaussian import Gaussian
from .interfaces import Measurement, Transition
from .resample import systematic_resample
from .sigma import unscented_cross
from .states import Ensemble, Innovation

Array = np.ndarray
Rng = np.random.Generator


@runtime_checkable
class Filter(Protocol):
    """Structural type of every core filter and wrapper (see the module docstring)."""

    @property
    def name(self) -> str: ...

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> Any: ...

    def predict(self, s: Any, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Rng | None = None) -> Any: ...

    def update(self, s: Any, z: Array, model: Measurement, rng: Rng | None = None
               ) -> tuple[Any, Innovation | None]: ...

    def estimate(self, s: Any) -> Gaussian: ...

    def cross_covariance(self, s_prev: Any, s_pred: Any, model: Transition, t: float,
                         dt: float, u: Array | None = None) -> Array: ...

    def rts_terms(self, s_prev: Any, s_pred: Any, model: Transition, t: float, dt: float,
                  u: Array | None = None, prev: Gaussian | None = None
                  ) -> tuple[Gaussian, Array]: ...

    def mix(self, states: Sequence[Any], w: Array, space: Space, rng: Rng) -> Any: ...


# ------------------------------------------------------------------------------ helpers


def sigma_point_terms(
    g: Gaussian, model: Transition, t: float, dt: float, u: Array | None = None, ukf: Any = None
) -> tuple[Gaussian, Array]:
    """Unscented prediction of ``g`` and its cross-covariance C (the documented fallback):
    ``ukf.predict_cross``, by default :func:`.sigma.unscented_cross` (what ``UKF()``'s
    gives: alpha=1, beta=2, kappa=0)."""
    if ukf is None:
        return unscented_cross(g, model, t, dt, u)
    res: tuple[Gaussian, Array] = ukf.predict_cross(g, model, t, dt, u)
    return res


def ensemble_cross(E_f: Ensemble, E_p: Ensemble, x_f: Array, x_p: Array) -> Array:
    """Weighted cross-covariance (n, n) of member deviations before (``E_f`` about
    ``x_f``) and after (``E_p`` about ``x_p``) one predict; members must correspond
    (row j of ``E_p`` is member j of ``E_f`` propagated). Weights are ``E_f``'s; the
    normalisation is the reliability-weighted unbiased 1 / (1 - sum w^2)."""
    M = E_f.M
    w = np.full(M, 1.0 / M) if E_f.w is None else E_f.w
    dA = E_f.space.local(x_f, E_f.X)
    dB = E_p.space.local(x_p, E_p.X)
    dA = dA - w @ dA
    dB = dB - w @ dB
    res: Array = (dA.T * w) @ dB / max(1.0 - float(w @ w), 1e-12)
    return res


def moment_match(gs: Sequence[Gaussian], w: Array, space: Space) -> Gaussian:
    """One Gaussian with the mean and covariance of the mixture sum_h w_h N(x_h, P_h)
    (``w`` sums to 1): mean on ``space`` started at the heaviest component, covariance
    sum_h w_h (P_h + d_h d_h^T) with d_h = local(x, x_h). The loop runs over the few
    hypotheses, not over members."""
    x = space.mean(np.stack([g.x for g in gs]), w, gs[int(np.argmax(w))].x)
    P = np.zeros_like(gs[0].P)
    for wh, g in zip(w, gs, strict=True):
        d = space.local(x, g.x[None, :])[0]
        P += wh * (g.P + np.outer(d, d))
    return Gaussian(x, 0.5 * (P + P.T))


def pool_ensembles(Es: Sequence[Ensemble], w: Array, rng: Rng) -> Ensemble:
    """Pool equal-size ensembles with weights w_h * w_hj and draw M members by systematic
    resampling (equal weights afterwards)."""
    M = Es[0].M
    X = np.concatenate([e.X for e in Es])
    wx = np.concatenate([wh * (np.full(M, 1.0 / M) if e.w is None else e.w)
                         for wh, e in zip(w, Es, strict=True)])
    idx = systematic_resample(wx / wx.sum(), rng, M)
    return Ensemble(X[idx], Es[0].space)


# ------------------------------------------------------------------------------ defaults


class FilterBase:
    """Defaults of the contract for filters whose state is Gaussian-like (any state
    ``estimate`` reads and ``init`` rebuilds). Subclasses are frozen dataclasses."""

    def estimate(self, s: Any) -> Gaussian:  # pragma: no cover - every filter overrides
        raise NotImplementedError

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> Any:
        raise NotImplementedError  # pragma: no cover

    def rts_terms(
        self, s_prev: Any, s_pred: Any, model: Transition, t: float, dt: float,
        u: Array | None = None, prev: Gaussian | None = None,
    ) -> tuple[Gaussian, Array]:
        """(prediction to pair with C, C) for RTS smoothing. ``prev`` is the filtered
        Gaussian the caller recorded for ``s_prev`` (default ``estimate(s_prev)``).
        Default: the sigma-point fallback (module docstring)."""
        g = self.estimate(s_prev) if prev is None else prev
        return sigma_point_terms(g, model, t, dt, u)

    def cross_covariance(
        self, s_prev: Any, s_pred: Any, model: Transition, t: float, dt: float,
        u: Array | None = None,
    ) -> Array:
        """C = Cov(e_{k-1}, e_k) (n, n), tangent coordinates; see :meth:`rts_terms`."""
        return self.rts_terms(s_prev, s_pred, model, t, dt, u)[1]

    def mix(self, states: Sequence[Any], w: Array, space: Space, rng: Rng) -> Any:
        """Moment-matched mixture of ``states`` (weights ``w`` summing to 1), rebuilt as
        this filter's state through ``init``."""
        g = moment_match([self.estimate(s) for s in states], np.asarray(w, float), space)
        return self.init(g, space, rng)


class EnsembleFilter(FilterBase):
    """Defaults for filters whose state is a persistent :class:`Ensemble`."""

    def keeps_members(self, E: Ensemble) -> bool:
        """True if ``predict(E)`` propagates these very members (row j stays member j),
        so that member-wise cross-covariances are meaningful."""
        return True

    def rts_terms(
        self, s_prev: Any, s_pred: Any, model: Transition, t: float, dt: float,
        u: Array | None = None, prev: Gaussian | None = None,
    ) -> tuple[Gaussian, Array]:
        """Member-wise cross-covariance paired with ``estimate(s_pred)`` when the predict
        kept the members (same M, :meth:`keeps_members`); else the sigma-point fallback."""
        g = self.estimate(s_prev) if prev is None else prev
        if (
            isinstance(s_prev, Ensemble)
            and isinstance(s_pred, Ensemble)
            and s_prev.M == s_pred.M
            and self.keeps_members(s_prev)
        ):
            gp = self.estimate(s_pred)
            return gp, ensemble_cross(s_prev, s_pred, g.x, gp.x)
        return sigma_point_terms(g, model, t, dt, u)

    def mix(self, states: Sequence[Any], w: Array, space: Space, rng: Rng) -> Any:
        """Pooled and systematically redrawn ensembles (equal sizes), else moment
        matching and ``init``."""
        if all(isinstance(e, Ensemble) for e in states) and len({e.M for e in states}) == 1:
            return pool_ensembles(states, w, rng)
        return super().mix(states, w, space, rng)
