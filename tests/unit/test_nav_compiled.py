"""The compiled navigation kernels (``uavest.models._compiled_nav``, numba): the IMU
mechanisation over rows, its tangent Jacobian and the magnetometer's (h, H) on the
navigation state equal their numpy references (``ImuTransition._np_f`` / ``_np_F``, the
``h`` and ``H`` of :class:`OnNav`) to rounding on states, spaces and steps the self-check
does not use, and an EKF run through them equals the numpy run."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import compiled_kernels

from uavest.core.gaussian import Gaussian
from uavest.core.interfaces import Measurement
from uavest.core.kalman import EKF
from uavest.models import navigation as nav_mod
from uavest.models.attitude import AttitudeNoise, MagField, MagHeading
from uavest.models.navigation import ImuTransition, MagFieldRef, NavNoise, OnNav

TOL = 1e-12


@pytest.fixture
def nb():
    return compiled_kernels(nav_mod.NAV_KERNELS.get, "navigation kernels")


def _noises():
    bias = NavNoise(gnss_bias_h=0.5, gnss_bias_v=0.8, gnss_bias_tau=60.0)
    return {"plain": NavNoise(), "gnss bias": bias,
            "bias and mag ref": NavNoise(gnss_bias_h=0.5, gnss_bias_v=0.8, gnss_bias_tau=60.0,
                                         mag_ref_inc=0.02, mag_ref_dec=0.03),
            "mag ref": NavNoise(mag_ref_inc=0.02)}


def _states(tr, M, g):
    n = tr.space.size
    X = g.normal(0.0, 1.0, (M, n)) * np.r_[np.ones(4), 5.0 * np.ones(6),
                                           0.02 * np.ones(3), 0.3 * np.ones(n - 13)]
    X[:, :4] = g.normal(0.0, 1.0, (M, 4))
    X[:, :4] /= np.linalg.norm(X[:, :4], axis=1)[:, None]
    return X


@pytest.mark.parametrize("name", list(_noises()))
@pytest.mark.parametrize("earth", [False, True])
def test_the_mechanisation_and_its_jacobian_equal_numpy(nb, name, earth, monkeypatch):
    tr = ImuTransition(_noises()[name], lat=-0.6, h=1500.0, earth_rate=earth)
    g = np.random.default_rng(7)
    X = _states(tr, 40, g)

    def boom(*a, **k):
        raise AssertionError("the numpy path ran")
    for dt in (0.005, 0.04, 0.3, -0.02):
        u = np.r_[g.normal(0.0, 2.0, 3), g.normal(0.0, 5.0, 3) + [0, 0, -9.8]]
        want_rows = tr._np_f(X, 0.0, dt, u)
        want_one = tr._np_f(X[3], 0.0, dt, u)
        want_F = tr._np_F(X[5], 0.0, dt, u)
        with monkeypatch.context() as m:
            m.setattr(ImuTransition, "_np_f", boom)
            m.setattr(ImuTransition, "_np_F", boom)
            got_rows, got_one = tr.f(X, 0.0, dt, u), tr.f(X[3], 0.0, dt, u)
            got_F = tr.F(X[5], 0.0, dt, u)
        assert got_rows.shape == want_rows.shape and got_one.shape == want_one.shape
        np.testing.assert_allclose(got_rows, want_rows, rtol=0, atol=TOL)
        np.testing.assert_allclose(got_one, want_one, rtol=0, atol=TOL)
        np.testing.assert_allclose(got_F, want_F, rtol=0, atol=TOL)
    # no input: a state at rest (u None is zeros)
    np.testing.assert_allclose(tr.f(X, 0.0, 0.01), tr._np_f(X, 0.0, 0.01), rtol=0, atol=TOL)
    np.testing.assert_allclose(tr.F(X[0], 0.0, 0.01), tr._np_F(X[0], 0.0, 0.01), rtol=0,
                               atol=TOL)


def test_a_rotation_too_small_for_the_sine_takes_the_series(nb):
    """w - b_g of 1e-9 rad/s (the series branches of Exp and J_r) and exactly 0."""
    tr = ImuTransition(NavNoise())
    X = _states(tr, 3, np.random.default_rng(1))
    for w in (1e-9, 0.0):
        X[:, 10:13] = [w, 0.0, -w]
        u = np.array([2 * w, 0.0, -2 * w, 0.1, 0.2, -9.8])
        np.testing.assert_allclose(tr.f(X, 0.0, 0.04, u), tr._np_f(X, 0.0, 0.04, u), rtol=0,
                                   atol=TOL)
        np.testing.assert_allclose(tr.F(X[0], 0.0, 0.04, u), tr._np_F(X[0], 0.0, 0.04, u),
                                   rtol=0, atol=TOL)


@pytest.mark.parametrize("inner", ["heading", "heading vertical", "field"])
@pytest.mark.parametrize("back", [0.0, 0.013, -0.01])
def test_the_magnetometer_h_H_equals_numpy(nb, inner, back, monkeypatch):
    g = np.random.default_rng(3)
    tr = ImuTransition(NavNoise(gnss_bias_h=0.5, gnss_bias_tau=60.0))
    m_in = {"heading": MagHeading(np.array([0.21, -0.07, 0.38]), np.eye(1)),
            "heading vertical": MagHeading(np.array([0.0, 0.0, 0.4]), np.eye(1)),
            "field": MagField(np.array([0.48, -0.02, 0.87]), np.eye(3))}[inner]
    for x in _states(tr, 12, g):
        w = g.normal(0.0, 1.5, 3)
        m = OnNav(m_in, back, w if back else None)
        want = Measurement.h_H(m, x)
        with monkeypatch.context() as mp:
            mp.setattr(OnNav, "H", lambda self, x: (_ for _ in ()).throw(AssertionError))
            got = m.h_H(x)
        assert got[1].shape == want[1].shape == (m_in.R.shape[0], tr.space.dim)
        np.testing.assert_allclose(got[0], want[0], rtol=0, atol=TOL)
        np.testing.assert_allclose(got[1], want[1], rtol=0, atol=TOL)


def test_the_magnetic_reference_states_keep_their_own_h_and_H(nb, monkeypatch):
    """MagFieldRef (an OnNav whose H has the reference's columns) is not the kernel's."""
    called = []
    noise = NavNoise(mag_ref_inc=0.02, mag_ref_dec=0.03)
    space = nav_mod.nav_space(noise)
    m = MagFieldRef(np.array([0.48, -0.02, 0.87]), np.eye(3), space, 0.01, np.ones(3))
    monkeypatch.setattr(OnNav, "_nb_h_H", lambda *a: called.append(1))
    x = _states(ImuTransition(noise), 1, np.random.default_rng(0))[0]
    h, H = m.h_H(x)
    assert not called and H.shape == (3, space.dim) and np.any(H[:, -2:] != 0.0)


def test_an_ekf_run_through_the_kernels_equals_the_numpy_run(nb, monkeypatch):
    """200 predict / magnetometer / GNSS-velocity steps of the 18-state EKF, once compiled
    and once with the kernels switched off, from the same seeded inputs."""
    tr = ImuTransition(NavNoise(gnss_bias_h=0.5, gnss_bias_v=0.8, gnss_bias_tau=60.0))
    ekf = EKF()

    def run():
        g = np.random.default_rng(11)
        x = np.zeros(tr.space.size)
        x[0] = 1.0
        s = Gaussian(x, np.eye(tr.space.dim) * 0.01)
        out = []
        for _ in range(200):
            u = np.r_[g.normal(0.0, 0.3, 3), g.normal(0.0, 1.0, 3) + [0, 0, -9.8]]
            s = ekf.predict(s, tr, 0.0, 0.04, u)
            z, mm = MagHeading.from_field(g.normal(0.0, 0.3, 3) + [0.3, 0.0, 0.4],
                                          AttitudeNoise(), 0.1)
            s, _ = ekf.update(s, z, OnNav(mm, 0.01, u[:3]))
            s, _ = ekf.update(s, g.normal(0.0, 0.1, 3),
                              nav_mod.GnssVelocity(np.eye(3) * 0.01))
            out.append(s.x)
        return np.array(out), s.P

    X1, P1 = run()
    monkeypatch.setattr(nav_mod.NAV_KERNELS, "loaded", False)
    X0, P0 = run()
    assert np.all(np.isfinite(X1))
    np.testing.assert_allclose(X1, X0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(P1, P0, rtol=0, atol=1e-12)


def test_a_zero_quaternion_gives_nan_as_numpy_does_not_an_exception(nb):
    """A diverged state's zero quaternion: the kernels divide by its norm, and give NaN as
    the numpy forms do (error_model="numpy"), for the filter guard to count and recover,
    not a ZeroDivisionError no caller catches (the attitude kernels' retract too)."""
    from uavest.geometry import rotation

    tr = ImuTransition(NavNoise())
    x = np.zeros(tr.space.size)
    u = np.array([0.1, 0.0, 0.0, 0.0, 0.0, -9.8])
    with np.errstate(all="ignore"):
        want_f, want_F = tr._np_f(x, 0.0, 0.04, u), tr._np_F(x, 0.0, 0.04, u)
        want_r = rotation._np_retract_rows(np.zeros(7), np.zeros((1, 6)))
    got_f, got_F = tr.f(x, 0.0, 0.04, u), tr.F(x, 0.0, 0.04, u)
    np.testing.assert_array_equal(np.isnan(got_f), np.isnan(want_f))
    np.testing.assert_array_equal(np.isnan(got_F), np.isnan(want_F))
    assert np.isnan(got_f[:4]).all()
    m = OnNav(MagHeading(np.array([0.2, 0.0, 0.4]), np.eye(1)), 0.01, np.ones(3))
    h, H = m.h_H(x)
    assert h.shape == (1,) and H.shape == (1, tr.space.dim)
    got_r = rotation.retract_rows(np.zeros(7), np.zeros((1, 6)))
    np.testing.assert_array_equal(np.isnan(got_r), np.isnan(want_r))


@pytest.mark.parametrize("extra, mag", [(0, 0), (3, 0), (3, 2)])
def test_the_navigation_space_rows_go_through_the_compiled_kernels(nb, extra, mag):
    """NavSpace's retract / local / mean on the filters' shapes (one state or rows against
    rows) take the attitude space's compiled kernels at the navigation width: the same
    numbers as the kernels called directly, and the numpy rows (``nav_retract_rows``,
    ``nav_local_rows``, ``nav_mean``) to 1e-12, on strided and contiguous arguments, both
    quaternion signs, angles from 1e-9 rad to ~3 rad."""
    from uavest.geometry import rotation
    from uavest.geometry.navigation import NavSpace, nav_local_rows, nav_mean, nav_retract_rows

    mk = compiled_kernels(rotation.MANIFOLD_KERNELS.get, "attitude kernels")
    space = NavSpace(extra, mag)
    g = np.random.default_rng(3 + extra + mag)
    for M in (1, 37, 629):
        X = g.normal(0.0, 1.0, (M, space.size))
        X[:, :4] /= np.linalg.norm(X[:, :4], axis=1)[:, None]
        X[::3, :4] *= -1.0
        wide = g.normal(0.0, 1.0, (M, space.dim + 2)) * 10 ** g.uniform(-9, 0.5, (M, 1))
        dx = wide[:, 1:-1]  # (strided rows)
        for x in (X[1 % M], X):
            got = space.retract(x, dx)
            np.testing.assert_array_equal(got, mk.retract_rows(np.atleast_2d(x), dx))
            np.testing.assert_allclose(got, nav_retract_rows(x, dx), rtol=0, atol=TOL)
            d = space.local(x, got)
            np.testing.assert_array_equal(d, mk.local_rows(np.atleast_2d(x), got))
            np.testing.assert_allclose(d, nav_local_rows(x, got), rtol=0, atol=TOL)
        w = g.uniform(0.1, 1.0, M)
        w /= w.sum()
        Xs = nav_retract_rows(X[0], g.normal(0.0, 0.05, (M, space.dim)))
        np.testing.assert_allclose(space.mean(Xs, w, Xs[0]), nav_mean(Xs, w, Xs[0]), rtol=0,
                                   atol=TOL)


@pytest.mark.parametrize("extra, mag", [(0, 0), (3, 2), (None, None)])
def test_the_members_moments_take_one_compiled_call(nb, extra, mag, monkeypatch):
    """``ensemble_moments`` on the quaternion-row spaces (NavSpace; ``None``: the attitude
    space) takes the fused kernel (``QuatRowsSpace.weighted_moments``): the mean from the
    heaviest member, the centred deviations and the covariance equal the composition of
    ``mean`` / ``local`` and numpy's weighted sums (the path without the kernels) to 1e-12,
    weighted and equal-weight, with both quaternion signs among the members."""
    from uavest.core.states import Ensemble, ensemble_estimate, ensemble_moments, equal_weights
    from uavest.geometry import rotation
    from uavest.geometry.navigation import NavSpace

    compiled_kernels(rotation.MANIFOLD_KERNELS.get, "attitude kernels")
    space = rotation.AttitudeSpace() if extra is None else NavSpace(extra, mag)
    g = np.random.default_rng(9)
    x = np.r_[0.6, -0.3, 0.7, 0.2, g.normal(0.0, 1.0, space.size - 4)]
    x[:4] /= np.linalg.norm(x[:4])
    for M, weighted in ((629, True), (221, False), (2, True)):
        X = space.retract(x, g.normal(0.0, 0.2, (M, space.dim)))
        X[::4, :4] *= -1.0
        w = g.uniform(0.2, 1.0, M) if weighted else None
        E = Ensemble(X, space, None if w is None else w / w.sum())
        got = ensemble_moments(E)
        assert ensemble_estimate(E).P is got[3]  # the fused moments give the estimate
        np.testing.assert_array_equal(got[3], got[3].T)
        assert space.weighted_moments(X, got[2]) is not None
        with monkeypatch.context() as m:
            m.setattr(rotation.MANIFOLD_KERNELS, "loaded", False)
            assert space.weighted_moments(X, got[2]) is None
            want = ensemble_moments(Ensemble(X, space, E.w))
        assert (got[2] is equal_weights(M)) == (not weighted)
        for p, q in zip(got, want, strict=True):
            np.testing.assert_allclose(p, q, rtol=0, atol=TOL)
        assert got[1].shape == (M, space.dim) and np.abs(got[2] @ got[1]).max() < 1e-15


def test_rotating_rows_by_rows_takes_the_kernel(monkeypatch):
    """``quat_rotate`` of rows by rows (the carried GNSS velocity's specific force on the
    members) takes the compiled ``rotate_rows``, equal to numpy's product with the
    rotation matrices to 1e-15, strided and contiguous; other shapes stay numpy's."""
    from uavest.geometry import rotation

    mk = compiled_kernels(rotation.MANIFOLD_KERNELS.get, "attitude kernels")
    g = np.random.default_rng(4)
    X = g.normal(0.0, 1.0, (300, 16))
    X[:, :4] /= np.linalg.norm(X[:, :4], axis=1)[:, None]
    V = g.normal(0.0, 5.0, (300, 3))
    want = np.einsum("...ij,...j->...i", rotation.quat_to_dcm(X[:, :4]), V)
    got = rotation.quat_rotate(X[:, :4], V)
    np.testing.assert_array_equal(got, mk.rotate_rows(X[:, :4], V))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rotation.quat_rotate(X[:, :4], X[:, 13:16]),
                               np.einsum("...ij,...j->...i", rotation.quat_to_dcm(X[:, :4]),
                                         X[:, 13:16]), rtol=0, atol=1e-14)
    with monkeypatch.context() as m:
        m.setattr(rotation.MANIFOLD_KERNELS, "loaded", False)
        np.testing.assert_allclose(rotation.quat_rotate(X[:, :4], V), got, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rotation.quat_rotate(X[0, :4], V[0]), want[0], rtol=0,
                               atol=1e-14)


def test_the_magnetometer_back_dating_of_rows_equals_numpy(nb):
    """``OnNav._q`` on rows (sigma points, members): the compiled back-dating (each row's
    attitude ``back`` s before, by its own gyro bias) equals the numpy one to 1e-12; one
    state keeps the numpy form."""
    tr = ImuTransition(_noises()["bias and mag ref"])
    g = np.random.default_rng(5)
    X = _states(tr, 300, g)
    m = OnNav(MagHeading(np.array([0.2, -0.05, 0.4]), np.eye(1)), 0.03,
              np.array([0.4, -1.2, 2.0]))
    got = m._q(X)
    np.testing.assert_array_equal(got, nb.back_q_rows(X, m.w, -m.back))
    np.testing.assert_allclose(got, m._np_q(X), rtol=0, atol=TOL)
    np.testing.assert_array_equal(m._q(X[4]), m._np_q(X[4]))
    assert OnNav(m.inner)._q(X) is not None and np.shares_memory(OnNav(m.inner)._q(X), X)


def test_a_hybrid_run_through_the_kernels_equals_the_numpy_run(nb, monkeypatch):
    """60 predict / magnetometer heading and field (back-dated) / GNSS-velocity steps of
    the navigation preset's hybrid (527 members on the 15-state space), once through the
    compiled kernels (mechanisation, the space's rows, the back-dating, the update's
    ``shift_tangent``) and once with them switched off,
    from the same seeded inputs and draws: the same estimates to 1e-8."""
    from uavest.core import hybrid
    from uavest.core.guard import Guarded
    from uavest.geometry import rotation
    from uavest.presets import build

    compiled_kernels(rotation.MANIFOLD_KERNELS.get, "attitude kernels")
    tr = ImuTransition(NavNoise())
    f = Guarded(build("hybrid", "nav", dim=tr.space.dim))

    def run():
        g = np.random.default_rng(11)
        rng = np.random.default_rng(12)
        x = np.zeros(tr.space.size)
        x[0] = 1.0
        s = f.init(Gaussian(x, np.eye(tr.space.dim) * 0.01), tr.space, rng)
        out = []
        for _ in range(60):
            u = np.r_[g.normal(0.0, 0.3, 3), g.normal(0.0, 1.0, 3) + [0, 0, -9.8]]
            s = f.predict(s, tr, 0.0, 0.04, u, rng)
            z, mm = MagHeading.from_field(g.normal(0.0, 0.3, 3) + [0.3, 0.0, 0.4],
                                          AttitudeNoise(), 0.1)
            s, _ = f.update(s, z, OnNav(mm, 0.01, u[:3]), rng)
            ref = np.array([0.6, 0.05, 0.8])
            zf = ref + g.normal(0.0, 0.05, 3)
            s, _ = f.update(s, zf / np.linalg.norm(zf),
                            OnNav(MagField(ref, np.eye(3) * 0.01), 0.01, u[:3]), rng)
            s, _ = f.update(s, g.normal(0.0, 0.1, 3), nav_mod.GnssVelocity(np.eye(3) * 0.01),
                            rng)
            e = f.estimate(s)
            out.append(np.r_[e.x, np.diag(e.P)])
        return np.array(out)

    Y1 = run()
    monkeypatch.setattr(nav_mod.NAV_KERNELS, "loaded", False)
    monkeypatch.setattr(rotation.MANIFOLD_KERNELS, "loaded", False)
    monkeypatch.setattr(hybrid.SHIFT_KERNELS, "loaded", False)
    Y0 = run()
    assert np.all(np.isfinite(Y1))
    np.testing.assert_allclose(Y1, Y0, rtol=0, atol=1e-8)


def test_the_hybrid_update_on_the_navigation_state_goes_through_its_kernel(nb):
    """The navigation preset's hybrid (``reinflate``) updates a prior with its memoised
    moments through ``shift_tangent`` for every measurement whose residual and mean are
    plain (GNSS position and velocity, baro, the magnetometer's field, the field against
    reference states) or an angle's (the magnetometer's heading, here with the members'
    headings on both sides of +-pi), equal to the numpy path to 1e-12 from the same draws;
    a prior without its moments and a model with a residual of its own take the numpy
    path (None)."""
    from uavest.core import hybrid
    from uavest.core.states import Ensemble, ensemble_moments
    from uavest.geometry import rotation
    from uavest.geometry.navigation import NavSpace
    from uavest.presets import build

    sk = compiled_kernels(hybrid.SHIFT_KERNELS.get, "shift kernels")
    g = np.random.default_rng(3)
    space = NavSpace(extra=3, mag=2)  # the GNSS bias and magnetic reference states too
    f = build("hybrid", "nav", dim=space.dim)
    assert f.reinflate
    x = np.zeros(space.size)
    x[0] = 1.0
    x[4:7] = [3.0, -1.0, 0.5]
    E = f.init(Gaussian(x, np.diag(np.r_[0.01 * np.ones(3), np.ones(6), 1e-4 * np.ones(6),
                                         0.04 * np.ones(3), 1e-3 * np.ones(2)])), space, g)
    E = Ensemble(E.X, space, g.uniform(0.5, 1.5, E.M) / E.M)
    E = Ensemble(E.X, space, E.w / E.w.sum())
    ensemble_moments(E)
    u = np.array([0.1, -0.2, 0.05])
    field = np.array([0.6, 0.05, 0.8])
    plain = [
        (np.array([2.9, -1.1, 0.6]), nav_mod.GnssVelocity(np.eye(3) * 0.01)),
        (np.array([0.5, 0.3, -0.2]), nav_mod.GnssPosition(np.eye(3) * 0.25)),
        (np.array([0.1]), nav_mod.BaroHeight(np.eye(1) * 0.04)),
        (field / np.linalg.norm(field), OnNav(MagField(field, np.eye(3) * 0.01), 0.02, u)),
        (field / np.linalg.norm(field), MagFieldRef(field, np.eye(3) * 0.01, space, 0.02, u)),
    ]
    # the heading where the members' headings straddle +-pi (the prior's yaw about 180
    # deg less the field's 0.08 rad): the wrapped residuals and mean
    psi = np.pi - np.arctan2(field[1], field[0])
    Xh = E.X.copy()
    Xh[:, :4] = rotation.quat_mul(np.array([np.cos(psi / 2), 0.0, 0.0, np.sin(psi / 2)]),
                                  E.X[:, :4])
    Eh = Ensemble(Xh, space, E.w)
    ensemble_moments(Eh)
    zh, mm = MagHeading.from_field(field, AttitudeNoise(), -3.1)
    heading = OnNav(mm, 0.02, u)
    hy = heading.h(Xh)[:, 0]
    assert (hy > 3.0).any() and (hy < -3.0).any()  # (both sides of the cut)
    for E1, z, model, how in [(E, *zm, "plain") for zm in plain] + [(Eh, zh, heading, "angle")]:
        assert model.arithmetic() == how
        a, ia = f._update_numpy(E1, z, model, np.random.default_rng(7))
        got = f._update_tangent(sk, E1, z, model, np.random.default_rng(7))
        assert got is not None, type(model).__name__
        b, ib = got
        for p, q in ((a.X, b.X), (a.w, b.w), (ia.nu, ib.nu), (ia.S, ib.S)):
            np.testing.assert_allclose(q, p, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ib.nis, ia.nis, rtol=1e-10)
        assert not np.array_equal(b.X, E1.X)  # it did move the members
    bare = Ensemble(E.X, space, E.w)
    assert f._update_tangent(sk, bare, *plain[0], np.random.default_rng(7)) is None

    class _Odd(nav_mod.GnssVelocity):  # a residual of its own: the numpy path's
        def residual(self, a, b):
            return 2.0 * (a - b)

    odd = _Odd(np.eye(3) * 0.01)
    assert odd.arithmetic() is None
    assert f._update_tangent(sk, E, plain[0][0], odd, np.random.default_rng(7)) is None
