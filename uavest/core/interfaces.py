"""Model interfaces the filters call (Stone Soup's split, kept small).

A :class:`Transition` maps states over one step; a :class:`Measurement` maps states to
measurements. Both are vectorised over rows: ``f`` and ``h`` take ``X`` shaped
``(M, size)`` and return ``(M, size)`` / ``(M, m)``. Process noise is additive in the
tangent space (``Q`` is n x n); measurement noise is additive in measurement space.

Jacobians ``F``/``H`` are tangent-space Jacobians; models supply analytic ones by
overriding ``F``/``H``, otherwise central finite differences through ``retract`` are used.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..geometry.spaces import Space, VectorSpace

Array = np.ndarray


class Transition:
    """Base transition model. Subclasses set ``space`` and implement ``f`` and ``Q``.

    ``t`` is the time at the *end* of the step (s, or the step index for discrete
    benchmarks), ``dt`` the step length, ``u`` an optional control/input (e.g. gyro rates).
    """

    space: Space
    linear: bool = False

    def f(self, X: Array, t: float, dt: float, u: Array | None = None) -> Array:
        raise NotImplementedError

    def Q(self, t: float, dt: float, u: Array | None = None) -> Array:
        raise NotImplementedError

    def F(self, x: Array, t: float, dt: float, u: Array | None = None) -> Array:
        """Tangent-space Jacobian of ``f`` at ``x`` (n x n); finite differences by default."""
        return fd_jacobian(lambda X: self.f(X, t, dt, u), self.space, self.space, x)


class Measurement:
    """Base measurement model. Subclasses implement ``h`` and set ``R`` (m x m).

    ``residual(a, b)`` is ``a - b`` with any wrapping (angles) the measurement needs, and
    ``mean(Y, w)`` the matching weighted mean; both default to plain arithmetic.
    """

    space: Space  # the *state* space the model reads
    R: Array
    linear: bool = False

    def h(self, X: Array) -> Array:
        raise NotImplementedError

    def H(self, x: Array) -> Array:
        """Jacobian of ``h`` w.r.t. the tangent-space state error at ``x`` (m x n)."""
        return fd_jacobian(self.h, self.space, None, x)

    def h_H(self, x: Array) -> tuple[Array, Array]:
        """(h(x), H(x)) of one state ``x``: what the EKF's update needs. Models whose
        measurement and Jacobian share work override it (the radar)."""
        return self.h(x[None, :])[0], self.H(x)

    def h_H_rows(self, X: Array) -> tuple[Array, Array]:
        """(h(X), H_rows(X)): measurements and Jacobians of every row of ``X`` (what the
        local-gain hybrid needs). Models whose two share work override it (the radar)."""
        return self.h(X), self.H_rows(X)

    def linearise_rows(self, X: Array, z: Array, w: Array
                       ) -> tuple[Array, Array, Array, Array]:
        """What the local-gain hybrid's update reads of the model at the rows ``X``
        (M, size) given the measurement ``z`` (m,) and weights ``w`` (M,): the Jacobians
        ``Hs`` (M, m, n), the residuals ``nu`` = residual(z, h(X_j)) (M, m), the rows'
        deviations ``dY`` = residual(h(X_j), ybar) (M, m) from their weighted mean
        ``ybar`` = mean(h(X), w), and ``nubar`` = residual(z, ybar) (m,).

        Composed here from :meth:`h_H_rows`, :meth:`residual` and :meth:`mean`; a model
        may override it with a fused (compiled) version giving the same arrays to
        rounding (the radar)."""
        Y, Hs = self.h_H_rows(X)
        ybar = self.mean(Y, w)
        return Hs, self.residual(z, Y), self.residual(Y, ybar), self.residual(z, ybar)

    def H_rows(self, X: Array) -> Array:
        """Jacobians at every row of ``X`` (M, size) -> (M, m, n), tangent-space; batched
        central finite differences through ``retract`` and ``residual`` by default."""
        return fd_jacobians(self.h, self.residual, self.space, X)

    def residual(self, a: Array, b: Array) -> Array:
        res: Array = a - b
        return res

    def mean(self, Y: Array, w: Array) -> Array:
        res: Array = np.dot(w, Y)  # = w @ Y, with less per-call overhead
        return res

    def arithmetic(self) -> str | None:
        """How :meth:`residual` and :meth:`mean` compute, for a compiled update to do them
        in its own loops: "plain" (``a - b`` and ``w @ Y``: neither is overridden),
        "angle" (every component an angle: ``wrap_pi(a - b)`` and the weighted mean of the
        rows wrapped about the first, as :class:`~uavest.models.attitude.MagHeading`
        says), None (anything else). A model that overrides either says which it is."""
        return "plain" if plain_measurement(self) else None

    @property
    def dim(self) -> int:
        res: int = self.R.shape[0]
        return res


def fd_jacobian(fun: Callable[[Array], Array], space: Space, out_space: Space | None, x: Array,
                eps: float = 1e-6) -> Array:
    """Central finite-difference Jacobian of ``fun`` (vectorised) at ``x``.

    Perturbs ``x`` in its tangent space; reads outputs through ``out_space.local`` (or plain
    differences when ``out_space`` is None, i.e. measurements). One batched call of ``fun``.
    """
    n = space.dim
    scale = eps * np.maximum(1.0, np.abs(x[:n])) if isinstance(space, VectorSpace) else np.full(
        n, eps
    )
    D = np.diag(scale)
    X = space.retract(x, np.vstack([D, -D]))
    Y = fun(X)
    if out_space is None:
        dY = Y[:n] - Y[n:]
    else:
        y0 = fun(x[None, :])[0]
        dY = out_space.local(y0, Y[:n]) - out_space.local(y0, Y[n:])
    res: Array = (dY / (2.0 * scale[:, None])).T
    return res


def fd_jacobians(fun: Callable[[Array], Array], residual: Callable[[Array, Array], Array],
                 space: Space, X: Array, eps: float = 1e-6) -> Array:
    """Central finite-difference Jacobians of the vectorised ``fun`` at every row of ``X``
    (M, size) -> (M, m, n), differences read through ``residual`` (e.g. wrapped angles).
    One batched call of ``fun`` on 2 n M rows; no Python loop over rows."""
    M, n = X.shape[0], space.dim
    if isinstance(space, VectorSpace):
        scale = eps * np.maximum(1.0, np.abs(X[:, :n]))
    else:
        scale = np.full((M, n), eps)
    D = (scale[:, :, None] * np.eye(n)).reshape(M * n, n)  # row (i, j): scale_ij e_j
    Xr = np.repeat(X, n, axis=0)
    Y = fun(np.vstack([space.retract(Xr, D), space.retract(Xr, -D)]))
    dY = residual(Y[: M * n], Y[M * n :]).reshape(M, n, -1)
    res: Array = (dY / (2.0 * scale[:, :, None])).transpose(0, 2, 1)
    return res


class LinearTransition(Transition):
    """x_k = F x_{k-1} (+ B u) + w, w ~ N(0, Q). ``F``/``Q`` fixed matrices."""

    linear = True

    def __init__(self, F: Array, Q: Array, B: Array | None = None) -> None:
        self._F = np.asarray(F, float)
        self._Q = np.asarray(Q, float)
        self._B = None if B is None else np.asarray(B, float)
        self.space = VectorSpace(self._F.shape[0])

    def f(self, X: Array, t: float, dt: float, u: Array | None = None) -> Array:
        Y: Array = X @ self._F.T
        if self._B is not None and u is not None:
            Y = Y + self._B @ u
        return Y

    def Q(self, t: float, dt: float, u: Array | None = None) -> Array:
        return self._Q

    def F(self, x: Array, t: float, dt: float, u: Array | None = None) -> Array:
        return self._F


class LinearMeasurement(Measurement):
    """z = H x + v, v ~ N(0, R)."""

    linear = True

    def __init__(self, H: Array, R: Array) -> None:
        self._H = np.atleast_2d(np.asarray(H, float))
        self.R = np.atleast_2d(np.asarray(R, float))
        self.space = VectorSpace(self._H.shape[1])

    def h(self, X: Array) -> Array:
        Y: Array = X @ self._H.T
        return Y

    def H(self, x: Array) -> Array:
        return self._H

    def H_rows(self, X: Array) -> Array:
        return np.broadcast_to(self._H, (X.shape[0], *self._H.shape))


def plain_measurement(model: Measurement) -> bool:
    """True if the model's ``mean`` and ``residual`` are the plain weighted sum and
    difference of :class:`Measurement` (a wrapper that delegates its attributes, e.g. the
    adaptive filters' noise override, gives False: the safe answer)."""
    t = type(model)
    return (getattr(t, "mean", None) is Measurement.mean
            and getattr(t, "residual", None) is Measurement.residual)
