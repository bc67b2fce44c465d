"""Divergence detection and recovery around any filter.

A :class:`Guarded` filter has the same interface as the filter it wraps. After every
predict and update it checks the estimate: non-finite values, a covariance that is not
positive definite, an exception from the linear algebra (e.g. a failed downdate), a
covariance that has exploded (a variance above ``max_growth`` times the largest prior
variance: the filter has lost the state while its NIS stays small), or an
NIS above the gate (chi-square ``gate_prob`` quantile for the measurement dimension) for
``strikes`` consecutive updates. On divergence it re-initialises the inner filter from the
last good estimate with its covariance multiplied by ``inflate`` and reports it: the
state's ``resets`` counter grows and ``reset`` is True for that step. It never returns a
NaN/inf estimate.

Only *numerical* failures are recovered from: ``numpy.linalg.LinAlgError`` (which the
core's own numerical failures raise: :class:`~uavest.core.linalg.NumericalError`,
:class:`~uavest.core.linalg.NotPositiveDefinite`) and ``FloatingPointError``, plus the
checks above. Anything else (a measurement of the wrong shape, a wrong model type: a
``ValueError``, ``TypeError``, ``IndexError``...) is a programming error and propagates.

Smoothing (:meth:`Guarded.rts_terms`): the inner filter's terms; after a reset in the
predict the predicted state is a re-initialisation, not a propagation of the previous
one, so the inner filter is asked for its sigma-point fallback (``s_pred=None``: an
unscented prediction of the filtered estimate and its cross-covariance).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any, cast

import numpy as np

from ..geometry.spaces import Space
from . import linalg as _linalg
from .contract import Filter, FilterBase
from .gaussian import Gaussian
from .interfaces import Measurement, Transition
from .states import Innovation

Array = np.ndarray
Rng = np.random.Generator

#: What the guard recovers from (numerical failures only; see the module docstring).
NUMERICAL_ERRORS = (np.linalg.LinAlgError, FloatingPointError)


@lru_cache(maxsize=64)
def nis_gate(m: int, prob: float) -> float:
    """The ``prob`` quantile of chi-square with ``m`` degrees of freedom
    (chi2.ppf(prob, m) == chdtri(m, 1 - prob), without importing scipy.stats)."""
    from scipy.special import chdtri  # at the first gate, not at import (start-up)

    return float(chdtri(m, 1.0 - prob))


@dataclass(frozen=True, slots=True)
class GuardState:
    inner: Any
    last_good: Gaussian
    strikes: int = 0
    resets: int = 0
    reset: bool = False  # True if this step re-initialised
    reason: str = ""
    var_limit: float = np.inf  # largest variance tolerated before declaring divergence
    est: Gaussian | None = None  # the checked estimate of ``inner`` (saves recomputing it)


@dataclass(frozen=True)
class Guarded(FilterBase):
    """Wraps ``filter`` with divergence detection and recovery (see module docstring)."""

    filter: Filter
    gate_prob: float = 0.9999
    strikes: int = 5
    inflate: float = 10.0
    max_growth: float = 1e8

    @property
    def name(self) -> str:
        return self.filter.name

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> GuardState:
        limit = self.max_growth * float(np.max(np.diag(prior.P)))
        return GuardState(self.filter.init(prior, space, rng), prior, var_limit=limit)

    def _recover(self, s: GuardState, space: Space, rng: Rng | None, reason: str
                 ) -> GuardState:
        g = s.last_good
        P = g.P * self.inflate
        top = float(np.max(np.diag(P)))
        if top > s.var_limit / self.inflate:  # never restart at the explosion's edge
            P = P * (s.var_limit / self.inflate / top)
        inner = self.filter.init(Gaussian(g.x.copy(), P), space, rng)
        return GuardState(inner, g, 0, s.resets + 1, True, reason, s.var_limit)

    def _check(self, inner: Any, var_limit: float = np.inf) -> tuple[Gaussian | None, str]:
        """(estimate, "") or (None, why). One Cholesky does the finite and the PD check:
        LAPACK's factor of a lower triangle holding a NaN or an infinity has a NaN on its
        diagonal (or fails), so a finite factor diagonal and a finite mean mean a finite,
        PD estimate (the upper triangle, which no consumer reads, is not summed)."""
        try:
            g = self.filter.estimate(inner)
        except NUMERICAL_ERRORS as e:
            return None, f"estimate failed: {e}"
        P = g.P
        L, info = _linalg.dpotrf(P, lower=1)
        # sums of Python floats: a few entries, cheaper than two numpy reductions
        if info != 0 or not math.isfinite(sum(g.x.tolist()) + sum(L.diagonal().tolist())):
            return None, ("non-finite estimate" if not g.finite()
                          else "covariance not positive definite")
        if var_limit < np.inf and max(P.diagonal().tolist()) > var_limit:
            return None, "covariance exploded"
        return g, ""

    def predict(self, s: GuardState, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Rng | None = None) -> GuardState:
        try:
            inner = self.filter.predict(s.inner, model, t, dt, u, rng)
        except NUMERICAL_ERRORS as e:
            return self._recover(s, model.space, rng, f"predict failed: {e}")
        return self._after_predict(s, inner, model, rng)

    def update(self, s: GuardState, z: Array, model: Measurement, rng: Rng | None = None
               ) -> tuple[GuardState, Innovation | None]:
        try:
            inner, inn = self.filter.update(s.inner, z, model, rng)
        except NUMERICAL_ERRORS as e:
            return self._recover(s, model.space, rng, f"update failed: {e}"), None
        return self._after_update(s, inner, cast(Innovation, inn), model, rng)

    # -- many states at once (the tracker) -------------------------------------------
    def predict_many(self, states: Sequence[GuardState], model: Transition, t: float,
                     dt: float, u: Array | None = None, rng: Rng | None = None
                     ) -> list[GuardState]:
        """:meth:`predict` of every state; the inner filter's ``predict_many`` (one batched
        computation) when it has one and every state is fine, each result then checked as
        :meth:`predict` checks it. Any numerical failure of the batch: one at a time."""
        many = getattr(self.filter, "predict_many", None)
        if many is not None and len(states) > 1:
            try:
                inners = many([s.inner for s in states], model, t, dt, u, rng)
            except NUMERICAL_ERRORS:
                inners = None
            if inners is not None:
                return [self._after_predict(s, inner, model, rng)
                        for s, inner in zip(states, inners, strict=True)]
        return [self.predict(s, model, t, dt, u, rng) for s in states]

    def update_many(self, states: Sequence[GuardState], zs: Array, model: Measurement,
                    rng: Rng | None = None) -> list[tuple[GuardState, Innovation | None]]:
        """:meth:`update` of every state with its measurement; batched through the inner
        filter's ``update_many`` as :meth:`predict_many`."""
        many = getattr(self.filter, "update_many", None)
        if many is not None and len(states) > 1:
            try:
                res = many([s.inner for s in states], zs, model, rng)
            except NUMERICAL_ERRORS:
                res = None
            if res is not None:
                return [self._after_update(s, inner, inn, model, rng)
                        for s, (inner, inn) in zip(states, res, strict=True)]
        return [self.update(s, z, model, rng) for s, z in zip(states, zs, strict=True)]

    def _after_predict(self, s: GuardState, inner: Any, model: Transition, rng: Rng | None
                       ) -> GuardState:
        g, why = self._check(inner, s.var_limit)
        if g is None:
            return self._recover(s, model.space, rng, why)
        return GuardState(inner, s.last_good, s.strikes, s.resets, var_limit=s.var_limit, est=g)

    def _after_update(self, s: GuardState, inner: Any, inn: Innovation, model: Measurement,
                      rng: Rng | None) -> tuple[GuardState, Innovation | None]:
        g, why = self._check(inner, s.var_limit)
        if g is None or not math.isfinite(inn.nis):
            return self._recover(s, model.space, rng, why or "non-finite NIS"), inn
        strikes = s.strikes + 1 if inn.nis > nis_gate(len(inn.nu), self.gate_prob) else 0
        if strikes >= self.strikes:
            return self._recover(s, model.space, rng, f"NIS above gate {strikes} times"), inn
        return GuardState(inner, g, strikes, s.resets, False, "", s.var_limit, g), inn

    def adopt(self, s: GuardState, inner: Any, space: Space, rng: Rng | None = None,
              resets: int | None = None) -> GuardState:
        """``s`` with its inner state replaced by ``inner`` (e.g. a mixture of hypothesis
        updates), checked like any update; ``resets`` overrides the reset count."""
        resets = s.resets if resets is None else resets
        g, why = self._check(inner, s.var_limit)
        if g is None:
            return self._recover(replace(s, resets=resets), space, rng, why)
        return GuardState(inner, g, 0, resets, False, "", s.var_limit, g)

    def estimate(self, s: GuardState) -> Gaussian:
        if s.est is not None:
            return s.est
        g, _ = self._check(s.inner)
        return s.last_good if g is None else g

    def rts_terms(self, s_prev: GuardState, s_pred: GuardState | None, model: Transition,
                  t: float, dt: float, u: Array | None = None, prev: Gaussian | None = None
                  ) -> tuple[Gaussian, Array]:
        """The inner filter's smoothing terms; after a reset in this predict (or with
        ``s_pred=None``) its sigma-point fallback from the filtered estimate ``prev``
        (default ``estimate(s_prev)``), see the module docstring."""
        prev = self.estimate(s_prev) if prev is None else prev
        inner = None if s_pred is None or s_pred.reset else s_pred.inner
        return self.filter.rts_terms(s_prev.inner, inner, model, t, dt, u, prev)

    def mix(self, states: Sequence[GuardState], w: Array, space: Space, rng: Rng
            ) -> GuardState:
        """The inner filter's mixture of the hypotheses' inner states, checked like an
        update (:meth:`adopt`), keeping the largest reset count of the hypotheses."""
        inner = self.filter.mix([s.inner for s in states], np.asarray(w, float), space, rng)
        return self.adopt(states[0], inner, space, rng, max(s.resets for s in states))
