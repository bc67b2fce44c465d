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


def test_conditional_bounds_per_run_and_looser_than_unconditional():
    """Each run's conditional matrix is the recursion on that run alone, and averaging
    the information over runs with different geometries can only lower the bound
    (Jensen): trace inv(E[J]) <= E[trace inv(J_r)] at every scan."""
    from uavest.eval.pcrlb import conditional_bounds
    from uavest.models.radar import RadarMeasurement

    mot = NearlyConstantVelocity(2, q=0.5)
    meas = RadarMeasurement(ndim=2, sigma_range=10.0, sigma_az=np.deg2rad(5.0))
    rng = np.random.default_rng(1)
    x0 = np.array([5000.0, 5000.0, -50.0, 0.0])
    truths = np.empty((6, 31, 4))
    for r in range(6):
        x = x0 + np.r_[rng.normal(scale=800, size=2), 0, 0]
        for k in range(31):
            truths[r, k] = x
            x = mot.f(x[None], k + 1, 1.0)[0]
    J0 = np.linalg.inv(np.diag([1e6, 1e6, 400.0, 400.0]))
    cond = conditional_bounds(J0, truths, mot, meas, 1.0)
    for r in (0, 3):
        np.testing.assert_allclose(cond[r], pcrlb(J0, truths[r : r + 1], mot, meas, 1.0),
                                   rtol=1e-9)
    unc = position_bound(pcrlb(J0, truths, mot, meas, 1.0), 2)
    avg = np.sqrt(np.einsum("rkii->k", cond[:, :, :2, :2]) / 6)
    assert np.all(unc <= avg * (1 + 1e-9))
    assert unc[-1] < 0.9 * avg[-1]  # and here clearly looser
