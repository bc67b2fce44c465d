"""Estimation metrics for Monte Carlo runs (errors are truth - estimate in the tangent
space; for the benchmark systems that is plain subtraction).

- RMSE per run: sqrt(mean over time of ||e_k||^2).
- approximation error (Cui, Sun and Wen 2022): mean over time of ||x_pred - x_true||
  (before update).
- estimation error (Cui, Sun and Wen 2022): mean over time of ||x_est - x_true||
  (after update).
- NEES per step: e^T P^-1 e; averaged over time and runs.
"""

from __future__ import annotations

import numpy as np

Array = np.ndarray


def rmse(err: Array) -> float:
    """err (T, n) -> sqrt(mean_t ||e_t||^2)."""
    return float(np.sqrt(np.mean(np.sum(err * err, axis=-1))))


def mean_abs(err: Array) -> float:
    """err (T, n) -> mean_t ||e_t|| (Euclidean norm; |e| in 1-D)."""
    return float(np.mean(np.sqrt(np.sum(err * err, axis=-1))))


def nees(err: Array, P: Array) -> Array:
    """e^T P^-1 e for errors ``err`` (..., n) and covariances ``P`` (..., n, n)."""
    return np.einsum("...i,...i->...", err, np.linalg.solve(P, err[..., None])[..., 0])


def nees_band(n: int, runs: float, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` chi-square band for the NEES of an ``n``-dimensional state
    averaged over ``runs`` samples (a non-integer mean sample count is allowed):
    chi2.ppf([(1-p)/2, (1+p)/2], runs * n) / runs, computed as scipy.stats does it
    (2 gammaincinv(df / 2, q)) without importing scipy.stats (~1.2 s at start-up)."""
    from scipy.special import gammaincinv

    df = runs * n
    lo, hi = 2.0 * gammaincinv(df / 2, np.array([(1 - prob) / 2, (1 + prob) / 2])) / runs
    return float(lo), float(hi)
