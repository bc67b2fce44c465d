"""Benchmark systems built from typed scenarios, and their vectorised simulation."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.gaussian import Gaussian
from ..core.interfaces import LinearMeasurement, Measurement, Transition
from ..models.benchmarks import (
    Nonlinear2DMeasurement,
    Nonlinear2DTransition,
    UNGMMeasurement,
    UNGMTransition,
)
from ..models.motion import NearlyConstantVelocity
from ..scenarios import ScenarioError, typed

Array = np.ndarray


@dataclass(frozen=True)
class System:
    """A simulated benchmark: models, the truth's and the filter's priors, and timing."""

    transition: Transition
    measurement: Measurement
    truth_prior: Gaussian
    filter_prior: Gaussian
    steps: int
    dt: float
    divergence_rmse: float


def _prior(p: Any, key: str, n: int, name: str) -> Gaussian:
    """The ``key`` ("truth" or "filter") Gaussian of the ``[prior]`` table: per-dimension
    mean and variance (one value is broadcast)."""
    mean, var = getattr(p, f"{key}_mean"), getattr(p, f"{key}_var")
    if not mean or not var:
        raise ScenarioError(f"scenario {name!r}: prior.{key}_mean and prior.{key}_var "
                            "are required")
    m = np.broadcast_to(np.asarray(mean, float), (n,)).copy()
    v = np.broadcast_to(np.asarray(var, float), (n,))
    return Gaussian(m, np.diag(v))


def build_system(sc: Any) -> System:
    """Models and priors for scenario kinds ``ungm``, ``nonlinear2d``, ``linear_cv`` (the
    scenario typed, or its dict)."""
    sc = typed(sc)
    m = sc.model if hasattr(sc, "model") else None
    if sc.kind == "ungm":
        tr = UNGMTransition(m.a, m.b, m.alpha, m.beta, m.Q)
        me = UNGMMeasurement(m.c, m.R)
        dt = 1.0
    elif sc.kind == "nonlinear2d":
        tr = Nonlinear2DTransition(m.nl, m.rho, m.th, m.g, m.alpha, m.beta, m.Q)
        me = Nonlinear2DMeasurement(m.nl, m.c, m.R)
        dt = 1.0
    elif sc.kind == "linear_cv":
        dt = float(m.dt)
        tr = NearlyConstantVelocity(1, m.q)
        me = LinearMeasurement([[1.0, 0.0]], [[m.R]])
    else:
        raise ScenarioError(f"scenario kind {sc.kind!r} is not a benchmark system")
    n = tr.space.dim
    return System(
        tr, me, _prior(sc.prior, "truth", n, sc.name), _prior(sc.prior, "filter", n, sc.name),
        int(sc.steps), dt, float(sc.divergence_rmse),
    )


def simulate(sysm: System, runs: int, rng: np.random.Generator) -> tuple[Array, Array]:
    """Truths (runs, T, n) and measurements (runs, T, m), all runs at once.

    x_0 ~ truth prior; for k = 1..T: x_k = f(x_{k-1}, t=k dt) + w, z_k = h(x_k) + v.
    """
    tr, me = sysm.transition, sysm.measurement
    n, T = tr.space.dim, sysm.steps
    x = sysm.truth_prior.x + rng.standard_normal((runs, n)) @ np.linalg.cholesky(
        sysm.truth_prior.P
    ).T
    X = np.empty((runs, T, n))
    Z = np.empty((runs, T, me.dim))
    for k in range(1, T + 1):
        t = k * sysm.dt
        x = tr.f(x, t, sysm.dt) + rng.standard_normal((runs, n)) @ np.linalg.cholesky(
            tr.Q(t, sysm.dt)
        ).T
        X[:, k - 1] = x
        Z[:, k - 1] = me.h(x) + rng.standard_normal((runs, me.dim)) @ np.linalg.cholesky(me.R).T
    return X, Z
