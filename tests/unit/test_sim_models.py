"""Simulator building blocks: truth kinematics, IMU model, targets, radar geometry, geodesy."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.geometry.geodesy import LocalFrame
from uavest.geometry.rotation import G0, quat_exp, quat_log, quat_mul, quat_to_dcm
from uavest.scenarios import load_typed
from uavest.scenarios.schema import Imu, Mag, Manoeuvre, SimRadar, SimTarget, Vehicle
from uavest.sim import Simulator
from uavest.sim.radar import Radar, Targets
from uavest.sim.sensors import ImuModel
from uavest.sim.vehicle import Manoeuvres, VehicleModel, stream_rng


def _vehicle(man, jitter=0.0, period=None):
    return VehicleModel(Vehicle(manoeuvres=tuple(Manoeuvre(**m) for m in man),
                                jitter_deg=jitter, period_s=period), stream_rng(0, "motion"))


def test_level_still_reads_minus_g():
    v = _vehicle([])
    tr = v.chunk(np.arange(200) / 100.0)
    assert np.allclose(tr.f_body, [0.0, 0.0, -G0], atol=1e-12)
    assert np.allclose(tr.omega, 0.0) and np.allclose(tr.vel, 0.0)


def test_body_rates_integrate_to_attitude():
    sc = load_typed("sim_default")
    v = VehicleModel(sc.vehicle, stream_rng(0, "motion"))
    rate = 500.0
    t = np.arange(0, 30 * rate) / rate
    tr = v.chunk(t)
    q = tr.q[0]
    for k in range(t.size - 1):  # midpoint rates: second order
        q = quat_mul(q, quat_exp(0.5 * (tr.omega[k] + tr.omega[k + 1]) / rate))
    err = np.linalg.norm(quat_log(quat_mul(np.array([q[0], *(-q[1:])]), tr.q[-1])))
    assert err < 1e-4
    assert np.abs(np.rad2deg(tr.euler[:, 0])).max() > 20  # a non-trivial trajectory


def test_translation_consistent_and_chunk_invariant():
    sc = load_typed("sim_default")
    t = np.arange(0, 40 * 200) / 200.0
    one = VehicleModel(sc.vehicle, stream_rng(0, "motion")).chunk(t)
    v2 = VehicleModel(sc.vehicle, stream_rng(0, "motion"))
    parts = [v2.chunk(t[i:i + 137]) for i in range(0, t.size, 137)]
    pos = np.concatenate([p.pos for p in parts])
    assert np.allclose(pos, one.pos, atol=1e-9)
    # velocity is the derivative of position, acceleration of velocity (central diff.)
    dv = (one.pos[2:] - one.pos[:-2]) * 100.0
    assert np.allclose(dv, one.vel[1:-1], atol=1e-3)
    da = (one.vel[2:] - one.vel[:-2]) * 100.0
    assert np.allclose(da, one.acc[1:-1], atol=0.02)  # jerk steps at ramp edges
    f = np.einsum("nji,nj->ni", one.R, one.acc - [0, 0, G0])
    assert np.allclose(f, one.f_body)
    # tilting accelerates: the pitch-down hold (29-39 s) flies the vehicle forward
    assert np.abs(one.vel[:, :2]).max() > 2.0


def test_manoeuvre_validation():
    with pytest.raises(ValueError, match="channel"):
        Manoeuvres([Manoeuvre(channel="thrust", start=0, duration=1)])
    with pytest.raises(ValueError, match="period"):
        Manoeuvres([Manoeuvre(channel="roll", start=5, duration=10)], period=10)
    m = Manoeuvres([Manoeuvre(channel="yaw", kind="ramp", start=1, duration=2, value=90)],
                   period=10)
    val, _ = m.eval(np.array([0.0, 5.0, 15.0, 25.0]))
    assert np.allclose(np.rad2deg(val[:, 2]), [0, 90, 180, 270])


def test_imu_noise_scales_with_density():
    tr = _vehicle([]).chunk(np.arange(20000) / 400.0)
    imu = ImuModel(Imu(gyro_bias=(0, 0, 0), accel_bias=(0, 0, 0), gyro_bias_walk=0,
                       accel_bias_walk=0, vibration_accel=(0,), vibration_gyro=(0,),
                       gyro_noise_density=1e-3), Mag(), 400.0, seed=1).chunk(tr)
    assert imu.gyro.std(0) == pytest.approx(np.full(3, 1e-3 * np.sqrt(400)), rel=0.05)
    assert np.abs(imu.gyro.mean(0)).max() < 1e-3
    # magnetometer: held between 50 Hz updates
    assert imu.mag_new.sum() == pytest.approx(20000 / 8, abs=1)


def test_a_drifting_gyros_bias_ramps_across_chunks():
    """``imu.gyro_drift`` (rad/s^2, as an ArduPilot SITL's SIM_DRIFT_SPEED): the true bias
    moves by the drift times the time on every axis, over the chunk boundaries, beside
    its random walk; the readings carry it; at 0 the readings are those of a scenario
    without the key, bit for bit (the recorded logs are reproducible)."""
    t = np.arange(8000) / 400.0
    tr = [_vehicle([]).chunk(part) for part in np.split(t, 4)]

    def run(**kw):
        imu = ImuModel(Imu(gyro_bias=(0.01, -0.02, 0.003), **kw), Mag(), 400.0, seed=3)
        return [imu.chunk(c) for c in tr]

    plain, zero, drift = run(), run(gyro_drift=0.0), run(gyro_drift=1e-4)
    for a, b in zip(plain, zero, strict=True):
        assert np.array_equal(a.gyro, b.gyro) and np.array_equal(a.gyro_bias, b.gyro_bias)
    ramp = np.concatenate([d.gyro_bias - p.gyro_bias for d, p in zip(drift, plain,
                                                                      strict=True)])
    np.testing.assert_allclose(ramp, np.outer(t + 1 / 400.0, [1e-4] * 3), atol=1e-15)
    np.testing.assert_allclose(drift[-1].gyro - plain[-1].gyro, ramp[-2000:], atol=1e-15)


def test_targets_turns_are_continuous():
    tg = Targets([SimTarget(position_ned=(0, 0, -100), velocity_ned=(30, 0, -1),
                            turns=((5, 15, 9.0), (20, float("inf"), -3.0)))])
    t = np.arange(0, 40, 0.01)
    P, V = tg.state_at(t)
    P, V = P[0], V[0]
    assert np.allclose(np.linalg.norm(V[:, :2], axis=1), 30.0)
    assert np.allclose((P[2:] - P[:-2]) / 0.02, V[1:-1], atol=0.02)
    # 10 s at 9 deg/s right turn: course 90 deg (east), then straight until 20 s
    k = int(17 / 0.01)
    assert np.allclose(V[k, :2], [0, 30], atol=1e-9)
    assert P[-1, 2] == pytest.approx(-100 - 1 * 39.99, abs=1e-6)  # climbing 1 m/s


def test_radar_spherical_roundtrip_and_fov():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(100, 3)) * 1000
    assert np.allclose(Radar.to_cartesian(Radar.to_spherical(d)), d)
    rae = Radar.to_spherical(np.array([[100.0, 100.0, -100.0]]))[0]  # right and up
    assert rae[1] == pytest.approx(np.pi / 4) and rae[2] > 0
    r = Radar(SimRadar(fov_az_deg=90, fov_el_deg=20, r_min=10, r_max=1000, pd=1.0,
                       clutter_rate=0), rng)
    ok = r.in_view(Radar.to_spherical(np.array(
        [[500, 0, 0], [500, 600, 0], [500, 0, -200], [5, 0, 0], [2000, 0, 0]], float)))
    assert ok.tolist() == [True, False, False, False, False]
    dets = r.scan(np.eye(3), np.zeros(3), np.array([[500.0, 0, 0], [0, 500.0, 0]]), [7, 8])
    assert [x.obstacle_id for x in dets] == [7]


def test_local_frame_against_pymap3d():
    pm = pytest.importorskip("pymap3d")
    f = LocalFrame(47.3977, 8.5456, 488.0)
    ned = np.array([[3000.0, -2500.0, -600.0], [-100.0, 50.0, 20.0]])
    lat, lon, h = f.ned_to_geodetic(ned)
    for i in range(2):
        ref = pm.ned2geodetic(*ned[i], 47.3977, 8.5456, 488.0)
        assert np.allclose([lat[i], lon[i]], ref[:2], atol=1e-10)
        assert h[i] == pytest.approx(ref[2], abs=1e-4)
    assert np.allclose(f.geodetic_to_ned(lat, lon, h), ned, atol=1e-5)


def test_truth_at_interpolates_history():
    sim = Simulator(load_typed("sim_default"), seed=0, imu_rate=100.0)
    sim.run(None, duration=3.0, speed=0)
    pos = np.concatenate([c.truth.pos for c in sim._chunks])
    R = np.concatenate([c.truth.R for c in sim._chunks])
    a, b = sim.truth_at(1.0), sim.truth_at(1.005)
    assert np.allclose(a.vehicle.pos_ned, pos[100])
    assert np.allclose(b.vehicle.pos_ned, 0.5 * (pos[100] + pos[101]))
    assert np.allclose(quat_to_dcm(a.vehicle.q), R[100])
    c = sim.truth_at(0.495)  # across a chunk boundary (chunks of 0.5 s)
    assert np.allclose(c.vehicle.pos_ned, 0.5 * (pos[49] + pos[50]))
    with pytest.raises(ValueError):
        sim.truth_at(10.0)
    assert a.target_pos.shape == (4, 3) and a.target_ids == [1, 2, 3, 4]


def test_simulator_takes_the_typed_scenario():
    from uavest.scenarios import load_scenario

    with pytest.raises(TypeError, match="load_typed"):
        Simulator(load_scenario("sim_default"))
    sc = load_typed("sim_default", ["imu.rate_hz=200"])
    assert Simulator(sc).imu_rate == 200.0  # the typed table's value, not a default
