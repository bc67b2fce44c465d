"""Unscented Kalman filter (Van der Merwe scaled sigma points, or cubature points) and
its square-root form, on any :class:`Space` (UKF-M style: sigma points are tangent-space
offsets mapped by ``retract``).

Sigma points (n = tangent dimension, L = chol(P)):
    lambda = alpha^2 (n + kappa) - n,   c = sqrt(n + lambda)
    chi_0 = x,  chi_i = retract(x, +c L[:, i]),  chi_{n+i} = retract(x, -c L[:, i])
    Wm_0 = lambda / (n + lambda),  Wc_0 = Wm_0 + 1 - alpha^2 + beta,
    Wm_i = Wc_i = 1 / (2 (n + lambda))
Cubature (``points="cubature"``): the 2n points +-sqrt(n) L[:, i], weights 1/(2n).

predict:  X_j = f(chi_j);  x- = mean(X, Wm);  P- = sum Wc_j d_j d_j^T + Q, d_j = local(x-, X_j)
update:   fresh sigma points of (x-, P-); Z_j = h(chi_j); z- = mean(Z, Wm)
          Pzz = sum Wc e_j e_j^T + R, e_j = Z_j (-) z-;  Pxz = sum Wc D_j e_j^T (D_j offsets)
          K = Pxz Pzz^-1 (solve);  x+ = retract(x-, K (z (-) z-));  P+ = P- - K Pzz K^T
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from types import ModuleType
from typing import Any

import numpy as np

from ..compiled import register
from ..geometry.spaces import Space, VectorSpace
from .contract import FilterBase
from .gaussian import Gaussian
from .interfaces import Measurement, Transition, plain_measurement
from .linalg import chol, gain_factor, nis_from_factor
from .sigma import sigma_weights, unscented_predict
from .spec import param
from .states import Innovation, innovation

Array = np.ndarray
Rng = np.random.Generator
_dot = np.dot  # the same BLAS products as @ without the gufunc's per-call cost
_array = np.array
_empty = np.empty


@lru_cache(maxsize=64)
def _scalar_weights(alpha: float, beta: float, kappa: float) -> tuple[float, ...]:
    """(c, Wm_0, Wm_1, Wc_0, Wc_1) of the 1-D Merwe set as Python floats (the entries of
    :func:`sigma_weights`; Wm_2 = Wm_1, Wc_2 = Wc_1)."""
    c, Wm, Wc, _ = sigma_weights(1, alpha, beta, kappa, "merwe")
    return c, float(Wm[0]), float(Wm[1]), float(Wc[0]), float(Wc[1])


def _ut_cases(nb: ModuleType) -> Iterator[tuple[str, Any, Any]]:
    """The self-check (:mod:`uavest.compiled`): one predict and one update of a 3-D state
    with a 2-D measurement, the kernels against the array path."""

    class _T(Transition):
        space = VectorSpace(3)

        def f(self, X: Array, t: float, dt: float = 1.0, u: Array | None = None) -> Array:
            Y: Array = X + 0.1 * np.sin(X[:, ::-1])
            return Y

        def Q(self, t: float, dt: float = 1.0, u: Array | None = None) -> Array:
            return np.diag([0.1, 0.2, 0.3])

    class _H(Measurement):
        space = VectorSpace(3)
        R = np.array([[0.5, 0.1], [0.1, 0.4]])

        def h(self, X: Array) -> Array:
            return np.stack([X[:, 0] * X[:, 1], X[:, 2]], axis=1)

    f = UKF(alpha=0.7)
    g = Gaussian(np.array([0.3, -1.2, 2.0]), np.array([[2.0, 0.3, 0.1], [0.3, 1.0, -0.2],
                                                        [0.1, -0.2, 1.5]]))
    a, b = f._predict(g, _T(), 1.0, 1.0, None)[0], f._predict_compiled(nb, g, _T(), 1.0,
                                                                       1.0, None)
    if b is None:
        yield "predict", None, a.x
        return
    yield "predict x", b.x, a.x
    yield "predict P", b.P, a.P
    z = np.array([0.5, 1.0])
    ua, ia = f._update(g, z, _H())
    got = f._update_compiled(nb, g, z, _H())
    if got is None:
        yield "update", None, ua.x
        return
    ub, ib = got
    yield "update x", ub.x, ua.x
    yield "update P", ub.P, ua.P
    yield "S", ib.S, ia.S
    yield "nis", ib.nis, ia.nis


#: The compiled unscented kernels (:mod:`uavest.core._compiled_ut`)
UT_KERNELS = register("ut", "uavest.core._compiled_ut", "numba unscented kernels", _ut_cases,
                      rtol=1e-12, atol=1e-12)


_MERWE = {"points": ("merwe",)}


@dataclass(frozen=True)
class UKF(FilterBase):
    """Unscented Kalman filter. ``alpha``, ``beta``, ``kappa`` as Van der Merwe; defaults
    alpha=1, beta=2, kappa=0 (all weights positive but Wc_0 = 2). ``points="cubature"``
    gives the cubature Kalman filter (Arasaratnam and Haykin, IEEE TAC 2009), where the
    three have no effect. n + kappa must be > 0 (checked at the first step)."""

    alpha: float = field(default=1.0, metadata=param(
        "float", lo=0.0, lo_open=True, when=_MERWE, doc="sigma-point spread"))
    beta: float = field(default=2.0, metadata=param(
        "float", lo=0.0, when=_MERWE, doc="prior-distribution term of Wc_0 (2: Gaussian)"))
    kappa: float = field(default=0.0, metadata=param(
        "float", when=_MERWE, doc="secondary scaling"))
    points: str = field(default="merwe", metadata=param(
        "choice", choices=("merwe", "cubature"), doc="sigma-point set"))
    name: str = "ukf"

    def _w(self, n: int) -> tuple[float, Array, Array, Array]:
        return sigma_weights(n, self.alpha, self.beta, self.kappa, self.points)

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> Gaussian:
        if type(space) is VectorSpace and (space.dim > 1 or self.points != "merwe"):
            UT_KERNELS.get()  # numba's import and cache load here, not in the first step
        return prior

    def _predict(self, g: Gaussian, model: Transition, t: float, dt: float, u: Array | None
                 ) -> tuple[Gaussian, Array, Array, Array]:
        """(prediction, offsets D, deviations dY, Wc): :func:`.sigma.unscented_predict`."""
        return unscented_predict(g, model, t, dt, u, self._w(model.space.dim))

    def predict_cross(
        self, g: Gaussian, model: Transition, t: float, dt: float, u: Array | None = None
    ) -> tuple[Gaussian, Array]:
        """Predict; also return the cross-covariance C = Cov(x_k, x_{k+1}) (n x n) used by
        the unscented RTS smoother."""
        gp, D, dY, Wc = self._predict(g, model, t, dt, u)
        return gp, (D.T * Wc) @ dY

    def rts_terms(self, s_prev: Any, s_pred: Any, model: Transition, t: float, dt: float,
                  u: Array | None = None, prev: Gaussian | None = None
                  ) -> tuple[Gaussian, Array]:
        """The sigma-point prediction of the prior and its cross-covariance
        (:meth:`predict_cross`); identical to ``predict`` for the prediction."""
        return self.predict_cross(s_prev if prev is None else prev, model, t, dt, u)

    def predict(self, g: Gaussian, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Rng | None = None) -> Gaussian:
        space = model.space
        if type(space) is VectorSpace:
            if space.dim == 1 and self.points == "merwe":
                out = self._predict_1d(g, model, t, dt, u)
            else:
                nb = UT_KERNELS.get()
                out = self._predict_compiled(nb, g, model, t, dt, u) if nb else None
            if out is not None:
                return out
        return self._predict(g, model, t, dt, u)[0]

    # -- vector spaces with numba: the algebra between the model calls compiled ------------
    def _sigma_compiled(self, nb: ModuleType, g: Gaussian, n: int
                        ) -> tuple[Array, Array, Array, Array] | None:
        """(Wm, Wc, D, X): the weights, the offsets D = U L^T and the sigma points X of
        ``g`` by the kernel; None if P has no plain factor (the array path then jitters or
        raises)."""
        _, Wm, Wc, U = self._w(n)
        D, X = _empty(U.shape), _empty(U.shape)
        if nb.sigma(g.x, g.P, U, D, X):
            return None
        return Wm, Wc, D, X

    def _predict_compiled(self, nb: ModuleType, g: Gaussian, model: Transition, t: float,
                          dt: float, u: Array | None
                          ) -> Gaussian | None:
        """``_predict`` with the sigma points and the moments in two kernel calls
        (:mod:`uavest.core._compiled_ut`); None if P has no plain factor."""
        n = model.space.dim
        sp = self._sigma_compiled(nb, g, n)
        if sp is None:
            return None
        Wm, Wc, _, X = sp
        Y = model.f(X, t, dt, u)
        x, P = _empty(n), _empty((n, n))
        nb.moments(Y, Wm, Wc, model.Q(t, dt, u), x, P)
        return Gaussian(x, P)

    def _update_compiled(self, nb: ModuleType, g: Gaussian, z: Array, model: Measurement
                         ) -> tuple[Gaussian, Innovation] | None:
        """``_update`` with the sigma points and the gain algebra in two kernel calls, the
        model's ``h``, ``mean`` and ``residual`` between them; None if P or S has no plain
        factor (the array path then jitters or raises)."""
        n = model.space.dim
        sp = self._sigma_compiled(nb, g, n)
        if sp is None:
            return None
        Wm, Wc, D, X = sp
        Z = model.h(X)
        zhat = model.mean(Z, Wm)
        E = model.residual(Z, zhat)
        nu = model.residual(z, zhat)
        m = E.shape[1]
        if nu.shape != (m,):  # (the array path's products raise on a wrong-sized z)
            return None
        x, P, S = _empty(n), _empty((n, n)), _empty((m, m))
        st, nis = nb.update(g.x, g.P, D, E, Wc, model.R, nu, x, P, S)
        if st:
            return None
        return Gaussian(x, P), Innovation(nu, S, nis)

    # -- 1-D states: the same formulas on Python floats ----------------------------------
    # On a 1-D state the step's cost is numpy's per-call floor (~1 us a call on 3 sigma
    # points), not arithmetic: these do what ``_predict`` / ``update`` do for n = m = 1
    # with the 1 x 1 factor, gain and solve on floats (as ``linalg``'s 1 x 1 shortcuts),
    # sigma points x, x + c sqrt(p), x - c sqrt(p) and the weighted sums written out. The
    # sums are the same products in the same order, but BLAS may fuse a multiply and an
    # add where Python rounds both: equal to the array path to rounding (~1e-16
    # relative; tests/unit/test_fast_paths.py). Anything outside the fast case (a factor
    # or an innovation variance that is not finite and positive, a measurement model with
    # its own ``mean`` / ``residual``) takes the array path, which also decides what a
    # failure raises.

    def _sigma_1d(self, g: Gaussian
                  ) -> tuple[float, float, float, tuple[float, float, float, float], Array] | None:
        """(p, x0, s, (wm0, wm1, wc0, wc1), X): the 1-D prior's variance and mean, the
        sigma offset s = c sqrt(p), the weights and the points x0, x0 + s, x0 - s (3, 1);
        None if p is not finite and positive."""
        p = g.P.item(0)
        if not 0.0 < p < math.inf:
            return None
        c, wm0, wm1, wc0, wc1 = _scalar_weights(self.alpha, self.beta, self.kappa)
        x0 = g.x.item(0)
        s = c * math.sqrt(p)
        return p, x0, s, (wm0, wm1, wc0, wc1), _array([[x0], [x0 + s], [x0 - s]])

    def _predict_1d(self, g: Gaussian, model: Transition, t: float, dt: float,
                    u: Array | None) -> Gaussian | None:
        sp = self._sigma_1d(g)
        if sp is None:
            return None
        _, _, _, (wm0, wm1, wc0, wc1), X = sp
        (y0,), (y1,), (y2,) = model.f(X, t, dt, u).tolist()
        x = wm0 * y0 + wm1 * y1 + wm1 * y2
        d0, d1, d2 = y0 - x, y1 - x, y2 - x
        P = wc0 * d0 * d0 + wc1 * d1 * d1 + wc1 * d2 * d2 + model.Q(t, dt, u).item(0)
        return Gaussian(_array([x]), _array([[P]]))

    def _update_1d(self, g: Gaussian, z: Array, model: Measurement
                   ) -> tuple[Gaussian, Innovation] | None:
        if type(z) is not np.ndarray or z.shape != (1,):
            return None
        sp = self._sigma_1d(g)
        if sp is None:
            return None
        p, x0, s, (wm0, wm1, wc0, wc1), X = sp
        (z0,), (z1,), (z2,) = model.h(X).tolist()
        zhat = wm0 * z0 + wm1 * z1 + wm1 * z2
        e0, e1, e2 = z0 - zhat, z1 - zhat, z2 - zhat
        S = wc0 * e0 * e0 + wc1 * e1 * e1 + wc1 * e2 * e2 + model.R.item(0)
        if not 0.0 < S < math.inf:
            return None
        Pxz = wc1 * s * e1 + wc1 * -s * e2  # the centre's offset is 0
        i = 1.0 / math.sqrt(S)
        K = Pxz * i * i
        v = z.item() - zhat
        return (Gaussian(_array([x0 + K * v]), _array([[p - K * Pxz]])),
                Innovation(_array([v]), _array([[S]]), v * (v * i * i)))

    def update(
        self, g: Gaussian, z: Array, model: Measurement, rng: Rng | None = None
    ) -> tuple[Gaussian, Innovation]:
        space = model.space
        if type(space) is VectorSpace:
            if (space.dim == 1 and self.points == "merwe" and model.dim == 1
                    and plain_measurement(model)):
                out = self._update_1d(g, z, model)
            else:
                nb = UT_KERNELS.get()
                out = self._update_compiled(nb, g, z, model) if nb else None
            if out is not None:
                return out
        return self._update(g, z, model)

    def _update(self, g: Gaussian, z: Array, model: Measurement
                ) -> tuple[Gaussian, Innovation]:
        """The update on arrays (any space and measurement model; the reference of the
        1-D float path)."""
        space = model.space
        _, Wm, Wc, U = self._w(space.dim)
        D = _dot(U, chol(g.P).T)
        Z = model.h(space.retract(g.x, D))
        zhat = model.mean(Z, Wm)
        A = np.concatenate((D, model.residual(Z, zhat)), axis=1)  # joint [state, meas.] devs
        C = _dot(A.T * Wc, A)
        n = D.shape[1]
        S = C[n:, n:] + model.R
        Pxz = C[:n, n:]
        K, cS = gain_factor(Pxz, S)
        nu = model.residual(z, zhat)
        x = space.retract(g.x, _dot(K, nu))
        # P - K Pxz^T (= P - K S K^T) is symmetric up to rounding; every consumer reads the
        # lower triangle (Cholesky), so no explicit symmetrising is needed here
        P = g.P - _dot(K, Pxz.T)
        return Gaussian(x, P), Innovation(nu, S, nis_from_factor(cS, nu))

    def estimate(self, g: Gaussian) -> Gaussian:
        return g

    # -- many states at once (the tracker: every track of a scan) ------------------------
    def predict_many(self, gs: list[Gaussian], model: Transition, t: float, dt: float,
                     u: Array | None = None, rng: Rng | None = None) -> list[Gaussian]:
        """:meth:`predict` of every Gaussian of ``gs`` with one batched Cholesky and one
        call of ``model.f`` on all sigma points (vector state spaces; the same numbers as
        one at a time up to rounding). Other spaces: one at a time."""
        space = model.space
        if not isinstance(space, VectorSpace) or len(gs) < 2:
            return [self.predict(g, model, t, dt, u, rng) for g in gs]
        _, Wm, Wc, U = self._w(space.dim)
        x = np.stack([g.x for g in gs])
        L = _chol_many(np.stack([g.P for g in gs]))
        T, n = x.shape
        Y = model.f((x[:, None, :] + U @ L.transpose(0, 2, 1)).reshape(-1, n), t, dt, u)
        Y = Y.reshape(T, U.shape[0], n)
        xm = np.einsum("j,tjn->tn", Wm, Y)
        dY = Y - xm[:, None, :]
        P = np.einsum("tjn,j,tjk->tnk", dY, Wc, dY) + model.Q(t, dt, u)
        return [Gaussian(xm[i], P[i]) for i in range(T)]

    def update_many(self, gs: list[Gaussian], zs: Array, model: Measurement,
                    rng: Rng | None = None
                    ) -> list[tuple[Gaussian, Innovation]]:
        """:meth:`update` of every Gaussian of ``gs`` with its measurement ``zs[i]``: one
        batched Cholesky of the covariances, one call of ``model.h`` on all sigma points,
        one batched solve for the gains (vector state spaces and measurement models with a
        batched ``mean_rows``, e.g. the radar; else one at a time)."""
        space = model.space
        if (not isinstance(space, VectorSpace) or not hasattr(model, "mean_rows")
                or len(gs) < 2):
            return [self.update(g, z, model, rng) for g, z in zip(gs, zs, strict=True)]
        _, Wm, Wc, U = self._w(space.dim)
        x = np.stack([g.x for g in gs])
        P = np.stack([g.P for g in gs])
        T, n = x.shape
        D = U @ _chol_many(P).transpose(0, 2, 1)  # (T, J, n)
        Z = model.h((x[:, None, :] + D).reshape(-1, n)).reshape(T, U.shape[0], -1)
        zhat = model.mean_rows(Z, Wm)
        E = model.residual(Z, zhat[:, None, :])
        S = np.einsum("tjm,j,tjk->tmk", E, Wc, E) + model.R
        Pxz = np.einsum("tjn,j,tjm->tnm", D, Wc, E)
        cS = _chol_many(S)
        # K = Pxz S^-1 through the factor: S^-1 = L^-T L^-1
        Kt = np.linalg.solve(cS.transpose(0, 2, 1), np.linalg.solve(cS, Pxz.transpose(0, 2, 1)))
        K = Kt.transpose(0, 2, 1)
        nu = model.residual(np.asarray(zs, float), zhat)
        xn = x + np.einsum("tnm,tm->tn", K, nu)
        Pn = P - K @ Pxz.transpose(0, 2, 1)
        v = np.linalg.solve(cS, nu[:, :, None])[:, :, 0]
        nis = np.einsum("tm,tm->t", v, v)
        return [(Gaussian(xn[i], Pn[i]), Innovation(nu[i], S[i], float(nis[i])))
                for i in range(T)]


def _chol_many(P: Array) -> Array:
    """Lower Cholesky factors of a stack (T, n, n); any that numpy refuses through
    :func:`chol` (jitter) one at a time."""
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        return np.stack([chol(Pi) for Pi in P])


@dataclass(frozen=True)
class CKF(UKF):
    """Cubature Kalman filter: the UKF with the 2n cubature points +-sqrt(n) L_i and
    equal weights (Arasaratnam and Haykin, "Cubature Kalman filters", IEEE TAC 2009).
    No parameters."""

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    points: str = "cubature"
    name: str = "ckf"


# ----------------------------------------------------------------------------- square root


@dataclass(frozen=True, slots=True)
class SqrtGaussian:
    """Mean ``x`` and lower-triangular square root ``S`` of the covariance (P = S S^T)."""

    x: Array
    S: Array


def cholupdate(L: Array, v: Array, sign: float = 1.0) -> Array:
    """Rank-1 update (sign=+1) or downdate (sign=-1) of a lower Cholesky factor:
    returns L' with L' L'^T = L L^T + sign v v^T. Raises LinAlgError if a downdate
    would lose positive definiteness. O(n^2), loop over the n columns only."""
    L = L.copy()
    v = v.astype(float).copy()
    n = v.shape[0]
    for k in range(n):
        r2 = L[k, k] ** 2 + sign * v[k] ** 2
        if r2 <= 0.0 or not np.isfinite(r2):
            raise np.linalg.LinAlgError("cholupdate: downdate lost positive definiteness")
        r = np.sqrt(r2)
        cc = r / L[k, k]
        s = v[k] / L[k, k]
        L[k, k] = r
        if k + 1 < n:
            L[k + 1 :, k] = (L[k + 1 :, k] + sign * s * v[k + 1 :]) / cc
            v[k + 1 :] = cc * v[k + 1 :] - s * L[k + 1 :, k]
    return L


def _qr_lower(A: Array) -> Array:
    """Lower-triangular L with L L^T = A^T A, via QR of A (positive diagonal)."""
    R: Array = np.linalg.qr(A, mode="r")  # type: ignore[assignment]  # (mode r: R only)
    n = A.shape[1]
    R = R[:n, :n]
    sgn = np.sign(np.diag(R))
    sgn[sgn == 0] = 1.0
    res: Array = (R * sgn[:, None]).T
    return res


@dataclass(frozen=True)
class SRUKF(FilterBase):
    """Square-root UKF (Van der Merwe and Wan, "The square-root unscented Kalman filter
    for state and parameter estimation", ICASSP 2001): propagates S = sqrt(P) with a QR
    decomposition of the weighted sigma deviations and a rank-1 Cholesky update for the
    zeroth point (a downdate when Wc_0 < 0), so P stays PSD by construction."""

    alpha: float = field(default=1.0, metadata=param(
        "float", lo=0.0, lo_open=True, doc="sigma-point spread"))
    beta: float = field(default=2.0, metadata=param(
        "float", lo=0.0, doc="prior-distribution term of Wc_0 (2: Gaussian)"))
    kappa: float = field(default=0.0, metadata=param("float", doc="secondary scaling"))
    name: str = "srukf"

    def _w(self, n: int) -> tuple[float, Array, Array, Array]:
        return sigma_weights(n, self.alpha, self.beta, self.kappa, "merwe")

    def init(self, prior: Gaussian, space: Space, rng: Rng | None = None) -> SqrtGaussian:
        return SqrtGaussian(prior.x, chol(prior.P))

    @staticmethod
    def _sqrt_cov(dev: Array, Wc: Array, sqrt_noise: Array) -> Array:
        A = np.vstack([np.sqrt(Wc[1]) * dev[1:], sqrt_noise.T])
        L = _qr_lower(A)
        return cholupdate(L, np.sqrt(abs(Wc[0])) * dev[0], 1.0 if Wc[0] >= 0 else -1.0)

    def predict(self, s: SqrtGaussian, model: Transition, t: float, dt: float,
                u: Array | None = None, rng: Rng | None = None) -> SqrtGaussian:
        space = model.space
        _, Wm, Wc, U = self._w(space.dim)
        D = U @ s.S.T
        Y = model.f(space.retract(s.x, D), t, dt, u)
        x = space.mean(Y, Wm, Y[0])
        dY = space.local(x, Y)
        return SqrtGaussian(x, self._sqrt_cov(dY, Wc, chol(model.Q(t, dt, u))))

    def update(self, s: SqrtGaussian, z: Array, model: Measurement, rng: Rng | None = None
               ) -> tuple[SqrtGaussian, Innovation]:
        space = model.space
        _, Wm, Wc, U = self._w(space.dim)
        D = U @ s.S.T
        Z = model.h(space.retract(s.x, D))
        zhat = model.mean(Z, Wm)
        E = model.residual(Z, zhat)
        Sy = self._sqrt_cov(E, Wc, chol(model.R))
        Pxz = (D.T * Wc) @ E
        # K = Pxz (Sy Sy^T)^-1 by two triangular solves
        K = np.linalg.solve(Sy.T, np.linalg.solve(Sy, Pxz.T)).T
        nu = model.residual(z, zhat)
        x = space.retract(s.x, K @ nu)
        U = K @ Sy
        S = s.S
        for j in range(U.shape[1]):  # m downdates (m = measurement dim, not members)
            S = cholupdate(S, U[:, j], -1.0)
        return SqrtGaussian(x, S), innovation(nu, Sy @ Sy.T)

    def estimate(self, s: SqrtGaussian) -> Gaussian:
        return Gaussian(s.x, s.S @ s.S.T)

    def rts_terms(self, s_prev: Any, s_pred: Any, model: Transition, t: float, dt: float,
                  u: Array | None = None, prev: Gaussian | None = None
                  ) -> tuple[Gaussian, Array]:
        """The sigma-point prediction (a UKF with the same alpha, beta, kappa) of the
        prior and its cross-covariance."""
        g = self.estimate(s_prev) if prev is None else prev
        return UKF(self.alpha, self.beta, self.kappa).predict_cross(g, model, t, dt, u)
