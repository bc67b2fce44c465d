"""The PCRLB recursion equals the Kalman covariance on a linear-Gaussian model, and
bench-level sanity of the bound on a radar scenario."""

import numpy as np

from uavest.core import KF, Gaussian, LinearMeasurement
from uavest.eval.pcrlb import pcrlb, position_bound
from uavest.eval.tracking import nees_band
from uavest.models.motion import NearlyConstantVelocity


def test_pcrlb_equals_kalman_covariance_linear_gaussian():
    mot = NearlyConstantVelocity(2, q=0.5)
    H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    meas = LinearMeasurement(H, np.diag([100.0, 25.0]))
    P0 = np.diag([1e4, 1e4, 100.0, 100.0])
    rng = np.random.default_rng(0)
    truths = np.cumsum(rng.normal(size=(3, 51, 4)), axis=1)  # irrelevant for linear models
    B = pcrlb(np.linalg.inv(P0), truths, mot, meas, 1.0)
    g = Gaussian(np.zeros(4), P0)
    kf = KF()
    for k in range(50):
        g = kf.predict(g, mot, k + 1, 1.0)
        g, _ = kf.update(g, np.zeros(2), meas)
        np.testing.assert_allclose(B[k], g.P, rtol=1e-8, atol=1e-8)
    assert position_bound(B, 2)[-1] < position_bound(B, 2)[0]


def test_pcrlb_missed_detections_increase_bound():
    mot = NearlyConstantVelocity(1, q=1.0)
    meas = LinearMeasurement(np.array([[1.0, 0.0]]), np.array([[4.0]]))
    truths = np.zeros((2, 11, 2))
    J0 = np.eye(2) * 0.01
    full = pcrlb(J0, truths, mot, meas, 1.0)
    det = np.ones((2, 10))
    det[:, 5] = 0.0
    miss = pcrlb(J0, truths, mot, meas, 1.0, detected=det)
    assert miss[5, 0, 0] > full[5, 0, 0]
    np.testing.assert_allclose(miss[:5], full[:5])


def test_nees_band_matches_brief():
    lo, hi = nees_band(4, 100)
    assert abs(lo - 3.46) < 0.01 and abs(hi - 4.57) < 0.01
