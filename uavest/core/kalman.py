"""Kalman filter (linear) and extended Kalman filter, on any :class:`Space`.

Equations as implemented (tangent-space error state, so the EKF on a manifold is the
multiplicative/error-state EKF):

predict:  x- = f(x),            P- = F P F^T + Q
update:   nu = z (-) h(x-),     S = H P- H^T + R,      K = P- H^T S^-1 (solve)
          x+ = retract(x-, K nu)
          P+ = (I - K H) P- (I - K H)^T + K R K^T      (Joseph form)

The products are ``np.dot`` (the same BLAS calls as ``@`` with less per-call overhead on
these small matrices), the symmetrising ``(A + A^T) / 2`` is done in the fresh result, and
one Cholesky solve gives both the gain and S^-1 nu for the NIS: the same numbers as the
composed expressions, a quarter less time per radar step (docs/speed.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..geometry.spaces import Space
from . import linalg as _linalg
from .contract import FilterBase, sigma_point_terms
from .gaussian import Gaussian
from .interfaces import Measurement, Transition
from .linalg import chol
from .states import Innovation

Array = np.ndarray
Rng = np.random.Generator


_dot = np.dot


@lru_cache(maxsize=16)
def _eye(n: int) -> Array:
    I = np.eye(n)
    I.flags.writeable = False
    return I


def _sym(A: Array) -> Array:
    """(A + A^T) / 2 of a fresh product (written into the sum: no second temporary)."""
    S = A + A.T
    S *= 0.5
    res: Array = S
    return res


def _gain_nis(PHt: Array, S: Array, nu: Array) -> tuple[Array, float]:
    """K = P H^T S^-1 and nu^T S^-1 nu from one Cholesky solve S [K^T, u] = [H P, nu]
    (jittered factor when S is not numerically PD, as :func:`linalg.gain_factor`)."""
    n = PHt.shape[0]
    B = np.empty((S.shape[0], n + 1), order="F")
    B[:, :n] = PHt.T
    B[:, n] = nu
    _, X, info = _linalg.dposv(S, B, lower=1, overwrite_b=1)
    if info != 0:
        X = _linalg.dpotrs(chol(S), B, lower=1)[0]
    return X[:, :n].T, float(_dot(nu, X[:, n]))


@dataclass(frozen=True)
class EKF(FilterBase):
    """Extended Kalman filter. Uses the model's analytic ``F``/``H`` when it has them,
    else central finite differences (see :func:`uavest.core.interfaces.fd_jacobian`).
    No parameters."""

    name: str = "ekf"

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> Gaussian:
        return prior

    def predict_jac(
        self, g: Gaussian, model: Transition, t: float, dt: float, u: Array | None = None
    ) -> tuple[Gaussian, Array]:
        """Predict and also return the Jacobian F used (for RTS smoothing)."""
        F = model.F(g.x, t, dt, u)
        x = model.f(g.x[None, :], t, dt, u)[0]
        A = _dot(_dot(F, g.P), F.T)
        A += model.Q(t, dt, u)
        return Gaussian(x, _sym(A)), F

    def predict(self, g: Gaussian, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Rng | None = None) -> Gaussian:
        return self.predict_jac(g, model, t, dt, u)[0]

    def update(
        self, g: Gaussian, z: Array, model: Measurement, rng: Rng | None = None
    ) -> tuple[Gaussian, Innovation]:
        zhat, H = model.h_H(g.x)
        nu = model.residual(z, zhat)
        P, R = g.P, model.R
        PHt = _dot(P, H.T)
        S = _dot(H, PHt)
        S += R
        S = _sym(S)
        K, nis = _gain_nis(PHt, S, nu)
        x = model.space.retract(g.x, _dot(K, nu))
        IKH = _eye(P.shape[0]) - _dot(K, H)
        A = _dot(_dot(IKH, P), IKH.T)
        A += _dot(_dot(K, R), K.T)
        return Gaussian(x, _sym(A)), Innovation(nu, S, nis)

    def estimate(self, g: Gaussian) -> Gaussian:
        return g

    def rts_terms(self, s_prev: Gaussian, s_pred: Gaussian | None, model: Transition,
                  t: float, dt: float, u: Array | None = None, prev: Gaussian | None = None
                  ) -> tuple[Gaussian, Array]:
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

    def predict_jac(self, g: Gaussian, model: Transition, t: float, dt: float,
                    u: Array | None = None) -> tuple[Gaussian, Array]:
        if not getattr(model, "linear", False):
            raise TypeError(f"KF needs a linear transition model, got {type(model).__name__}")
        return super().predict_jac(g, model, t, dt, u)

    def update(self, g: Gaussian, z: Array, model: Measurement, rng: Rng | None = None
               ) -> tuple[Gaussian, Innovation]:
        if not getattr(model, "linear", False):
            raise TypeError(f"KF needs a linear measurement model, got {type(model).__name__}")
        return super().update(g, z, model, rng)
