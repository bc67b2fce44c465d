"""Kalman filter (linear) and extended Kalman filter, on any :class:`Space`.

Equations as implemented (tangent-space error state, so the EKF on a manifold is the
multiplicative/error-state EKF):

predict:  x- = f(x),            P- = F P F^T + Q
update:   nu = z (-) h(x-),     S = H P- H^T + R,      K = P- H^T S^-1 (solve)
          x+ = retract(x-, K nu)
          P+ = (I - K H) P- (I - K H)^T + K R K^T      (Joseph form)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .base import Innovation
from .contract import FilterBase, sigma_point_terms
from .gaussian import Gaussian
from .linalg import gain_factor, nis_from_factor, symmetrize
from .model import Measurement, Transition

Array = np.ndarray


@lru_cache(maxsize=16)
def _eye(n: int) -> Array:
    I = np.eye(n)
    I.flags.writeable = False
    return I


@dataclass(frozen=True)
class EKF(FilterBase):
    """Extended Kalman filter. Uses the model's analytic ``F``/``H`` when it has them,
    else central finite differences (see :func:`uavest.core.model.fd_jacobian`).
    No parameters."""

    name: str = "ekf"

    def init(self, prior: Gaussian, space, rng=None) -> Gaussian:
        return prior

    def predict_jac(
        self, g: Gaussian, model: Transition, t: float, dt: float, u: Array | None = None
    ) -> tuple[Gaussian, Array]:
        """Predict and also return the Jacobian F used (for RTS smoothing)."""
        F = model.F(g.x, t, dt, u)
        x = model.f(g.x[None, :], t, dt, u)[0]
        P = symmetrize(F @ g.P @ F.T + model.Q(t, dt, u))
        return Gaussian(x, P), F

    def predict(self, g: Gaussian, model: Transition, t: float, dt: float, u=None, rng=None):
        return self.predict_jac(g, model, t, dt, u)[0]

    def update(
        self, g: Gaussian, z: Array, model: Measurement, rng=None
    ) -> tuple[Gaussian, Innovation]:
        H = model.H(g.x)
        zhat = model.h(g.x[None, :])[0]
        nu = model.residual(z, zhat)
        PHt = g.P @ H.T
        S = symmetrize(H @ PHt + model.R)
        K, cS = gain_factor(PHt, S)
        x = model.space.retract(g.x, K @ nu)
        IKH = _eye(g.P.shape[0]) - K @ H
        P = symmetrize(IKH @ g.P @ IKH.T + K @ model.R @ K.T)
        return Gaussian(x, P), Innovation(nu, S, nis_from_factor(cS, nu))

    def estimate(self, g: Gaussian) -> Gaussian:
        return g

    def rts_terms(self, s_prev, s_pred, model, t, dt, u=None, prev=None):
        """(estimate(s_pred), P F^T), F the transition's tangent Jacobian at the prior
        mean (the RTS smoother's cross-covariance). ``s_pred=None``: the sigma-point
        fallback from the prior (see :mod:`uavest.core.contract`)."""
        g = s_prev if prev is None else prev
        if s_pred is None:
            return sigma_point_terms(g, model, t, dt, u)
        return s_pred, g.P @ model.F(g.x, t, dt, u).T


@dataclass(frozen=True)
class KF(EKF):
    """Linear Kalman filter: the EKF equations, which are exact for linear models.

    Refuses non-linear models so that a mistaken model choice fails loudly.
    """

    name: str = "kf"

    def predict_jac(self, g, model, t, dt, u=None):
        if not getattr(model, "linear", False):
            raise TypeError(f"KF needs a linear transition model, got {type(model).__name__}")
        return super().predict_jac(g, model, t, dt, u)

    def update(self, g, z, model, rng=None):
        if not getattr(model, "linear", False):
            raise TypeError(f"KF needs a linear measurement model, got {type(model).__name__}")
        return super().update(g, z, model, rng)
