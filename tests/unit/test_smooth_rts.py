"""RTS smoothing: exact on a linear-Gaussian random walk (matches the batch solution),
and on the attitude manifold it beats filtering for ekf (RTS), ukf (unscented RTS) and
hybrid (ensemble RTS)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from uavest.apps.replay import replay_arrays
from uavest.engine.smooth import rts_backward
from uavest.eval.attitude import rmse_deg
from uavest.geometry.spaces import VectorSpace
from uavest.models.attitude import AttitudeNoise

sys.path.insert(0, str(Path(__file__).parent))
from test_attitude_models import synthetic_constant_rate  # noqa: E402


def test_rts_matches_batch_least_squares_on_random_walk():
    rng = np.random.default_rng(0)
    N, q, r, p0 = 40, 0.3, 0.5, 2.0
    z = np.cumsum(rng.normal(0, np.sqrt(q), N)) + rng.normal(0, np.sqrt(r), N)
    # forward Kalman filter, steps 0..N (step 0 = prior, no measurement)
    xf, Pf = np.zeros((N + 1, 1)), np.zeros((N + 1, 1, 1))
    xp, Pp, C = xf.copy(), Pf.copy(), Pf.copy()
    xf[0], Pf[0] = 0.0, p0
    for k in range(1, N + 1):
        xp[k], Pp[k] = xf[k - 1], Pf[k - 1] + q
        C[k] = Pf[k - 1]  # F = 1
        K = Pp[k, 0, 0] / (Pp[k, 0, 0] + r)
        xf[k] = xp[k] + K * (z[k - 1] - xp[k])
        Pf[k] = (1 - K) * Pp[k]
    xs, Ps = rts_backward(VectorSpace(1), xf, Pf, xp, Pp, C)
    # batch: minimise x0^2/p0 + sum (x_k - x_{k-1})^2/q + sum (z_k - x_k)^2/r
    A = np.zeros((N + 1, N + 1))
    b = np.zeros(N + 1)
    A[0, 0] += 1 / p0
    for k in range(1, N + 1):
        A[k, k] += 1 / q + 1 / r
        A[k - 1, k - 1] += 1 / q
        A[k, k - 1] -= 1 / q
        A[k - 1, k] -= 1 / q
        b[k] += z[k - 1] / r
    x_batch = np.linalg.solve(A, b)
    np.testing.assert_allclose(xs[:, 0], x_batch, atol=1e-10)
    np.testing.assert_allclose(Ps[:, 0, 0], np.diag(np.linalg.inv(A)), atol=1e-10)


@pytest.mark.parametrize("spec", ["ekf", "ukf", "hybrid"])
def test_smoothing_beats_filtering_on_the_manifold(spec):
    d = synthetic_constant_rate(rate_hz=20.0, seconds=15.0, seed=3)
    # noisy gyro, noisy accel/mag: smoothing has something to gain
    rng = np.random.default_rng(5)
    gyro = d["gyro"] + 0.05 * rng.standard_normal(d["gyro"].shape)
    accel = d["accel"] + 0.3 * rng.standard_normal(d["accel"].shape)
    noise = AttitudeNoise(gyro_noise=0.012, rate_walk=0.01, accel_noise=0.4, mag_noise=0.05)
    r = replay_arrays(d["t"], gyro, accel, d["t"], d["mag"], filters=[spec], noise=noise,
                      declination=d["decl"], seed=2, smooth=True, rate_hz=0)
    xs, Ps = r.xs[spec], r.Ps[spec]
    late = r.t > 2.0
    f = rmse_deg(r.x[spec][:, :4], d["q"][1:], late)
    s = rmse_deg(xs[:, :4], d["q"][1:], late)
    tot_f = np.hypot(np.hypot(f["roll_rmse_deg"], f["pitch_rmse_deg"]), f["yaw_rmse_deg"])
    tot_s = np.hypot(np.hypot(s["roll_rmse_deg"], s["pitch_rmse_deg"]), s["yaw_rmse_deg"])
    assert tot_s < 0.8 * tot_f, (spec, f, s)
    # smoothed covariance is no larger than filtered (attitude block trace)
    assert np.trace(Ps[10:-10, :3, :3].mean(0)) < np.trace(r.P[spec][10:-10, :3, :3].mean(0))
