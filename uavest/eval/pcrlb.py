"""Posterior Cramér-Rao lower bound (PCRLB) by the Tichavsky recursion.

For x_k = f(x_{k-1}) + w_k, w_k ~ N(0, Q_k) and z_k = h(x_k) + v_k, v_k ~ N(0, R_k)
(Tichavsky, Muravchik, Nehorai 1998), the Fisher information J_k obeys

    J_k = D22 - D21 (J_{k-1} + D11)^-1 D12
    D11 = E[F^T Q^-1 F],  D12 = D21^T = -E[F^T] Q^-1,  D22 = Q^-1 + E[H^T R^-1 H]

with F = df/dx at x_{k-1} and H = dh/dx at x_k; the expectations are Monte Carlo
averages over the supplied truth trajectories. J_0 = P_0^-1 for a Gaussian prior. The
bound on any estimator's error covariance is E[(x^ - x)(x^ - x)^T] >= J_k^-1.

On a linear-Gaussian model the recursion reproduces the Kalman filter covariance exactly
(tested in ``tests/unit/test_radar_pcrlb.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..core.interfaces import Measurement, Transition

Array = np.ndarray


def pcrlb(
    J0: Array,
    truths: Array,
    transition: Transition,
    measurement: Measurement | Callable[[int], Measurement],
    dt: float,
    t0: float = 0.0,
    detected: Array | None = None,
) -> Array:
    """Bounds J_k^-1 for k = 1..K, shape (K, n, n).

    Args:
      J0: prior information (n, n), e.g. inv(P0).
      truths: truth trajectories (runs, K + 1, n), index 0 the initial state x_0.
      transition: motion model (its ``F`` at each truth state, ``Q``).
      measurement: a measurement model, or a callable ``k -> model`` (e.g. a moving sensor).
      dt: step (s); step k ends at ``t0 + k dt``.
      detected: optional (runs, K) 0/1 array; a missed detection contributes no
        measurement information for that run (information-reduction factor by Monte Carlo).
    """
    return _tichavsky(J0, truths, transition, measurement, dt, t0, detected, per_run=False)


def conditional_bounds(
    J0: Array,
    truths: Array,
    transition: Transition,
    measurement: Measurement | Callable[[int], Measurement],
    dt: float,
    t0: float = 0.0,
    detected: Array | None = None,
) -> Array:
    """The same recursion run separately on each truth trajectory: (runs, K, n, n).

    Run r's matrix is the covariance of a Kalman filter linearised at that run's own
    truth (an oracle), i.e. the information the run's measurements carry along its own
    path. It is **not** a lower bound (the posterior mean can beat it), but it shows how
    loose the unconditional bound :func:`pcrlb` is: averaging the information E[H^T R^-1 H]
    over runs whose measurement geometries differ gives inv(E[J]) <= E[inv(J)] (Jensen),
    so a tight range measurement seen from slightly different directions in different
    runs adds cross-range information that no single run has. Same arguments as
    :func:`pcrlb`.
    """
    return _tichavsky(J0, truths, transition, measurement, dt, t0, detected, per_run=True)


def _tichavsky(J0, truths, transition, measurement, dt, t0, detected, per_run: bool) -> Array:
    """The recursion with run-averaged expectations (J (n, n)) or per run (J (R, n, n))."""
    R_, K1, n = truths.shape
    J = np.broadcast_to(np.asarray(J0, float), (R_, n, n)).copy() if per_run else (
        np.asarray(J0, float))
    out = np.empty((R_, K1 - 1, n, n) if per_run else (K1 - 1, n, n))
    linear = getattr(transition, "linear", False)
    for k in range(1, K1):
        t = t0 + k * dt
        Qi = np.linalg.inv(transition.Q(t, dt))
        if linear:
            Fs = np.broadcast_to(transition.F(truths[0, k - 1], t, dt), (R_, n, n))
        else:
            Fs = np.stack([transition.F(truths[i, k - 1], t, dt) for i in range(R_)])
        meas = measurement(k) if callable(measurement) and not isinstance(
            measurement, Measurement
        ) else measurement
        Hs = np.stack([meas.H(truths[i, k]) for i in range(R_)])
        if detected is not None:
            Hs = Hs * detected[:, k - 1, None, None]
        D11 = np.einsum("rji,jk,rkl->ril", Fs, Qi, Fs)
        D12 = -np.einsum("rji,jk->rik", Fs, Qi)
        D22 = Qi + np.einsum("rji,jk,rkl->ril", Hs, np.linalg.inv(meas.R), Hs)
        if not per_run:  # expectations over the truths (D12 is linear in F)
            D11, D12, D22 = D11.mean(axis=0), D12.mean(axis=0), D22.mean(axis=0)
        J = D22 - np.swapaxes(D12, -1, -2) @ np.linalg.solve(J + D11, D12)
        J = 0.5 * (J + np.swapaxes(J, -1, -2))
        if per_run:
            out[:, k - 1] = np.linalg.inv(J)
        else:
            out[k - 1] = np.linalg.inv(J)
    return out


def position_bound(B: Array, ndim: int) -> Array:
    """sqrt(trace of the position block) of bounds ``B`` (K, n, n) -> (K,) metres."""
    return np.sqrt(np.einsum("kii->k", B[:, :ndim, :ndim]))


def velocity_bound(B: Array, ndim: int) -> Array:
    """sqrt(trace of the velocity block) of bounds ``B`` (K, n, n) -> (K,) m/s."""
    return np.sqrt(np.einsum("kii->k", B[:, ndim : 2 * ndim, ndim : 2 * ndim]))
