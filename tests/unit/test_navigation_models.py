"""Navigation model: analytic Jacobians against finite differences, gating, and the
registry's filters on a seeded synthetic straight-and-turn flight."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.core import Gaussian, fd_jacobian, make_filter
from uavest.geometry.navigation import NavSpace
from uavest.geometry.rotation import euler_to_quat, quat_rotate_inv
from uavest.models.attitude import MagField
from uavest.models.navigation import (
    BaroHeight,
    GnssPosition,
    GnssVelocity,
    ImuTransition,
    NavNoise,
    OnNav,
    innovation_gate,
    nav_dim,
    nav_space,
)

SP = NavSpace()


def _point(rng):
    q = rng.normal(size=4)
    return np.concatenate([q / np.linalg.norm(q), rng.normal(size=3) * 5,
                           rng.normal(size=3) * 50, rng.normal(size=3) * 0.01,
                           rng.normal(size=3) * 0.1])


@pytest.mark.parametrize("earth_rate", [False, True])
def test_imu_F_matches_finite_differences(earth_rate):
    rng = np.random.default_rng(0)
    tr = ImuTransition(NavNoise(), lat=np.deg2rad(47.0), h=400.0, earth_rate=earth_rate)
    for _ in range(5):
        x = _point(rng)
        u = np.concatenate([rng.normal(size=3) * 0.5, rng.normal(size=3) * 3 + [0, 0, -9.8]])
        dt = 0.02
        ref = fd_jacobian(lambda X, u=u, dt=dt: tr.f(X, 0.0, dt, u), SP, SP, x)
        tol = 1e-6 if not earth_rate else 1e-5  # Earth rate's q-dependence not in F
        np.testing.assert_allclose(tr.F(x, 0.0, dt, u), ref, atol=tol)


def test_gnss_H_matches_finite_differences():
    rng = np.random.default_rng(1)
    x = _point(rng)
    for m in (GnssPosition(np.eye(3)), GnssVelocity(np.eye(3)),
              GnssPosition(np.eye(2), rows=(0, 1))):
        ref = fd_jacobian(m.h, SP, None, x)
        np.testing.assert_allclose(m.H(x), ref, atol=1e-7)


def test_measurements_moved_back_in_time_match_finite_differences():
    """A GNSS velocity and position, a baro height and a magnetometer field older than the state
    (``back`` s): analytic H (and the rows the hybrid reads) against finite differences."""
    rng = np.random.default_rng(2)
    f = np.array([0.8, -1.5, -9.3])
    w = np.array([0.4, -0.3, 0.9])
    mref = np.array([0.44, 0.02, 0.9])
    mref /= np.linalg.norm(mref)
    models = (GnssVelocity(np.eye(3), back=0.03, f=f, g=9.8),
              GnssVelocity(np.eye(2), rows=(0, 1), back=0.03, f=f, g=9.8),
              GnssPosition(np.eye(3), back=0.2, k=0.02, f=f, g=9.8),
              GnssPosition(np.eye(2), rows=(0, 1), back=0.2, k=0.02, f=f, g=9.8),
              BaroHeight(np.eye(1), offset=3.0, back=0.05),
              OnNav(MagField(mref, np.eye(3) * 1e-4), 0.05, w))
    for _ in range(3):
        x = _point(rng)
        for m in models:
            ref = fd_jacobian(m.h, SP, None, x)
            np.testing.assert_allclose(m.H(x), ref, atol=2e-7)
        X = np.array([_point(rng) for _ in range(4)])
        for m in models[:4]:
            Hs = m.H_rows(X)
            for k in range(4):
                np.testing.assert_allclose(Hs[k], m.H(X[k]), atol=1e-12)
    # back = 0 is the plain model
    x = _point(rng)
    np.testing.assert_allclose(GnssVelocity(np.eye(3), back=0.0, f=f, g=9.8).h(x[None]),
                               x[None, 4:7])


def test_fix_type_gating_and_100m_jump_rejected():
    n = NavNoise()
    assert GnssPosition.from_fix([1, 2, 3], 1, 1.0, 1.0, n) is None
    z, m = GnssPosition.from_fix([1, 2, 3], 2, 1.0, 1.0, n)
    assert m.dim == 2 and z.shape == (2,)
    z, m = GnssPosition.from_fix([1, 2, 3], 3, 0.1, None, n)
    assert m.dim == 3 and m.R[0, 0] == n.gnss_pos_floor**2
    S = m.R + np.eye(3)
    assert innovation_gate(np.array([1.0, -1.0, 0.5]), S, 16.27)
    assert not innovation_gate(np.array([100.0, 0.0, 0.0]), S, 16.27)


def _flight(seed, steps=1500, dt=0.02, rate=0.0, mag=False):
    """Truth and noisy IMU/GNSS for 10 s straight then a 20 s coordinated-ish turn:
    (truth, IMU, fix position, fix velocity) per step. ``rate`` (rad/s^2): the gyro bias
    ramps at it on every axis (as an ArduPilot SITL's ``SIM_DRIFT_SPEED``); ``mag``: a
    10-Hz magnetometer's reading (or None) appended to each step's tuple."""
    rng = np.random.default_rng(seed)
    tr = ImuTransition(NavNoise())
    bg, ba = np.array([0.01, -0.005, 0.003]), np.array([0.1, -0.05, 0.08])
    x = np.concatenate([euler_to_quat(0.0, 0.0, 0.3), [5.0, 1.5, 0.0], np.zeros(3), bg, ba])
    out = []
    for k in range(steps):
        x[10:13] = bg + rate * k * dt
        wz = 0.0 if k * dt < 10 else 0.15
        w = np.array([0.02 * np.sin(0.5 * k * dt), 0.01, wz])
        # specific force so the velocity turns with the body (centripetal) and no climb
        v_b = quat_rotate_inv(x[:4], x[4:7])
        a_b = np.cross(w, v_b)
        f = a_b - quat_rotate_inv(x[:4], np.array([0, 0, tr.g]))
        u_true = np.concatenate([w + x[10:13], f + ba])
        xn = tr.f(x[None], 0.0, dt, u_true)[0]
        u = u_true + np.concatenate([rng.normal(size=3) * 0.003 / np.sqrt(dt),
                                     rng.normal(size=3) * 0.05 / np.sqrt(dt)])
        x = xn
        zp = zv = zm = None
        if k % 10 == 9:  # 5 Hz GNSS
            zp = x[7:10] + rng.normal(size=3) * [0.5, 0.5, 1.0]
            zv = x[4:7] + rng.normal(size=3) * 0.1
        if mag and k % 5 == 4:  # 10 Hz magnetometer, 0.01 rad per axis
            zb = quat_rotate_inv(x[:4], M_REF) + rng.normal(size=3) * 0.01
            zm = zb / np.linalg.norm(zb)
        out.append((x.copy(), u, zp, zv) + ((zm,) if mag else ()))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("spec", ["ekf", "ukf", "hybrid"])
def test_filters_converge_and_are_consistent_on_a_synthetic_flight(spec):
    n = NavNoise()
    tr = ImuTransition(n)
    data = _flight(3)
    x0 = data[0][0].copy()
    rng = np.random.default_rng(7)
    x0 = SP.retract(x0, np.concatenate([rng.normal(size=3) * 0.03, rng.normal(size=3) * 0.5,
                                        rng.normal(size=3) * 2, np.zeros(6)]))
    P0 = np.diag([0.05**2] * 3 + [1.0] * 3 + [9.0] * 3 + [0.01**2] * 3 + [0.2**2] * 3)
    f = make_filter(spec)
    s = f.init(Gaussian(x0, P0), SP, np.random.default_rng(11))
    Rp, Rv = np.diag([0.25, 0.25, 1.0]), np.eye(3) * 0.01
    nees, errs = [], []
    for k, (xt, u, zp, zv) in enumerate(data):
        s = f.predict(s, tr, k * 0.02, 0.02, u, rng)
        if zp is not None:
            s, _ = f.update(s, zp, GnssPosition(Rp), rng)
            s, _ = f.update(s, zv, GnssVelocity(Rv), rng)
        g = f.estimate(s)
        assert np.all(np.isfinite(g.x))
        if k > 500:
            e = SP.local(g.x, xt[None])[0]
            errs.append(e)
            nees.append(float(e[:9] @ np.linalg.solve(g.P[:9, :9], e[:9])))
    errs = np.array(errs)
    assert np.sqrt(np.mean(errs[:, 3:6] ** 2)) < 0.3  # velocity, m/s
    assert np.sqrt(np.mean(errs[:, 6:8] ** 2)) < 1.0  # horizontal position, m
    assert np.degrees(np.sqrt(np.mean(errs[:, :2] ** 2))) < 1.0  # tilt, deg
    if spec == "hybrid":
        # the hybrid is over-confident in attitude on this model (mean attitude NEES 8-16
        # against 3 for filter seeds 11-14, in band on 5-94 % of steps: docs/navigation.md);
        # here only: not diverged
        assert np.mean(nees) < 60.0
        return
    # 9-dof NEES within its 99 % band most of the time
    assert np.mean(np.array(nees) < 21.67) > 0.8


def test_noise_profile_follows_the_imu_rate() -> None:
    """A telemetry-rate MAVLink IMU gets the fitted MAVLink profile, a 200 Hz one the
    fast-stream profile, a DataFlash IMU the plain defaults; an unknown rate keeps the
    telemetry profile."""
    from uavest.models.navigation import (
        FAST_MAVLINK_PROFILE,
        FAST_STREAM_HZ,
        MAVLINK_PROFILE,
        NavNoise,
        nav_noise_for_source,
    )

    assert nav_noise_for_source("RAW_IMU", 3.8) == MAVLINK_PROFILE
    assert nav_noise_for_source("RAW_IMU") == MAVLINK_PROFILE
    assert nav_noise_for_source("RAW_IMU", 200.0) == FAST_MAVLINK_PROFILE
    assert nav_noise_for_source("SCALED_IMU2", FAST_STREAM_HZ) == FAST_MAVLINK_PROFILE
    assert nav_noise_for_source("IMU[0]", 3.8) == NavNoise()
    assert MAVLINK_PROFILE.gyro_noise > NavNoise().gyro_noise


def test_imu_filter_delay_of_every_streamed_ardupilot_imu() -> None:
    """RAW_IMU, SCALED_IMU* and HIGHRES_IMU carry ArduPilot's filtered IMU alike (the live
    link streams HIGHRES_IMU from the SITL): the group delay of its INS_GYRO_FILTER
    low-pass, sqrt(2)/(2 pi f_c); none without the parameter or for another source."""
    from uavest.engine.navigation import imu_filter_delay

    want = np.sqrt(2.0) / (2.0 * np.pi * 20.0)
    for src in ("RAW_IMU", "SCALED_IMU2", "HIGHRES_IMU"):
        d, why = imu_filter_delay(src, {"INS_GYRO_FILTER": 20.0})
        assert d == pytest.approx(want) and "INS_GYRO_FILTER" in why
        assert imu_filter_delay(src, {})[0] == 0.0
    assert imu_filter_delay("sensor_combined", {"INS_GYRO_FILTER": 20.0})[0] == 0.0


def _turning_flight(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A turning, accelerating flight sampled at ``t`` (s): body rate (rad/s, constant),
    specific force (m/s^2, body FRD) and attitude (body to NED)."""
    from uavest.geometry.rotation import quat_exp, quat_mul
    w = np.array([0.3, -0.5, 1.1])
    q0 = euler_to_quat(0.2, -0.1, 0.7)
    q = np.array([quat_mul(q0, quat_exp(w * tk)) for tk in t])
    f = np.c_[2.0 * np.sin(3 * t), 1.5 * np.cos(2 * t), -9.8 + 1.0 * np.sin(5 * t)]
    return np.broadcast_to(w, f.shape), f, q


def test_window_and_carry_forces_match_the_integrated_flight():
    """:func:`window_force` / :func:`carry_force` against the velocity and position of a
    finely integrated turning flight: the mean velocity over a 0.35 s window 0.08 s back
    and the position 0.26 s back, from the state at the end and 25 Hz steps."""
    from uavest.engine.nav_aiding import carry_force, window_force
    from uavest.geometry.rotation import quat_rotate
    g = 9.8
    t0, t_end, h = 0.0, 2.0, 1e-4
    tt = np.arange(t0, t_end + h / 2, h)
    w, f, q = _turning_flight(tt)
    a = np.array([quat_rotate(qk, fk) for qk, fk in zip(q, f, strict=True)]) + [0.0, 0.0, g]
    v = np.cumsum(a, axis=0) * h  # v(t0) = 0
    p = np.cumsum(v, axis=0) * h
    # 25 Hz steps: (end, length, rate, mean specific force over the step)
    edges = np.arange(t0, t_end + 1e-9, 0.04)
    steps = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (tt > lo) & (tt <= hi)
        # the mean force in the body frame at the step's end (a step's mean, as the IMU)
        steps.append((float(hi), 0.04, w[0], f[m].mean(axis=0)))
    qe = q[-1]
    center, span = t_end - 0.08 - 0.175, 0.35
    back, fw = window_force(steps, t_end, center, span)
    win = (tt >= center - span / 2) & (tt <= center + span / 2)
    v_mean = v[win].mean(axis=0)
    model = v[-1] - back * (quat_rotate(qe, fw) + [0.0, 0.0, g])
    assert back == pytest.approx(0.255)
    np.testing.assert_allclose(model, v_mean, atol=2e-3)
    # without the window's weighting (the step's force at the end) it is far worse
    naive = v[-1] - back * (quat_rotate(qe, steps[-1][3]) + [0.0, 0.0, g])
    assert np.linalg.norm(naive - v_mean) > 10 * np.linalg.norm(model - v_mean)
    t_fix = t_end - 0.26
    back, k, fp = carry_force(steps, t_end, t_fix)
    i = int(np.argmin(abs(tt - t_fix)))
    model_p = p[-1] - back * v[-1] + k * (quat_rotate(qe, fp) + [0.0, 0.0, g])
    assert k == pytest.approx(0.5 * 0.26**2)
    np.testing.assert_allclose(model_p, p[i], atol=1e-3)


# ------------------------------------------------------------------ GNSS bias states

BIAS = NavNoise(gnss_bias_h=0.8, gnss_bias_v=1.5, gnss_bias_tau=60.0)
SPB = NavSpace(extra=3)


def _point_b(rng):
    return np.concatenate([_point(rng), rng.normal(size=3) * [0.8, 0.8, 1.5]])


def test_gnss_bias_states_only_when_asked():
    assert not NavNoise().gnss_bias and ImuTransition(NavNoise()).space.dim == 15
    assert not NavNoise(gnss_bias_h=0.8).gnss_bias  # no correlation time: no states
    assert BIAS.gnss_bias and ImuTransition(BIAS).space == SPB and SPB.dim == 18
    assert nav_dim({}) == 15 and nav_dim({"gnss_bias_h": 1.0, "gnss_bias_tau": 30.0}) == 18


def test_gnss_bias_transition_F_and_Q_match_the_gauss_markov_process():
    rng = np.random.default_rng(5)
    tr = ImuTransition(BIAS, lat=np.deg2rad(47.0), h=400.0)
    dt = 0.04
    for _ in range(3):
        x = _point_b(rng)
        u = np.concatenate([rng.normal(size=3) * 0.5, rng.normal(size=3) * 3 + [0, 0, -9.8]])
        ref = fd_jacobian(lambda X, u=u: tr.f(X, 0.0, dt, u), SPB, SPB, x)
        np.testing.assert_allclose(tr.F(x, 0.0, dt, u), ref, atol=1e-6)
        # the first 16 components move as without the bias states
        np.testing.assert_allclose(tr.f(x, 0.0, dt, u)[:16],
                                   ImuTransition(NavNoise(), lat=np.deg2rad(47.0),
                                                 h=400.0).f(x[:16], 0.0, dt, u), atol=1e-12)
    # the bias keeps its steady variance: phi^2 sigma^2 + q = sigma^2 on every axis
    F, Q = tr.F(x, 0.0, dt, u), tr.Q(0.0, dt)
    sb2 = np.array([0.8, 0.8, 1.5]) ** 2
    np.testing.assert_allclose(np.diag(F)[15:] ** 2 * sb2 + np.diag(Q)[15:], sb2, rtol=1e-9)
    np.testing.assert_allclose(Q[:15, :15], ImuTransition(NavNoise()).Q(0.0, dt))


def test_measurements_on_the_biased_state_match_finite_differences():
    """A fix reads p + bp, a baro (offset to the GNSS height) -(p_D + bp_D), the rest do
    not read the bias; analytic H (and the hybrid's rows) against finite differences."""
    rng = np.random.default_rng(6)
    f = np.array([0.8, -1.5, -9.3])
    mref = np.array([0.44, 0.02, 0.9]) / np.linalg.norm([0.44, 0.02, 0.9])
    models = (GnssPosition(np.eye(3)), GnssPosition(np.eye(2), rows=(0, 1)),
              GnssPosition(np.eye(3), back=0.2, k=0.02, f=f, g=9.8),
              GnssPosition(np.eye(3), biased=False), GnssVelocity(np.eye(3), back=0.03, f=f,
                                                                  g=9.8),
              BaroHeight(np.eye(1), offset=3.0, back=0.05),
              OnNav(MagField(mref, np.eye(3) * 1e-4), 0.05, np.array([0.4, -0.3, 0.9])))
    x = _point_b(rng)
    for m in models:
        m.space = SPB
        ref = fd_jacobian(m.h, SPB, None, x)
        np.testing.assert_allclose(m.H(x), ref, atol=2e-7)
        Hs = m.H_rows(np.array([x, _point_b(rng)]))
        np.testing.assert_allclose(Hs[0], m.H(x), atol=1e-9)
    np.testing.assert_allclose(models[0].h(x), x[7:10] + x[16:19])
    np.testing.assert_allclose(models[3].h(x), x[7:10])  # the unaided run's hold
    np.testing.assert_allclose(models[5].h(x), -(x[9] - 0.05 * x[6]) + 3.0 - x[18])


def test_a_fix_splits_the_receiver_accuracy_into_bias_and_white_parts():
    n = BIAS.with_(gnss_pos_floor=0.3, gnss_vpos_floor=0.3)
    sh, sv = n.gnss_pos_sd(1.0, 2.0)
    assert sh == pytest.approx(0.6) and sv == pytest.approx(np.sqrt(4 - 1.5**2))
    assert n.gnss_pos_sd(0.5, None) == (0.3, 0.3)  # less than the bias: the floors
    assert NavNoise(gnss_pos_floor=0.3).gnss_pos_sd(1.0, None)[0] == 1.0  # no states


def _gm_flight(seed, steps=3000, dt=0.02, sigma=2.0, tau=10.0):
    """_flight with the fixes' position error a Gauss-Markov process (sigma m, tau s)."""
    data = _flight(seed, steps, dt)
    rng = np.random.default_rng(seed + 100)
    phi = np.exp(-10 * dt / tau)
    b = rng.normal(size=3) * sigma
    out = []
    for xt, u, zp, zv in data:
        if zp is not None:
            b = phi * b + rng.normal(size=3) * sigma * np.sqrt(1 - phi**2)
            zp = xt[7:10] + b
        out.append((xt, u, zp, zv))
    return out


#: The flights' start covariance: attitude, velocity, position, gyro and accel biases.
P0_FLIGHT = np.diag([0.05**2] * 3 + [1.0] * 3 + [9.0] * 3 + [0.01**2] * 3 + [0.2**2] * 3)


def _filter_flight(data, noise, spec, seed, prior, Rp, Rv, step=None):
    """The registry's filter ``spec`` over the seeded flight ``data`` on ``noise``'s state
    space (its random draws from ``seed``): the truth's start at :data:`P0_FLIGHT`, the
    extra states (GNSS bias, magnetic reference) appended at zero with the covariance
    ``prior``; at each fix its position and velocity with ``Rp`` / ``Rv``; after them
    ``step(k, xt, s, f, space, rng)`` returns the state with any other update. Yields
    ``(k, xt, estimate, space)`` per IMU step."""
    from scipy.linalg import block_diag

    tr = ImuTransition(noise)
    sp = tr.space
    x0, P0 = data[0][0].copy(), P0_FLIGHT
    if sp.dim > 15:
        x0, P0 = np.concatenate([x0, np.zeros(sp.dim - 15)]), block_diag(P0, prior)
    rng = np.random.default_rng(seed)
    f = make_filter(spec)
    s = f.init(Gaussian(x0, P0), sp, rng)
    for k, (xt, u, zp, zv) in enumerate(data):
        s = f.predict(s, tr, k * 0.02, 0.02, u, rng)
        if zp is not None:
            for z, m in ((zp, GnssPosition(Rp)), (zv, GnssVelocity(Rv))):
                m.space = sp
                s, _ = f.update(s, z, m, rng)
        if step is not None:
            s = step(k, xt, s, f, sp, rng)
        yield k, xt, f.estimate(s), sp


@pytest.mark.slow
def test_gnss_bias_states_make_the_position_nees_consistent():
    """The same seeded flight, fixes with a 10-s Gauss-Markov error of 2 m: the EKF that
    takes them as independent is over-confident in position; with the bias states its
    position NEES is in its 95 % band on most steps, and its position no worse."""
    from uavest.eval.navigation import nees_band

    data = _gm_flight(4)
    lo, hi = nees_band(3)
    res = {}
    for noise in (NavNoise(), NavNoise(gnss_bias_h=2.0, gnss_bias_v=2.0, gnss_bias_tau=10.0)):
        inb, err = [], []
        for k, xt, g, _ in _filter_flight(data, noise, "ekf", 1, np.eye(3) * 4.0,
                                          np.eye(3) * 0.01, np.eye(3) * 0.01):
            if k > 500:
                e = g.x[7:10] - xt[7:10]
                d = float(e @ np.linalg.solve(g.P[6:9, 6:9], e))
                inb.append(lo <= d <= hi)
                err.append(e)
        res[nav_space(noise).dim] = (np.mean(inb), np.sqrt(np.mean(np.square(err))))
    assert res[15][0] < 0.3, res
    assert res[18][0] >= 0.8, res
    assert res[18][1] <= 1.1 * res[15][1], res


# ------------------------------------------------------ magnetic reference states

MREF = NavNoise(mag_ref_inc=0.02, mag_ref_dec=0.01, mag_ref_walk=1e-4)
SPM = NavSpace(mag=2)
SPBM = NavSpace(extra=3, mag=2)
M_REF = np.array([0.44, 0.02, 0.9]) / np.linalg.norm([0.44, 0.02, 0.9])


def test_mag_ref_states_only_when_asked():
    assert not NavNoise().mag_ref and ImuTransition(NavNoise()).space.dim == 15
    assert MREF.mag_ref and ImuTransition(MREF).space == SPM and SPM.dim == 17
    both = MREF.with_(gnss_bias_h=0.8, gnss_bias_tau=60.0)
    assert ImuTransition(both).space == SPBM and SPBM.dim == 20
    assert SPBM.mag_slice == slice(19, 21) and SPM != SPB and SPM != SP
    assert nav_dim({"mag_ref_inc": 0.01}) == 17 and nav_dim({"mag_ref_dec": 0.01}) == 17


@pytest.mark.parametrize("sp", [SPM, SPBM], ids=["mag", "gnss_bias+mag"])
def test_mag_ref_transition_and_measurements_match_finite_differences(sp):
    """The reference errors are constant random walks; the field update reads them
    (analytic H against finite differences, with and without the sample's age), the
    GNSS and baro updates read the GNSS bias (when there) and not them."""
    from uavest.models.navigation import MagFieldRef

    rng = np.random.default_rng(8)
    noise = MREF.with_(gnss_bias_h=0.8, gnss_bias_v=1.5, gnss_bias_tau=60.0) \
        if sp.extra else MREF
    tr = ImuTransition(noise, lat=np.deg2rad(47.0), h=400.0)
    assert tr.space == sp
    f = np.array([0.8, -1.5, -9.3])
    dt = 0.04
    for _ in range(3):
        x = np.concatenate([_point(rng), rng.normal(size=sp.extra) * 0.8,
                            rng.normal(size=2) * 0.02])
        u = np.concatenate([rng.normal(size=3) * 0.5, rng.normal(size=3) * 3 + [0, 0, -9.8]])
        ref = fd_jacobian(lambda X, u=u: tr.f(X, 0.0, dt, u), sp, sp, x)
        np.testing.assert_allclose(tr.F(x, 0.0, dt, u), ref, atol=1e-6)
        np.testing.assert_allclose(tr.f(x, 0.0, dt, u)[sp.mag_slice], x[sp.mag_slice])
        for m in (MagFieldRef(M_REF, np.eye(3) * 1e-4, sp),
                  MagFieldRef(M_REF, np.eye(3) * 1e-4, sp, 0.05, np.array([0.4, -0.3, 0.9])),
                  GnssPosition(np.eye(3)), BaroHeight(np.eye(1), offset=3.0),
                  GnssPosition(np.eye(3), back=0.2, k=0.02, f=f, g=9.8),
                  GnssVelocity(np.eye(3), back=0.03, f=f, g=9.8)):
            m.space = sp
            ref = fd_jacobian(m.h, sp, None, x)
            np.testing.assert_allclose(m.H(x), ref, atol=2e-7)
        # zero errors: the plain field update's prediction
        x0 = x.copy()
        x0[sp.mag_slice] = 0.0
        np.testing.assert_allclose(MagFieldRef(M_REF, np.eye(3), sp).h(x0),
                                   quat_rotate_inv(x0[:4], M_REF), atol=1e-12)
        pos = GnssPosition(np.eye(3))
        pos.space = sp
        np.testing.assert_allclose(pos.h(x), x[7:10] + (x[16:19] if sp.extra else 0.0))
    Q = tr.Q(0.0, dt)
    np.testing.assert_allclose(np.diag(Q)[-2:], 1e-8 * dt + 1e-16)
    assert not Q[-2:, :-2].any()


@pytest.mark.slow
@pytest.mark.parametrize("spec", ["ekf", "ukf", "hybrid"])
def test_mag_ref_states_learn_a_field_off_the_model(spec):
    """The seeded straight-and-turn flight with a magnetometer whose field's inclination is
    1 deg (and declination 0.5 deg) off the reference the filter is given: each filter
    without the states holds its tilt to the wrong field and is over-confident; with them
    it learns the inclination's offset once the turn separates it from the tilt and the
    accelerometer bias, its tilt error after the turn is smaller and its attitude NEES in
    its band on most steps."""
    from uavest.eval.navigation import nees_band
    from uavest.models.attitude import mag_reference
    from uavest.models.navigation import MagFieldRef

    data = _flight(5)
    inc, dec, d_inc, d_dec = np.deg2rad(64.0), np.deg2rad(3.0), np.deg2rad(1.0), np.deg2rad(0.5)
    m_true, m_given = mag_reference(dec + d_dec, inc + d_inc), mag_reference(dec, inc)
    lo, hi = nees_band(3)
    res = {}
    for noise in (NavNoise(), NavNoise(mag_ref_inc=np.deg2rad(2.0),
                                       mag_ref_dec=np.deg2rad(2.0))):

        def mag(k, xt, s, f, sp, rng):
            if k % 5:  # 10 Hz magnetometer, 0.005 rad per axis
                return s
            zb = quat_rotate_inv(xt[:4], m_true) + rng.normal(size=3) * 0.005
            R = np.eye(3) * 0.005**2
            m = MagFieldRef(m_given, R, sp) if sp.mag else OnNav(MagField(m_given, R))
            m.space = sp
            return f.update(s, zb / np.linalg.norm(zb), m, rng)[0]

        inb, err = [], []
        for k, xt, g, sp in _filter_flight(data, noise, spec, 2,
                                           np.diag(noise.mag_ref_sd**2),
                                           np.diag([0.25, 0.25, 1.0]), np.eye(3) * 0.01, mag):
            if k > 1250:  # 5 s after the turn has begun (at 10 s)
                e = sp.local(g.x, xt if not sp.mag else np.r_[xt, d_inc, d_dec])[:3]
                d = float(e @ np.linalg.solve(g.P[:3, :3], e))
                inb.append(lo <= d <= hi)
                err.append(np.degrees(np.linalg.norm(e[:2])))
        res[sp.dim] = (np.mean(inb), np.sqrt(np.mean(np.square(err))), g.x[-2:],
                       np.sqrt(np.diag(g.P)[-2:]))
    (in15, e15, *_), (in17, e17, est, sd) = res[15], res[17]
    assert e17 < 0.5 * e15 and in17 >= 0.8 and in15 < 0.5, res
    # the inclination is learnt to 0.25 deg; the declination is what the yaw leaves
    # (this turn holds the yaw to about 1.3 deg): within 2 std of its own
    assert abs(est[0] - d_inc) < np.deg2rad(0.25) and sd[0] < np.deg2rad(0.25), res
    assert abs(est[1] - d_dec) < 2 * sd[1], res


# ------------------------------------------------------------ gyro drift states

DRIFT = NavNoise(gyro_drift_walk=1e-4, init_gyro_drift=2e-3)
RAMP = 5e-4  # rad/s^2 (at 1e-3 the hybrid's ensemble collapses with or without them)


def test_gyro_drift_states_only_when_asked():
    assert not NavNoise().gyro_drift and ImuTransition(NavNoise()).space == SP
    sp = ImuTransition(DRIFT).space
    assert sp == NavSpace(drift=3) and sp.dim == 18 and sp.drift_slice == slice(16, 19)
    full = ImuTransition(DRIFT.with_(gnss_bias_h=0.8, gnss_bias_tau=60.0,
                                     mag_ref_inc=0.01)).space
    # after the GNSS bias states, before the magnetic reference's (the last two)
    assert full == NavSpace(extra=3, mag=2, drift=3) and full.dim == 23
    assert full.drift_slice == slice(19, 22) and full.mag_slice == slice(22, 24)
    assert full != NavSpace(extra=3, mag=2) and nav_dim({"gyro_drift_walk": 1e-6}) == 18


@pytest.mark.parametrize("sp", [NavSpace(drift=3), NavSpace(extra=3, mag=2, drift=3)],
                         ids=["drift", "gnss_bias+drift+mag"])
def test_gyro_drift_transition_F_and_Q_are_the_integrated_random_walk(sp):
    """The bias moves at its rate over a step (the rate constant), F against finite
    differences, Q the exact integrated random walk's blocks; the measurements' H (the
    GNSS bias and the magnetic reference read at their places) against finite
    differences."""
    from uavest.models.navigation import MagFieldRef

    noise = DRIFT
    if sp.extra:
        noise = noise.with_(gnss_bias_h=0.8, gnss_bias_v=1.5, gnss_bias_tau=60.0,
                            mag_ref_inc=0.02, mag_ref_dec=0.01)
    tr = ImuTransition(noise, lat=np.deg2rad(47.0), h=400.0)
    assert tr.space == sp
    rng = np.random.default_rng(21)
    dt = 0.04
    ds = sp.drift_slice
    for _ in range(3):
        x = np.concatenate([_point(rng), rng.normal(size=sp.size - 16) * 0.5])
        x[ds] = rng.normal(size=3) * 1e-3
        u = np.concatenate([rng.normal(size=3) * 0.5, rng.normal(size=3) * 3 + [0, 0, -9.8]])
        y = tr.f(x, 0.0, dt, u)
        np.testing.assert_allclose(y[10:13], x[10:13] + x[ds] * dt, rtol=1e-12)
        np.testing.assert_allclose(y[ds], x[ds])
        ref = fd_jacobian(lambda X, u=u: tr.f(X, 0.0, dt, u), sp, sp, x)
        np.testing.assert_allclose(tr.F(x, 0.0, dt, u), ref, atol=1e-6)
        models = [GnssPosition(np.eye(3)), GnssVelocity(np.eye(3), back=0.03,
                                                        f=np.array([0.8, -1.5, -9.3]), g=9.8),
                  BaroHeight(np.eye(1), offset=3.0)]
        if sp.mag:
            models.append(MagFieldRef(M_REF, np.eye(3) * 1e-4, sp))
        for m in models:
            m.space = sp
            np.testing.assert_allclose(m.H(x), fd_jacobian(m.h, sp, None, x), atol=2e-7)
    Q = tr.Q(0.0, dt)
    i, b = np.arange(ds.start - 1, ds.stop - 1), np.arange(9, 12)
    q = noise.gyro_drift_walk**2
    np.testing.assert_allclose(Q[i, i], q * dt + 1e-18)
    np.testing.assert_allclose(Q[b, i], q * dt**2 / 2)
    np.testing.assert_allclose(Q[b, b], noise.gyro_bias_walk**2 * dt + 1e-16 + q * dt**3 / 3)
    assert np.allclose(Q, Q.T) and np.all(np.linalg.eigvalsh(Q) > 0)
    # the rest is the model's without the states
    Qp = ImuTransition(noise.with_(gyro_drift_walk=0.0), lat=np.deg2rad(47.0),
                       h=400.0).Q(0.0, dt)
    Qp[b, b] += q * dt**3 / 3
    keep = np.setdiff1d(np.arange(sp.dim), i)
    np.testing.assert_allclose(Q[np.ix_(keep, keep)], Qp)


@pytest.mark.slow
@pytest.mark.parametrize("spec", ["ekf", "ukf", "hybrid"])
def test_gyro_drift_states_follow_a_ramping_bias(spec, rate=None):
    """A gyro bias ramping at 0.5 mrad/s per second: the random-walk bias lags it, and
    every filter is over-confident in its attitude (NEES in band on fewer than 0.6 of the
    steps after the turn); with the drift states every filter learns the ramp's rate
    (within 2 std or 20 %), its attitude NEES is in band on 0.8 of the steps or more and
    its attitude error is smaller by 15 % or more (the rest is this flight's noise)."""
    from uavest.eval.navigation import nees_band

    rate = rate or RAMP
    data = _flight(6, rate=rate, mag=True)
    lo, hi = nees_band(3)
    res = {}
    for noise in (NavNoise(), DRIFT):
        tr = ImuTransition(noise)
        sp = tr.space
        x0, P0 = data[0][0].copy(), P0_FLIGHT
        if sp.drift:
            x0 = np.concatenate([x0, np.zeros(3)])
            P0 = np.block([[P0, np.zeros((15, 3))],
                           [np.zeros((3, 15)), np.eye(3) * noise.init_gyro_drift**2]])
        rng = np.random.default_rng(3)
        f = make_filter(spec)
        s = f.init(Gaussian(x0, P0), sp, rng)
        inb, err = [], []
        for k, (xt, u, zp, zv, zm) in enumerate(data):
            s = f.predict(s, tr, k * 0.02, 0.02, u, rng)
            ups = [] if zp is None else [(zp, GnssPosition(np.diag([0.25, 0.25, 1.0]))),
                                          (zv, GnssVelocity(np.eye(3) * 0.01))]
            if zm is not None:
                ups.append((zm, OnNav(MagField(M_REF, np.eye(3) * 1e-4))))
            for z, m in ups:
                m.space = sp
                s, _ = f.update(s, z, m, rng)
            g = f.estimate(s)
            if k > 750:
                e = SP.local(g.x[:16], xt)[:3]
                d = float(e @ np.linalg.solve(g.P[:3, :3], e))
                inb.append(lo <= d <= hi)
                err.append(np.degrees(np.linalg.norm(e)))
        res[sp.dim] = (np.mean(inb), np.sqrt(np.mean(np.square(err))),
                       g.x[16:19] if sp.drift else None,
                       np.sqrt(np.diag(g.P)[15:18]) if sp.drift else None)
    (in15, e15, *_), (in18, e18, est, sd) = res[15], res[18]
    assert in15 < 0.6 and in18 >= 0.8 and e18 < 0.85 * e15, res
    assert np.all(np.abs(est - rate) < np.maximum(2 * sd, 0.2 * rate)), res


@pytest.mark.parametrize("extra,mag", [(0, 0), (3, 0), (3, 2)])
def test_one_state_retract_on_floats_is_the_rows_retract(extra, mag):
    """The EKF's retract of one state (Python floats) against the rows' (numpy): the same
    point to rounding on random states and steps of every size, and numpy's NaN (never an
    exception) for a zero quaternion, an infinite or a NaN rotation."""
    from uavest.geometry.navigation import nav_retract_one, nav_retract_rows

    sp = NavSpace(extra, mag)
    g = np.random.default_rng(extra + mag)
    for _ in range(300):
        x = g.normal(size=sp.size)
        x[:4] /= np.linalg.norm(x[:4])
        dx = g.normal(size=sp.dim) * 10.0 ** g.uniform(-9, 0.5)
        got = nav_retract_one(x, dx)
        assert np.array_equal(sp.retract(x, dx), got)  # (the space's path for one state)
        np.testing.assert_allclose(got, nav_retract_rows(x, dx[None, :])[0], rtol=0,
                                   atol=4e-16 * (1.0 + np.abs(x) + np.abs(dx[0])).max())
        assert abs(np.linalg.norm(got[:4]) - 1.0) < 1e-15
    x = np.r_[0.6, 0.0, 0.8, 0.0, np.arange(sp.size - 4.0)]
    for bad_x, bad_dx in ((True, None), (False, np.inf), (False, np.nan)):
        xx, dx = x.copy(), np.full(sp.dim, 0.1)
        if bad_x:
            xx[:4] = 0.0
        else:
            dx[1] = bad_dx
        with np.errstate(all="ignore"):
            got, want = nav_retract_one(xx, dx), nav_retract_rows(xx, dx[None, :])[0]
        assert np.isnan(got[:4]).all() and np.array_equal(got, want, equal_nan=True)


@pytest.mark.parametrize("extra,mag", [(0, 0), (3, 0), (3, 2)])
def test_carried_gnss_h_H_of_one_state_is_the_rows_reference(extra, mag):
    """The EKF's (h, H) of a GNSS fix carried by the state (Python floats) against
    :meth:`h` and :meth:`H_rows` (numpy): position (3-D, 2-D; on the receiver's bias
    states or not) and velocity, carried or plain, on random states."""
    sp = NavSpace(extra, mag)
    g = np.random.default_rng(10 + extra + mag)
    seen = set()
    for k in range(120):
        x = g.normal(size=sp.size)
        x[:4] /= np.linalg.norm(x[:4])
        f = g.normal(0.0, 5.0, 3) if k % 4 else None
        rows = (0, 1) if k % 3 == 0 else (0, 1, 2)
        back = g.uniform(0.0, 0.3)
        R = np.eye(len(rows))
        ms = [GnssPosition(R, rows, back=back, k=0.5 * back**2, f=f, g=9.8,
                           biased=bool(k % 2)),
              GnssVelocity(R, rows, back=back, f=f, g=9.8)]
        for m in ms:
            m.space = sp
            y, H = m.h_H(x)
            np.testing.assert_allclose(y, m.h(x[None, :])[0], rtol=1e-14, atol=1e-13)
            np.testing.assert_allclose(H, m.H_rows(x[None, :])[0], rtol=1e-14, atol=1e-13)
            assert H.shape == (len(rows), sp.dim)
            seen.add((type(m).__name__, m._carried, len(rows)))
    assert len(seen) == 8
