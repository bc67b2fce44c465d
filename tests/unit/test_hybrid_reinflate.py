"""The hybrid's re-spread after its EnKF shift (``reinflate``, :func:`sampling_shrink`):
an ensemble's gain from sample moments takes out of an unobserved state's spread a share
tr(S^-1 Pyy) / N it does not have (Houtekamer and Mitchell 1998's inbreeding); the
re-spread puts it back, keeps the mean, and the navigation preset turns it on."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.core.hybrid import HybridShift, sampling_shrink
from uavest.core.interfaces import LinearMeasurement
from uavest.core.states import Ensemble, ensemble_estimate
from uavest.geometry.rotation import AttitudeSpace
from uavest.geometry.spaces import VectorSpace
from uavest.models.attitude import GravityDirection
from uavest.presets import build, resolve


def test_the_shrink_is_the_measurement_share_over_the_effective_members():
    Pyy, R = np.array([[4.0]]), np.array([[1.0]])
    assert sampling_shrink(Pyy, R, np.full(10, 0.1)) == pytest.approx(0.8 / 10)
    w = np.array([0.5, 0.25, 0.25])  # N = 1 / sum w^2 = 8/3
    assert sampling_shrink(Pyy, R, w) == pytest.approx(0.8 * 0.375)
    # two measurements: the trace of S^-1 Pyy, each direction's share
    Pyy2, R2 = np.diag([4.0, 1.0]), np.diag([1.0, 3.0])
    assert sampling_shrink(Pyy2, R2, np.full(4, 0.25)) == pytest.approx((0.8 + 0.25) / 4)


def _posterior_over_prior_spread(f: HybridShift, M: int, reps: int) -> float:
    """Mean over ``reps`` ensembles of M members of (the unobserved state's sample variance
    after one update) / (before): x0 observed with R = 1, x1 independent of it."""
    me = LinearMeasurement(np.array([[1.0, 0.0]]), np.array([[1.0]]))
    rng = np.random.default_rng(5)
    ratios = []
    for _ in range(reps):
        X = rng.standard_normal((M, 2))
        E, _ = f.update(Ensemble(X, VectorSpace(2)), np.array([0.3]), me, rng)
        ratios.append(np.var(E.X[:, 1], ddof=1) / np.var(X[:, 1], ddof=1))
    return float(np.mean(ratios))


def test_the_respread_undoes_the_sample_gains_shrink_of_an_unobserved_state():
    M, reps = 20, 3000
    # expected shrink without it: tr(S^-1 Pyy) / M = (1 / 2) / 20 = 2.5 % (MC error ~0.3 %)
    plain = _posterior_over_prior_spread(HybridShift(weights="equal"), M, reps)
    fixed = _posterior_over_prior_spread(HybridShift(weights="equal", reinflate=True), M, reps)
    assert 0.96 < plain < 0.985, plain
    assert abs(fixed - 1.0) < 0.01, fixed


@pytest.mark.parametrize("weights", ["equal", "confidence"])
def test_the_respread_keeps_the_weighted_mean_and_scales_the_deviations(weights):
    me = LinearMeasurement(np.array([[1.0, 0.0, 0.0]]), np.array([[0.5]]))
    X = np.random.default_rng(1).standard_normal((40, 3))
    out = {}
    for on in (False, True):
        rng = np.random.default_rng(2)  # the same draws for both
        E, _ = HybridShift(weights=weights, reinflate=on).update(
            Ensemble(X, VectorSpace(3)), np.array([0.4]), me, rng)
        out[on] = E
    a, b = ensemble_estimate(out[False]), ensemble_estimate(out[True])
    np.testing.assert_allclose(b.x, a.x, atol=1e-12)
    if weights == "confidence":  # the weights are the update's, untouched (to rounding:
        # without the re-spread the update may run in the compiled kernel)
        np.testing.assert_allclose(out[True].w, out[False].w, rtol=1e-12)
    ratio = np.diag(b.P) / np.diag(a.P)
    assert np.all(ratio > 1.0) and np.ptp(ratio) < 1e-9, ratio  # one factor, every state


def test_on_the_attitude_manifold_it_keeps_the_mean_and_widens_the_spread():
    space = AttitudeSpace()
    rng0 = np.random.default_rng(3)
    x = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    X = space.retract(x, 0.05 * rng0.standard_normal((60, 6)))
    me = GravityDirection(np.eye(3) * 0.05**2)
    z = np.array([0.0, 0.02, 1.0]) / np.hypot(0.02, 1.0)
    res = {}
    for on in (False, True):
        E, _ = HybridShift(weights="equal", reinflate=on).update(
            Ensemble(X, space), z, me, np.random.default_rng(4))
        res[on] = ensemble_estimate(E)
    # the members are rebuilt about the prior mean (second order in the 0.05-rad spread)
    assert np.linalg.norm(space.local(res[False].x, res[True].x)) < 1e-3
    assert np.all(np.diag(res[True].P) > np.diag(res[False].P))


def test_the_navigation_preset_turns_it_on_and_the_attitude_preset_does_not():
    assert resolve("hybrid", "nav", dim=15).params["reinflate"] is True
    assert resolve("hybrid", "attitude", dim=6).params["reinflate"] is False
    assert resolve("hybrid(reinflate=false)", "nav", dim=15).params["reinflate"] is False
    f = build(resolve("hybrid", "nav", dim=15))
    assert isinstance(f, HybridShift) and f.reinflate and (f.n_cloud, f.tau) == (16, 0.9)
