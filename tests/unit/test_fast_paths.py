"""The speed paths of issue 13 against the array paths they shortcut (the reference):
the UKF's 1-D float path (``UKF._predict_1d`` / ``_update_1d`` against ``_predict`` /
``_update``), the UKF's compiled vector-space path (``uavest.core._compiled_ut``) and the
default hybrid's kernels (``uavest.core._compiled_shift``) against the numpy path."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import compiled_kernels

from uavest.core import make_filter
from uavest.core.gaussian import Gaussian
from uavest.core.interfaces import Measurement
from uavest.core.linalg import NotPositiveDefinite
from uavest.core.unscented import UKF
from uavest.experiments.systems import build_system, simulate
from uavest.models.benchmarks import UNGMMeasurement, UNGMTransition
from uavest.scenarios import load_scenario, load_typed


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
    out = ukf.update(g, z, _WrappedUNGM())  # (the compiled vector-space path, if numba)
    np.testing.assert_allclose(out[0].x, ref[0].x, rtol=1e-14)
    np.testing.assert_allclose(out[0].P, ref[0].P, rtol=1e-14)
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


# ------------------------------------------------------------------ the hybrid's kernels
def _shift_kernels():
    from uavest.core import hybrid

    return hybrid, compiled_kernels(hybrid.SHIFT_KERNELS.get, "shift kernels")


def _states(name: str, spec: str, steps: int = 30):
    """(filter, transition, measurement, [(ensemble after predict, z, t)]) of one seeded
    run on the numpy path: weighted and equal-weight ensembles, before and after
    regenerations."""
    from uavest.core import hybrid

    sysm = build_system(load_scenario(name, []))
    tr, me = sysm.transition, sysm.measurement
    _, Z = simulate(sysm, 1, np.random.default_rng([0, 1]))
    f = make_filter(spec)
    rng = np.random.default_rng(7)
    keep = hybrid.SHIFT_KERNELS.loaded
    hybrid.SHIFT_KERNELS.loaded = False  # the numpy path
    try:
        E = f.init(sysm.filter_prior, tr.space, rng)
        out = []
        for k in range(steps):
            t = (k + 1) * sysm.dt
            out.append((E, t))
            E = f.predict(E, tr, t, sysm.dt, None, rng)
            out[-1] = (out[-1][0], E, Z[0][k], t)
            E, _ = f.update(E, Z[0][k], me, rng)
    finally:
        hybrid.SHIFT_KERNELS.loaded = keep
    return f, tr, me, out


def _close(a, b, tol=1e-12):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol * max(1.0, float(np.abs(b).max())))


@pytest.mark.parametrize("name, spec", [
    ("ungm", "hybrid"), ("nonlinear2d", "hybrid"), ("ungm", "hybrid(weights=equal)"),
    ("ungm", "hybrid(tau=0.05, min_ess=0.5)"), ("nonlinear2d", "hybrid(n_cloud=8)")])
def test_hybrid_compiled_steps_equal_the_numpy_path(name, spec):
    """From the same ensemble and the same seeded generator, the compiled predict and
    update equal the numpy path (``_HybridBase.predict``, ``HybridShift._update_numpy``) to
    1e-12: members, weights, the estimate, the innovation; and they leave the generator
    in the same state (the same draws in the same order)."""
    hybrid, nb = _shift_kernels()
    f, tr, me, states = _states(name, spec)
    regen = 0
    for E0, E, z, t in states:
        ra, rb = np.random.default_rng(11), np.random.default_rng(11)
        a = hybrid._HybridBase.predict(f, E0, tr, t, 1.0, None, ra)
        b = f.predict(E0, tr, t, 1.0, None, rb)
        regen += E0.w is not None and a.w is None
        _close(b.X, a.X)
        assert (a.w is None) == (b.w is None)
        assert ra.random() == rb.random()
        ra, rb = np.random.default_rng(12), np.random.default_rng(12)
        (ua, ia), (ub, ib) = f._update_numpy(E, z, me, ra), f.update(E, z, me, rb)
        assert ub.gaussian is not None  # the estimate comes with the kernel's result
        _close(ub.X, ua.X)
        assert (ua.w is None) == (ub.w is None)
        if ua.w is not None:
            _close(ub.w, ua.w)
        ga, gb = hybrid.ensemble_estimate(ua), f.estimate(ub)
        _close(gb.x, ga.x)
        _close(gb.P, ga.P)
        _close(ib.nu, ia.nu)
        _close(ib.S, ia.S)
        _close(ib.nis, ia.nis, 1e-11)
        assert ra.random() == rb.random()
    if spec == "hybrid":
        assert regen > 0  # the regeneration kernel was compared too


@pytest.mark.parametrize("name", ["ungm", "nonlinear2d"])
def test_hybrid_compiled_runs_follow_the_numpy_path(name):
    """Whole seeded runs (5 x 60 steps) of the default hybrid, compiled against numpy:
    the estimates stay within 1e-5 (rounding differences that the tempering and
    regeneration decisions never turned into different choices here)."""
    hybrid, nb = _shift_kernels()
    sysm = build_system(load_scenario(name, []))
    tr, me = sysm.transition, sysm.measurement
    _, Z = simulate(sysm, 5, np.random.default_rng([0, 0]))
    f = make_filter("hybrid")

    def run(r, kernels):
        keep = hybrid.SHIFT_KERNELS.loaded
        hybrid.SHIFT_KERNELS.loaded = kernels
        try:
            rng = np.random.default_rng([0, r])
            s = f.init(sysm.filter_prior, tr.space, rng)
            xs = []
            for k in range(60):
                s = f.predict(s, tr, (k + 1) * sysm.dt, sysm.dt, None, rng)
                s, _ = f.update(s, Z[r][k], me, rng)
                xs.append(f.estimate(s).x)
            return np.array(xs)
        finally:
            hybrid.SHIFT_KERNELS.loaded = keep

    for r in range(5):
        np.testing.assert_allclose(run(r, nb), run(r, False), rtol=1e-5, atol=1e-5)


def test_tempered_kernel_equals_tempered_weights():
    """The kernel's tempering (the grid's sums by a recursion, the chosen point directly)
    against ``tempered_weights`` on 3000 random cases (weights equal and skewed,
    likelihood spreads 1e-2 to 1e4): the same phi, weights to 1e-12."""
    hybrid, nb = _shift_kernels()
    from uavest.core import _compiled_shift as cs
    from uavest.core.states import equal_weights

    rng = np.random.default_rng(0)
    grid = 0
    for _ in range(3000):
        M = int(rng.choice([5, 20, 99, 300]))
        if rng.random() < 0.5:
            w = equal_weights(M)
        else:
            w = rng.uniform(0, 1, M) ** rng.uniform(1, 20)
            w /= w.sum()
        ll = -0.5 * (rng.standard_normal(M) * 10 ** rng.uniform(-2, 4)) ** 2
        phi_max, floor = rng.uniform(0.05, 1.0), rng.uniform(0.05, 0.9)
        W0, phi0 = hybrid.tempered_weights(w, ll, phi_max, floor)
        W = np.empty(M)
        phi = cs._tempered(np.array(w), ll, phi_max, floor, W)
        assert phi == phi0
        grid += phi0 != phi_max
        np.testing.assert_allclose(W, W0, rtol=1e-12, atol=1e-300)
    assert grid > 1000


def test_hybrid_compiled_failures_take_the_numpy_path():
    """A non-finite measurement, members or weights: the compiled path hands over to the
    numpy path, which fails or continues as it always has; the guard keeps the estimate
    finite."""
    hybrid, nb = _shift_kernels()
    f, tr, me, states = _states("ungm", "hybrid", 3)
    _, E, z, t = states[-1]
    with np.errstate(invalid="ignore"):  # the numpy path's NaN arithmetic
        _hybrid_failures(f, tr, me, E, z, t)


def _hybrid_failures(f, tr, me, E, z, t):
    from uavest.core import Guarded
    from uavest.core.linalg import NumericalError
    from uavest.core.states import Ensemble

    for bad in (np.array([np.nan]), np.array([np.inf])):
        ra, rb = np.random.default_rng(1), np.random.default_rng(1)
        try:
            ua, _ = f._update_numpy(E, bad, me, ra)
        except np.linalg.LinAlgError as e:
            with pytest.raises(type(e)):
                f.update(E, bad, me, rb)
        else:
            ub, _ = f.update(E, bad, me, rb)
            assert np.array_equal(ua.X, ub.X, equal_nan=True)
    X = E.X.copy()
    X[3] = np.nan
    En = Ensemble(X, E.space, E.w)
    try:
        ua, _ = f._update_numpy(En, z, me, np.random.default_rng(1))
    except np.linalg.LinAlgError as e:
        with pytest.raises(type(e)):
            f.update(En, z, me, np.random.default_rng(1))
    w = np.full(E.M, np.nan)
    with pytest.raises(NumericalError):  # non-finite weights: systematic_resample's error
        f.predict(Ensemble(E.X, E.space, w), tr, t, 1.0, None, np.random.default_rng(1))
    # the guard around the compiled hybrid: NaN measurements never give a NaN estimate
    g = Guarded(f)
    rng = np.random.default_rng(3)
    s = g.init(Gaussian(np.array([0.1]), np.array([[2.0]])), tr.space, rng)
    for k in range(20):
        s = g.predict(s, tr, k + 1.0, 1.0, None, rng)
        s, _ = g.update(s, np.array([np.nan]) if k % 4 == 3 else np.array([1.0]), me, rng)
        assert g.estimate(s).finite()


def test_shift_kernels_can_be_switched_off(monkeypatch):
    from uavest.core import hybrid

    monkeypatch.setattr(hybrid.SHIFT_KERNELS, "loaded", None)
    monkeypatch.setenv("UAVEST_NUMBA", "0")
    assert hybrid.SHIFT_KERNELS.get() is None
    f, tr, me, states = _states("ungm", "hybrid", 2)
    _, E, z, _ = states[-1]
    ua, _ = f.update(E, z, me, np.random.default_rng(1))  # the numpy path
    ub, _ = f._update_numpy(E, z, me, np.random.default_rng(1))
    assert np.array_equal(ua.X, ub.X) and ua.gaussian is None


# ------------------------------------------------------------------- the UKF's kernels
def _ut_kernels():
    from uavest.core import unscented

    return compiled_kernels(unscented.UT_KERNELS.get, "unscented kernels")


def _radar_models():
    from uavest.tracking.scenario import build_models

    motion, radar = build_models(load_typed("radar_far", ["radar.sigma_az_deg=5"]))
    return motion, radar


@pytest.mark.parametrize("ukf", [UKF(), UKF(alpha=0.3, beta=2.0, kappa=1.0),
                                 make_filter("ckf")])
def test_ukf_compiled_steps_equal_the_array_path(ukf):
    """The radar (4-D state; range and azimuth, wrapped residual and circular mean) and
    the 2-D system: one compiled predict and update from random Gaussians equal the
    array path (``_predict`` / ``_update``) to 1e-12."""
    nb = _ut_kernels()
    motion, radar = _radar_models()
    sysm = build_system(load_scenario("nonlinear2d", []))
    rng = np.random.default_rng(5)
    for tr, me, scale in ((motion, radar, 1e3), (sysm.transition, sysm.measurement, 3.0)):
        n = tr.space.dim
        for _ in range(200):
            x = rng.normal(0, scale, n)
            A = rng.normal(size=(n, n)) * scale * 10 ** rng.uniform(-3, 0)
            g = Gaussian(x, A @ A.T + 1e-3 * np.eye(n))
            a = ukf._predict_compiled(nb, g, tr, 3.0, 1.0, None)
            b = ukf._predict(g, tr, 3.0, 1.0, None)[0]
            _close(a.x, b.x)
            _close(a.P, b.P)
            z = me.h(x[None, :] + rng.normal(0, 0.1 * scale, (1, n)))[0]
            (ua, ia), (ub, ib) = ukf._update_compiled(nb, g, z, me), ukf._update(g, z, me)
            _close(ua.x, ub.x)
            _close(ua.P, ub.P, 1e-10)
            _close(ia.nu, ib.nu)
            _close(ia.S, ib.S)
            assert type(ia.nis) is float
            _close(ia.nis, ib.nis, 1e-10)


def test_ukf_compiled_runs_follow_the_array_path():
    """Whole radar runs (5 x 100 scans, coasting through missed detections) with the
    compiled path and with the array path: estimates within 1e-8 (relative)."""
    nb = _ut_kernels()
    from uavest.core import unscented
    from uavest.experiments.radar import data_rng
    from uavest.tracking.scenario import generate_run, prior

    sc = load_typed("radar_far", ["radar.sigma_az_deg=5"])
    motion, radar = _radar_models()
    _, P0 = prior(sc)
    f = UKF()
    for r in range(5):
        rd = generate_run(sc, data_rng(0, r))
        Z = [s[o == 0][0] if np.any(o == 0) else None
             for s, o in zip(rd.scans, rd.origins, strict=True)]
        out = []
        for kernels in (nb, False):
            keep = unscented.UT_KERNELS.loaded
            unscented.UT_KERNELS.loaded = kernels
            try:
                g, xs = Gaussian(rd.x0, P0), []
                for k, z in enumerate(Z):
                    g = f.predict(g, motion, k + 1.0, 1.0)
                    if z is not None:
                        g, _ = f.update(g, z, radar)
                    xs.append(np.concatenate([g.x, g.P.ravel()]))
                out.append(np.array(xs))
            finally:
                unscented.UT_KERNELS.loaded = keep
        np.testing.assert_allclose(out[0], out[1], rtol=1e-8, atol=1e-8)


def test_ukf_compiled_failures_take_the_array_path(monkeypatch):
    """A covariance without a plain factor: the compiled path declines and the array path
    jitters (a PSD-singular P) or raises (an indefinite one) as before; a wrong-sized z
    raises; the kernels can be switched off."""
    nb = _ut_kernels()
    from uavest.core import unscented

    motion, radar = _radar_models()
    x = np.array([1000.0, 2000.0, 10.0, -5.0])
    sing = Gaussian(x, np.diag([100.0, 100.0, 0.0, 4.0]))
    assert UKF()._predict_compiled(nb, sing, motion, 1.0, 1.0, None) is None
    a, b = UKF().predict(sing, motion, 1.0, 1.0), UKF()._predict(sing, motion, 1.0, 1.0,
                                                               None)[0]
    assert np.array_equal(a.P, b.P)
    bad = Gaussian(x, np.diag([100.0, -1.0, 1.0, 4.0]))
    with pytest.raises(NotPositiveDefinite):
        UKF().predict(bad, motion, 1.0, 1.0)
    with pytest.raises(NotPositiveDefinite):
        UKF().update(bad, np.array([2000.0, 1.0]), radar)
    g = Gaussian(x, np.diag([100.0, 100.0, 1.0, 4.0]))
    with pytest.raises(ValueError):
        UKF().update(g, np.array([2000.0, 1.0, 3.0]), radar)
    monkeypatch.setattr(unscented.UT_KERNELS, "loaded", None)
    monkeypatch.setenv("UAVEST_NUMBA", "0")
    assert unscented.UT_KERNELS.get() is None
