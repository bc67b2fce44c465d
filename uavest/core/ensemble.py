"""Ensemble Kalman filters: stochastic EnKF (perturbed observations) and the ensemble
transform Kalman filter (ETKF, a deterministic square-root EnKF; Hunt, Kostelich and
Szunyogh, "Efficient data assimilation for spatiotemporal chaos: a local ensemble
transform Kalman filter", Physica D 2007).

Members persist across steps. Process noise rides on the members:
    X_j <- retract(f(X_j), w_j),  w_j ~ N(0, Q)
Stochastic EnKF update (sample moments, 1/(M-1)):
    Pxy = dX^T dY / (M-1),  Pyy = dY^T dY / (M-1) + R,  K = Pxy Pyy^-1
    X_j <- retract(X_j, K (z (-) Y_j + v_j)),  v_j ~ N(0, R)
ETKF update (no perturbations): with C = dY R^-1, A = (M-1) I + C dY^T = V diag(l) V^T,
    Pa~ = A^-1,  W = V diag(sqrt((M-1)/l)) V^T,  wbar = Pa~ C (z (-) ybar)
    X_j <- retract(xbar, sum_i dX_i (W_ij + wbar_i))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..geometry.spaces import Space
from .contract import EnsembleFilter
from .gaussian import Gaussian
from .interfaces import Measurement, Transition
from .linalg import chol, gain, symmetrize
from .spec import param
from .states import Ensemble, Innovation, ensemble_estimate, innovation, sample_gaussian

Array = np.ndarray


def propagate_members(
    E: Ensemble, model: Transition, t: float, dt: float, u: Array | None,
    rng: np.random.Generator, inflation: float = 1.0
) -> Ensemble:
    """f on every member, then additive tangent process noise w ~ N(0, Q) per member."""
    space = model.space
    X = model.f(E.X, t, dt, u)
    L = chol(model.Q(t, dt, u))
    W = np.dot(rng.standard_normal((E.M, space.dim)), L.T)  # np.dot: = @, less overhead
    if inflation != 1.0:
        w = np.full(E.M, 1.0 / E.M) if E.w is None else E.w
        x = space.mean(X, w, X[0])
        W = W + (inflation - 1.0) * space.local(x, X)
    return Ensemble(space.retract(X, W), space, E.w)


def _equal_moments(E: Ensemble, model: Measurement
                   ) -> tuple[Array, Array, Array, Array, Array]:
    """(x, dX, Y, ybar, dY): equal-weight moments of the members and their images."""
    space = model.space
    M = E.M
    w = np.full(M, 1.0 / M)
    x = space.mean(E.X, w, E.X[0])
    dX = space.local(x, E.X)
    dX = dX - dX.mean(axis=0)
    Y = model.h(E.X)
    ybar = model.mean(Y, w)
    dY = model.residual(Y, ybar)
    dY = dY - dY.mean(axis=0)
    return x, dX, Y, ybar, dY


@dataclass(frozen=True)
class _PersistentEnsemble(EnsembleFilter):
    """Shared by EnKF and ETKF: iid Gaussian start, members propagated with process noise
    and multiplicative ``inflation``, the estimate from the ensemble's moments. Every
    predict keeps member j as row j (member-wise RTS cross-covariance)."""

    members: int = field(default=100, metadata=param("int", lo=2, doc="ensemble size M"))
    inflation: float = field(default=1.0, metadata=param(
        "float", lo=0.0, lo_open=True, doc="multiplicative anomaly inflation (1: none)"))

    def init(  # type: ignore[override]  # (a generator is required here)
        self, prior: Gaussian, space: Space, rng: np.random.Generator
    ) -> Ensemble:
        return Ensemble(sample_gaussian(prior, space, self.members, rng), space)

    def predict(self, E: Ensemble, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Any = None) -> Ensemble:
        return propagate_members(E, model, t, dt, u, rng, self.inflation)

    def estimate(self, E: Ensemble) -> Gaussian:
        return ensemble_estimate(E)


@dataclass(frozen=True)
class EnKF(_PersistentEnsemble):
    """Stochastic EnKF with perturbed observations. ``members`` M (default 100),
    multiplicative ``inflation`` of the forecast anomalies (default 1.0: none)."""

    name: str = "enkf"

    def update(self, E: Ensemble, z: Array, model: Measurement, rng: Any = None
               ) -> tuple[Ensemble, Innovation]:
        M = E.M
        _, dX, Y, ybar, dY = _equal_moments(E, model)
        Pxy = dX.T @ dY / (M - 1)
        S = symmetrize(dY.T @ dY / (M - 1) + model.R)
        K = gain(Pxy, S)
        V = rng.standard_normal((M, model.dim)) @ chol(model.R).T
        X = model.space.retract(E.X, (model.residual(z, Y) + V) @ K.T)
        return Ensemble(X, E.space), innovation(model.residual(z, ybar), S)


@dataclass(frozen=True)
class ETKF(_PersistentEnsemble):
    """Ensemble transform Kalman filter: deterministic square-root EnKF (no perturbed
    observations); the analysis ensemble has exactly the Kalman posterior covariance in
    the ensemble subspace. Symmetric square root keeps the mean unbiased."""

    name: str = "etkf"

    def update(self, E: Ensemble, z: Array, model: Measurement, rng: Any = None
               ) -> tuple[Ensemble, Innovation]:
        M = E.M
        x, dX, Y, ybar, dY = _equal_moments(E, model)
        S = symmetrize(dY.T @ dY / (M - 1) + model.R)
        nu = model.residual(z, ybar)
        C = np.linalg.solve(model.R, dY.T).T  # (M, m) = dY R^-1
        A = (M - 1) * np.eye(M) + C @ dY.T
        lam, V = np.linalg.eigh(symmetrize(A))
        lam = np.maximum(lam, 1e-12)
        Pa = (V / lam) @ V.T
        W = (V * np.sqrt((M - 1) / lam)) @ V.T
        wbar = Pa @ (C @ nu)
        dXa = (W + wbar[:, None]).T @ dX
        return Ensemble(model.space.retract(x, dXa), E.space), innovation(nu, S)
