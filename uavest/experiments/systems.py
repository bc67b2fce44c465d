"""Benchmark systems built from scenario dicts, and their vectorised simulation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.gaussian import Gaussian
from ..core.model import LinearMeasurement, Measurement, Transition
from ..models.benchmarks import (
    Nonlinear2DMeasurement,
    Nonlinear2DTransition,
    UNGMMeasurement,
    UNGMTransition,
)
from ..models.motion import NearlyConstantVelocity
from ..scenarios import ScenarioError

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


def _prior(p: dict, key: str, n: int) -> Gaussian:
    m = np.broadcast_to(np.asarray(p[f"{key}_mean"], float), (n,)).copy()
    v = np.broadcast_to(np.asarray(p[f"{key}_var"], float), (n,))
    return Gaussian(m, np.diag(v))


def build_system(sc: dict) -> System:
    """Models and priors for scenario kinds ``ungm``, ``nonlinear2d``, ``linear_cv``."""
    kind = sc["kind"]
    m = dict(sc.get("model", {}))
    try:
        if kind == "ungm":
            tr = UNGMTransition(m["a"], m["b"], m["alpha"], m["beta"], m["Q"])
            me = UNGMMeasurement(m["c"], m["R"])
            dt = 1.0
        elif kind == "nonlinear2d":
            tr = Nonlinear2DTransition(
                m["nl"], m["rho"], m["th"], m["g"], m["alpha"], m["beta"], m["Q"]
            )
            me = Nonlinear2DMeasurement(m["nl"], m["c"], m["R"])
            dt = 1.0
        elif kind == "linear_cv":
            dt = float(m["dt"])
            tr = NearlyConstantVelocity(1, m["q"])
            me = LinearMeasurement([[1.0, 0.0]], [[m["R"]]])
        else:
            raise ScenarioError(f"scenario kind {kind!r} is not a benchmark system")
    except KeyError as e:
        raise ScenarioError(f"scenario {sc.get('name')!r}: missing model parameter {e}") from None
    n = tr.space.dim
    p = sc["prior"]
    return System(
        tr, me, _prior(p, "truth", n), _prior(p, "filter", n), int(sc["steps"]), dt,
        float(sc.get("divergence_rmse", np.inf)),
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
