"""State spaces: a retraction ``retract`` and its local inverse ``local``.

Following UKF-M (Brossard et al.), every filter works on a state ``x`` of ambient size
``size`` whose uncertainty lives in a tangent space of dimension ``dim``. Sigma points,
ensemble members and corrections are built in the tangent space and mapped back with
``retract``; deviations are read with ``local``. For plain vectors both are ``+``/``-``.

All functions are vectorised: ``x`` is ``(size,)`` or ``(M, size)``, ``dx`` is ``(dim,)``
or ``(M, dim)``; broadcasting follows numpy.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

Array = np.ndarray


class Space(Protocol):
    """What a filter needs to know about its state space."""

    dim: int  # tangent dimension n (covariances are n x n)
    size: int  # ambient size of the state array

    def retract(self, x: Array, dx: Array) -> Array:
        """Move from ``x`` along tangent vector(s) ``dx``."""

    def local(self, x: Array, y: Array) -> Array:
        """Tangent vector(s) at ``x`` that ``retract`` maps to ``y`` (inverse of retract)."""

    def mean(self, X: Array, w: Array, x0: Array | None = None) -> Array:
        """Weighted mean of points ``X`` (M, size) with weights ``w`` (M,) summing to 1."""


class VectorSpace:
    """Euclidean R^n: retract is addition, local is subtraction, mean is the weighted sum."""

    __slots__ = ("dim", "size")

    def __init__(self, dim: int) -> None:
        self.dim = int(dim)
        self.size = int(dim)

    def retract(self, x: Array, dx: Array) -> Array:
        res: Array = x + dx
        return res

    def local(self, x: Array, y: Array) -> Array:
        res: Array = y - x
        return res

    def mean(self, X: Array, w: Array, x0: Array | None = None) -> Array:
        res: Array = w @ X
        return res

    def __repr__(self) -> str:
        return f"VectorSpace({self.dim})"


def manifold_mean(
    space: Space, X: Array, w: Array, x0: Array, iters: int = 5, tol: float = 1e-10
) -> Array:
    """Iterated tangent-space weighted mean (Karcher mean) for non-Euclidean spaces.

    Starting at ``x0``, repeatedly averages ``local(x, X)`` and retracts, as UKF-on-manifold
    implementations do. Used by spaces whose ``mean`` is not a plain weighted sum.
    """
    x = x0
    for _ in range(iters):
        d = w @ space.local(x, X)
        x = space.retract(x, d)
        if float(d @ d) < tol:
            break
    return x
