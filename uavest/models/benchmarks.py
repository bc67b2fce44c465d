"""Benchmark systems: the UNGM (Gordon, Salmond and Smith 1993; docs/references.md) and a
2-D strongly nonlinear system.

UNGM (univariate nonstationary growth model), with t = k the index of the new state:
    x_k = a x_{k-1} + b x_{k-1} / (1 + x_{k-1}^2) + alpha cos(beta (k - 1)) + w,  w ~ N(0, Q)
    y_k = x_k^2 / c + v,  v ~ N(0, R)
defaults a=0.5, b=25, c=20, alpha=8, beta=1.2, Q=10, R=1 (Q and R are variances).

Nonlinear2D (ours; the hybrid paper's 2-D equations are not recoverable from its text). A
damped rotation plus a UNGM-like growth term and a squared measurement, with one parameter
``nl`` that
sweeps the nonlinearity from a linear system (nl = 0) to a strongly nonlinear one (nl = 1):
    x1' = rho (cos(th) x1 - sin(th) x2) + nl * g x1 / (1 + x1^2)
    x2' = rho (sin(th) x1 + cos(th) x2) + nl * alpha cos(beta k)
    z1  = x1 + nl * (x1^2 / c - x1),   z2 = x2      (z1 = x1^2/c at nl = 1: sign ambiguity)
defaults rho=0.9, th=0.3 rad, g=10, alpha=4, beta=1.2, c=10, Q=diag(1, 1), R=diag(1, 1).
"""

from __future__ import annotations

import math

import numpy as np

from ..core.interfaces import Measurement, Transition
from ..geometry.spaces import VectorSpace


class UNGMTransition(Transition):
    def __init__(self, a=0.5, b=25.0, alpha=8.0, beta=1.2, Q=10.0) -> None:
        self.a, self.b, self.alpha, self.beta = float(a), float(b), float(alpha), float(beta)
        self._Q = np.array([[float(Q)]])
        self.space = VectorSpace(1)

    def f(self, X, t, dt=1.0, u=None):
        return X * (self.a + self.b / (1.0 + X * X)) + self.alpha * math.cos(self.beta * (t - 1))

    def F(self, x, t, dt=1.0, u=None):
        x0 = x[0]
        return np.array([[self.a + self.b * (1.0 - x0 * x0) / (1.0 + x0 * x0) ** 2]])

    def Q(self, t, dt=1.0, u=None):
        return self._Q


class UNGMMeasurement(Measurement):
    def __init__(self, c=20.0, R=1.0) -> None:
        self.c = float(c)
        self.R = np.array([[float(R)]])
        self.space = VectorSpace(1)

    def h(self, X):
        return X * X / self.c

    def H(self, x):
        return np.array([[2.0 * x[0] / self.c]])


class Nonlinear2DTransition(Transition):
    def __init__(self, nl=1.0, rho=0.9, th=0.3, g=10.0, alpha=4.0, beta=1.2, Q=(1.0, 1.0)):
        self.nl, self.rho, self.th, self.g = float(nl), float(rho), float(th), float(g)
        self.alpha, self.beta = float(alpha), float(beta)
        self._Q = np.diag(np.broadcast_to(np.asarray(Q, float), (2,)))
        c, s = np.cos(self.th), np.sin(self.th)
        self._A = self.rho * np.array([[c, -s], [s, c]])
        self.space = VectorSpace(2)

    def f(self, X, t, dt=1.0, u=None):
        Y = X @ self._A.T
        x1 = X[:, 0]
        Y[:, 0] += self.nl * self.g * x1 / (1.0 + x1 * x1)
        Y[:, 1] += self.nl * self.alpha * np.cos(self.beta * t)
        return Y

    def F(self, x, t, dt=1.0, u=None):
        J = self._A.copy()
        x1 = x[0]
        J[0, 0] += self.nl * self.g * (1.0 - x1 * x1) / (1.0 + x1 * x1) ** 2
        return J

    def Q(self, t, dt=1.0, u=None):
        return self._Q


class Nonlinear2DMeasurement(Measurement):
    def __init__(self, nl=1.0, c=10.0, R=(1.0, 1.0)):
        self.nl, self.c = float(nl), float(c)
        self.R = np.diag(np.broadcast_to(np.asarray(R, float), (2,)))
        self.space = VectorSpace(2)

    def h(self, X):
        x1 = X[:, 0]
        return np.stack([x1 + self.nl * (x1 * x1 / self.c - x1), X[:, 1]], axis=1)

    def H(self, x):
        return np.array([[1.0 + self.nl * (2.0 * x[0] / self.c - 1.0), 0.0], [0.0, 1.0]])
