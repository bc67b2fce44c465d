"""Radar measurement and coordinated-turn models: Jacobians, wrapping, circular means."""

import numpy as np
import pytest

from uavest.core import UKF, Gaussian, fd_jacobian, make_filter
from uavest.models.radar import RadarMeasurement, SensorPose, euler_zyx, wrap_angle
from uavest.models.turn import CoordinatedTurn


def _pose3(rng):
    R = euler_zyx(*rng.uniform(-0.5, 0.5, 3))
    return SensorPose(rng.normal(0, 100, 3), R, rng.normal(0, 10, 3))


@pytest.mark.parametrize("ndim,rr", [(2, None), (2, 1.0), (3, None), (3, 1.0)])
def test_jacobian_matches_finite_differences(ndim, rr):
    rng = np.random.default_rng(1)
    pose = _pose3(rng) if ndim == 3 else SensorPose(
        rng.normal(0, 100, 2), euler_zyx(0.7, 0, 0)[:2, :2], rng.normal(0, 5, 2)
    )
    m = RadarMeasurement(ndim, sigma_rr=rr, pose=pose)
    for _ in range(5):
        x = np.concatenate([rng.normal(0, 3000, ndim), rng.normal(0, 50, ndim)])
        H = m.H(x)
        Hfd = fd_jacobian(m.h, m.space, None, x)
        np.testing.assert_allclose(H, Hfd, rtol=1e-5, atol=1e-9)


def test_ground_radar_conventions():
    m = RadarMeasurement(3)
    z = m.h(np.array([[0.0, 1000.0, 1000.0, 0, 0, 0]]))[0]
    assert z[0] == pytest.approx(np.sqrt(2) * 1000)
    assert z[1] == pytest.approx(np.pi / 2)  # north = +90 deg, counter-clockwise from east
    assert z[2] == pytest.approx(np.pi / 4)
    m2 = RadarMeasurement(2, sigma_rr=1.0)
    z = m2.h(np.array([[1000.0, 0.0, 10.0, 5.0]]))[0]
    assert z[2] == pytest.approx(10.0)  # receding at 10 m/s


def test_uav_pose_rotates_line_of_sight():
    # UAV heading north (yaw 90 deg): a target due north is straight ahead (azimuth 0)
    pose = SensorPose(np.array([0.0, 0, 100]), euler_zyx(np.pi / 2, 0, 0), np.zeros(3))
    m = RadarMeasurement(3, pose=pose)
    z = m.h(np.array([[0.0, 2000.0, 100.0, 0, 0, 0]]))[0]
    assert z[1] == pytest.approx(0.0, abs=1e-12)
    p, _ = m.to_cartesian(z)
    np.testing.assert_allclose(p, [0, 2000, 100], atol=1e-9)


def test_to_cartesian_inverts_h():
    rng = np.random.default_rng(2)
    for ndim in (2, 3):
        pose = _pose3(rng) if ndim == 3 else SensorPose.fixed(2, [10.0, -20.0], 0.3)
        m = RadarMeasurement(ndim, pose=pose)
        x = np.concatenate([rng.normal(0, 3000, ndim), np.zeros(ndim)])
        p, C = m.to_cartesian(m.h(x[None])[0])
        np.testing.assert_allclose(p, x[:ndim], atol=1e-6)
        assert np.all(np.linalg.eigvalsh(C) > 0)


def test_residual_wraps_across_pi():
    m = RadarMeasurement(2)
    a = np.array([100.0, np.pi - 0.01])
    b = np.array([90.0, -np.pi + 0.01])
    r = m.residual(a, b)
    assert r[0] == pytest.approx(10.0)
    assert r[1] == pytest.approx(-0.02)
    # broadcasting (M, m) vs (m,) and the other way round
    Y = np.array([[1.0, -np.pi + 0.01], [2.0, np.pi - 0.03]])
    R1 = m.residual(Y, a)
    R2 = m.residual(a, Y)
    np.testing.assert_allclose(R1[:, 1], [0.02, -0.02], atol=1e-12)
    np.testing.assert_allclose(R2, -R1, atol=1e-12)
    assert np.all(np.abs(wrap_angle(np.linspace(-20, 20, 101))) <= np.pi)


def test_circular_mean_across_pi():
    m = RadarMeasurement(2)
    Y = np.array([[100.0, np.pi - 0.1], [200.0, -np.pi + 0.1]])
    mu = m.mean(Y, np.array([0.5, 0.5]))
    assert mu[0] == pytest.approx(150.0)
    assert abs(abs(mu[1]) - np.pi) < 1e-12  # not 0, the arithmetic mean


@pytest.mark.parametrize("name", ["ekf", "ukf", "hybrid"])
def test_filters_track_a_target_behind_the_radar(name):
    """Target moving along the -x axis crosses azimuth +-pi every few scans; the update
    must not jump by 2 pi (the error stays small)."""
    rng = np.random.default_rng(3)
    from uavest.models.motion import NearlyConstantVelocity

    mot = NearlyConstantVelocity(2, 0.01)
    meas = RadarMeasurement(2, sigma_range=5.0, sigma_az=np.deg2rad(0.5))
    x = np.array([-3000.0, 150.0, 0.0, -10.0])  # y goes 150 -> -150 (crosses the -x axis)
    f = make_filter(name)
    s = f.init(Gaussian(x + [20, 20, 1, 1], np.diag([400.0, 400, 4, 4])), mot.space, rng)
    for k in range(1, 31):
        x = mot.f(x[None], k, 1.0)[0]
        s = f.predict(s, mot, k, 1.0, None, rng)
        s, inn = f.update(s, meas.sample(x[None], rng)[0], meas, rng)
        assert abs(inn.nu[1]) < 0.1
    assert np.linalg.norm(f.estimate(s).x[:2] - x[:2]) < 60.0


def test_coordinated_turn_limits():
    ct = CoordinatedTurn(2, q=0.1)
    X = np.array([[0.0, 0, 10, 0, 0.0], [0.0, 0, 10, 0, 1e-9], [0.0, 0, 10, 0, np.pi / 10]])
    Y = ct.f(X, 1.0, 10.0)
    np.testing.assert_allclose(Y[0], [100, 0, 10, 0, 0], atol=1e-9)
    np.testing.assert_allclose(Y[1, :4], Y[0, :4], atol=1e-6)
    # half turn in 10 s at speed 10: radius 10/(pi/10) -> ends at (0, 2 r), velocity reversed
    r = 10 / (np.pi / 10)
    np.testing.assert_allclose(Y[2, :4], [0, 2 * r, -10, 0], atol=1e-9)
    ct3 = CoordinatedTurn(3)
    Y3 = ct3.f(np.array([[0.0, 0, 5, 10, 0, 1, np.pi / 10]]), 1.0, 10.0)[0]
    np.testing.assert_allclose(Y3[[0, 1, 3, 4]], [0, 2 * r, -10, 0], atol=1e-9)
    assert Y3[2] == pytest.approx(15.0)
    Q = ct3.Q(0, 2.0)
    assert Q.shape == (7, 7) and np.all(np.linalg.eigvalsh(Q) > 0)


def test_ukf_with_coordinated_turn_runs():
    rng = np.random.default_rng(0)
    ct = CoordinatedTurn(2, q=0.1, q_omega=1e-5)
    meas = RadarMeasurement(2, state_dim=5, sigma_range=5.0, sigma_az=np.deg2rad(0.2))
    x = np.array([2000.0, 0, 0, 20, 0.05])
    s = Gaussian(x.copy(), np.diag([100.0, 100, 4, 4, 1e-3]))
    f = UKF()
    for k in range(1, 40):
        x = ct.f(x[None], k, 1.0)[0]
        s = f.predict(s, ct, k, 1.0)
        s, _ = f.update(s, meas.sample(x[None], rng)[0], meas)
    assert abs(s.x[4] - 0.05) < 0.01


@pytest.mark.parametrize("w0", [0.0, 5e-7, 1e-6, 2e-6, 1e-5, 1e-3])
def test_coordinated_turn_F_omega_column_near_zero(w0):
    """d/d omega of the CT step near omega = 0 (where the finite differences straddle the
    series cut-off or evaluate (1 - cos wT)/w at tiny wT) against a 50-digit mpmath
    derivative. The cancelling form 1 - cos(wT) was off by ~1e-4 relative here."""
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 50
    T = 1.0
    x = np.array([100.0, 200.0, 30.0, -40.0, w0])
    vx, vy = mp.mpf(x[2]), mp.mpf(x[3])

    def a(w):
        return mp.sin(w * T) / w if w != 0 else mp.mpf(T)

    def b(w):
        return (1 - mp.cos(w * T)) / w if w != 0 else mp.mpf(0)

    comps = [
        lambda w: a(w) * vx - b(w) * vy,
        lambda w: b(w) * vx + a(w) * vy,
        lambda w: mp.cos(w * T) * vx - mp.sin(w * T) * vy,
        lambda w: mp.sin(w * T) * vx + mp.cos(w * T) * vy,
    ]
    w = mp.mpf(w0) if w0 else mp.mpf("1e-40")
    expect = np.array([float(mp.diff(f, w)) for f in comps])
    F = CoordinatedTurn(2, q=0.1).F(x, 1.0, T)
    np.testing.assert_allclose(F[:4, -1], expect, rtol=1e-7, atol=0)


@pytest.mark.parametrize("rr", [None, 1.0])
def test_jacobian_finite_for_target_straight_above_sensor(rr):
    """A target directly above a UAV radar (zero horizontal range) or at the antenna: the
    azimuth/elevation Jacobian has 0/0 there; H must stay finite (as h does)."""
    pose = SensorPose(np.array([100.0, -50.0, 500.0]), np.eye(3), np.array([30.0, 0, 0]))
    m = RadarMeasurement(3, sigma_rr=rr, pose=pose)
    for p in ([100.0, -50.0, 900.0], [100.0, -50.0, 500.0]):
        x = np.array([*p, -20.0, 10.0, 0.0])
        assert np.all(np.isfinite(m.h(x[None])))
        assert np.all(np.isfinite(m.H(x)))
    m2 = RadarMeasurement(2, sigma_rr=rr)
    assert np.all(np.isfinite(m2.H(np.array([0.0, 0.0, 5.0, 1.0]))))


def test_sensor_pose_from_ned_frd_matches_enu_flu():
    """The attitude pipeline's q (body FRD -> NED) gives the same ENU/FLU pose as the
    scenario's Euler construction: ENU yaw = pi/2 - NED heading, FLU pitch = -FRD pitch,
    same roll; position and velocity swap north/east and flip down."""
    from uavest.geometry.rotation import euler_to_quat

    rng = np.random.default_rng(5)
    for _ in range(5):
        roll, pitch, yaw = rng.uniform(-1.0, 1.0, 3)
        pose = SensorPose.from_ned_frd(
            euler_to_quat(roll, pitch, yaw), [100.0, 200.0, -500.0], [3.0, 4.0, 1.0]
        )
        np.testing.assert_allclose(
            pose.R_ws, euler_zyx(np.pi / 2 - yaw, -pitch, roll), atol=1e-12
        )
        np.testing.assert_allclose(pose.position, [200.0, 100.0, 500.0])
        np.testing.assert_allclose(pose.velocity, [4.0, 3.0, -1.0])
    # level, heading east (NED yaw 90 deg): a target 1 km east at the same height is
    # straight ahead (azimuth 0, elevation 0); one 1 km north is to the left (+90 deg)
    pose = SensorPose.from_ned_frd(euler_to_quat(0.0, 0.0, np.pi / 2), [0.0, 0.0, -500.0])
    m = RadarMeasurement(3, pose=pose)
    z = m.h(np.array([[1000.0, 0, 500, 0, 0, 0], [0, 1000.0, 500, 0, 0, 0]]))
    np.testing.assert_allclose(z[:, 1:], [[0.0, 0.0], [np.pi / 2, 0.0]], atol=1e-12)


def test_batched_fd_jacobians_match_analytic_radar_jacobian_across_pi():
    """Measurement.H_rows (batched central differences, residual-wrapped) equals the
    analytic radar Jacobian row by row, including targets just either side of the
    azimuth branch cut at +-pi (a plain difference there would be ~2 pi / eps)."""
    from uavest.core.interfaces import Measurement

    m = RadarMeasurement(ndim=3, sigma_rr=1.0)
    rng = np.random.default_rng(4)
    X = rng.normal(scale=[3000, 3000, 500, 30, 30, 5], size=(20, 6))
    X[:2, :3] = [[-4000.0, 1e-7, 300.0], [-4000.0, -1e-7, 300.0]]  # on the -x axis
    J = Measurement.H_rows(m, X)
    assert J.shape == (20, 4, 6)
    for x, Jx in zip(X, J, strict=True):
        np.testing.assert_allclose(Jx, m.H(x), rtol=1e-5, atol=1e-6)
