"""The speed paths of issue 13 against the array paths they shortcut (the reference):
the UKF's 1-D float path (``UKF._predict_1d`` / ``_update_1d`` against ``_predict`` /
``_update``)."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.core import make_filter
from uavest.core.gaussian import Gaussian
from uavest.core.linalg import NotPositiveDefinite
from uavest.core.model import Measurement
from uavest.core.unscented import UKF
from uavest.experiments.systems import build_system, simulate
from uavest.models.benchmarks import UNGMMeasurement, UNGMTransition
from uavest.scenarios import load_scenario


def _ungm():
    sysm = build_system(load_scenario("ungm", []))
    return sysm, sysm.transition, sysm.measurement


class _WrappedUNGM(UNGMMeasurement):
    """The UNGM measurement with its own (equal) residual: not 'plain', so the UKF takes
    the array path."""

    def residual(self, a, b):
        return a - b


@pytest.mark.parametrize("ukf", [UKF(), UKF(alpha=0.5, beta=2.0, kappa=1.0)])
def test_ukf_1d_float_path_equals_the_array_path_per_step(ukf):
    """One predict and one update from the same Gaussian, over states and variances
    spanning 1e-6 to 1e6: the float path equals the array path to rounding."""
    tr, me = UNGMTransition(), UNGMMeasurement()
    rng = np.random.default_rng(3)
    for _ in range(400):
        x = rng.normal(0, 10) * 10 ** rng.uniform(-2, 1)
        g = Gaussian(np.array([x]), np.array([[10 ** rng.uniform(-6, 6)]]))
        t = float(rng.integers(1, 100))
        a, b = ukf.predict(g, tr, t, 1.0), ukf._predict(g, tr, t, 1.0, None)[0]
        assert a.x.shape == (1,) and a.P.shape == (1, 1)
        np.testing.assert_allclose(a.x, b.x, rtol=1e-14, atol=1e-14 * np.sqrt(g.P[0, 0]))
        np.testing.assert_allclose(a.P, b.P, rtol=1e-13)
        z = np.array([rng.normal(x * x / 20, 3)])
        (ua, ia), (ub, ib) = ukf.update(g, z, me), ukf._update(g, z, me)
        np.testing.assert_allclose(ua.x, ub.x, rtol=1e-12, atol=1e-12 * np.sqrt(g.P[0, 0]))
        np.testing.assert_allclose(ua.P, ub.P, rtol=1e-10, atol=1e-13 * g.P[0, 0])
        np.testing.assert_allclose(ia.nu, ib.nu, rtol=1e-13, atol=1e-13 * abs(z[0]))
        np.testing.assert_allclose(ia.S, ib.S, rtol=1e-13)
        assert type(ia.nis) is float
        np.testing.assert_allclose(ia.nis, ib.nis, rtol=1e-11)
        assert ia.nu.shape == ib.nu.shape and ia.S.shape == ib.S.shape


def test_ukf_1d_float_path_follows_the_array_path_over_ungm_runs():
    """Whole seeded UNGM runs (20 x 100 steps), the float path against the array path:
    rounding differences stay at rounding level (the UKF does not amplify them)."""
    sysm, tr, me = _ungm()
    _, Z = simulate(sysm, 20, np.random.default_rng([0, 0]))
    f = make_filter("ukf")
    for r in range(len(Z)):
        a = b = sysm.filter_prior
        for k, z in enumerate(Z[r]):
            a = f.predict(a, tr, k + 1.0, sysm.dt)
            b = f._predict(b, tr, k + 1.0, sysm.dt, None)[0]
            (a, ia), (b, ib) = f.update(a, z, me), f._update(b, z, me)
            np.testing.assert_allclose(a.x, b.x, rtol=1e-8, atol=1e-8)
            np.testing.assert_allclose(a.P, b.P, rtol=1e-8)
            np.testing.assert_allclose(ia.nis, ib.nis, rtol=1e-8, atol=1e-10)


def test_ukf_1d_outside_the_fast_case_takes_the_array_path():
    """A measurement with its own residual, the cubature set and a 2-D state take the
    array path (same numbers: they are it); a covariance that is not positive, or a
    non-finite innovation variance, falls through to it and fails as it does."""
    tr, me = UNGMTransition(), UNGMMeasurement()
    g = Gaussian(np.array([1.5]), np.array([[4.0]]))
    z = np.array([2.0])
    ukf = UKF()
    ref = ukf._update(g, z, me)
    out = ukf.update(g, z, _WrappedUNGM())
    assert np.array_equal(out[0].x, ref[0].x) and np.array_equal(out[0].P, ref[0].P)
    bad = Gaussian(np.array([1.5]), np.array([[-1.0]]))
    with pytest.raises(NotPositiveDefinite):
        ukf.predict(bad, tr, 1.0, 1.0)
    with pytest.raises(NotPositiveDefinite):
        ukf.update(bad, z, me)
    nan = Gaussian(np.array([np.nan]), np.array([[4.0]]))
    a, b = ukf.predict(nan, tr, 1.0, 1.0), ukf._predict(nan, tr, 1.0, 1.0, None)[0]
    assert np.isnan(a.x).all() and np.isnan(b.x).all()
    with pytest.raises(ValueError):
        ukf.update(g, np.array([1.0, 2.0]), me)  # a wrong-sized z raises on both paths
    with pytest.raises(ValueError):
        ukf._update(g, np.array([1.0, 2.0]), me)
    # a z given as a list or a 0-d array: the array path's broadcasting
    (a, _), (b, _) = ukf.update(g, [2.0], me), ukf._update(g, z, me)
    assert np.array_equal(a.x, b.x)


def test_ukf_plain_measurement_check():
    from uavest.core.unscented import plain_measurement

    assert plain_measurement(UNGMMeasurement())
    assert not plain_measurement(_WrappedUNGM())
    assert issubclass(_WrappedUNGM, Measurement)
