"""Filter-step construction: exact gyro pre-integration when the filter runs slower than
the IMU, trapezoid rates for slow streams, causal velocity differencing, stacked updates."""

from __future__ import annotations

import numpy as np

from uavest.apps.replay import samples_from_arrays
from uavest.core import EKF, Gaussian
from uavest.engine.attitude import AttitudeOptions, AttitudeStream, _StepBuilder
from uavest.engine.records import Step
from uavest.geometry.rotation import euler_to_quat, quat_exp, quat_log, quat_mul
from uavest.ingest.types import ImuSample, PositionSample
from uavest.models.attitude import AttitudeNoise, GravityDirection, MagField, Stacked


def _steps(t, gyro, accel, **opts) -> tuple[list[Step], dict]:
    s = AttitudeStream(samples_from_arrays(t, gyro, accel), AttitudeOptions(**opts))
    steps = [x for x in s if isinstance(x, Step)]
    return steps, s.summary


def test_preintegration_is_exact_product_of_rotations():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.003, 0.005, 401))
    gyro = rng.normal(0, 1.5, (401, 3))
    steps, sm = _steps(t, gyro, np.tile([0, 0, -9.8], (401, 1)), rate_hz=25.0,
                       integration="hold")
    assert sm["integration"] == "hold" and sm["preintegrated_samples_per_step"] > 1
    q = np.array([1.0, 0, 0, 0])  # reference: sample by sample
    for i in range(1, 401):
        q = quat_mul(q, quat_exp(gyro[i] * (t[i] - t[i - 1])))
    q2 = np.array([1.0, 0, 0, 0])  # the steps
    for st in steps:
        q2 = quat_mul(q2, quat_exp(st.u * st.dt))
    np.testing.assert_allclose(quat_log(quat_mul(np.array([1.0, 0, 0, 0]) * [1, -1, -1, -1],
                                                 q)), quat_log(q2), atol=1e-9)


def test_slow_stream_uses_trapezoid():
    t = np.arange(0, 5, 0.26)
    gyro = np.outer(t, [0.1, 0.0, 0.0])
    steps, sm = _steps(t, gyro, np.tile([0, 0, -9.8], (t.size, 1)))
    assert sm["integration"] == "trapezoid"
    np.testing.assert_allclose([st.u[0] for st in steps], 0.1 * 0.5 * (t[1:] + t[:-1]))


def test_velocity_acceleration_is_causal():
    """Each step's vehicle acceleration uses the last two velocities at or before its end,
    nothing later (the builder sees samples in time order, one at a time)."""
    import heapq

    tv = np.arange(0.0, 10.0, 0.25)
    pos = [PositionSample(float(a), None, np.array([a * a, 0.0, 0.0]), None, "P")
           for a in tv]
    ti = np.array([0.0, 0.1, 5.0, 5.2])
    imu = [ImuSample(float(a), np.zeros(3), np.array([0, 0, -9.8]), "I") for a in ti]
    b = _StepBuilder("trapezoid", 1, use_pos=True)
    raws = []
    for smp in heapq.merge(imu, pos, key=lambda x: x.t):
        raws.extend(b.push(smp))
    raws.extend(b.flush())
    a = np.array([r.accel_ned for r in raws])  # steps ending at 0.1, 5.0, 5.2
    assert np.isnan(a[0]).all()  # fewer than two samples before t = 0.1
    assert a[1, 0] == (25.0 - 4.75**2) / 0.25  # uses 4.75 and 5.0, nothing later
    assert a[2, 0] == a[1, 0]


def test_stacked_update_matches_sequential_for_ekf():
    x = np.concatenate([euler_to_quat(0.1, -0.2, 0.4), np.zeros(3)])
    g = Gaussian(x, np.diag([0.01, 0.01, 0.02, 1e-4, 1e-4, 1e-4]))
    n = AttitudeNoise(accel_noise=0.5, mag_noise=0.05)
    mref = np.array([0.4, 0.1, 0.9]) / np.linalg.norm([0.4, 0.1, 0.9])
    # measurements a few degrees off the prior mean (small innovations)
    xt = np.concatenate([quat_mul(x[:4], quat_exp(np.array([0.03, -0.02, 0.04]))), x[4:]])
    za, ma = GravityDirection.from_accel(-9.8 * GravityDirection(np.eye(3)).h(xt), n)
    zm, mm = MagField.from_field(0.5 * MagField(mref, np.eye(3)).h(xt), n, mref)
    f = EKF()
    seq, _ = f.update(f.update(g, za, ma)[0], zm, mm)
    z, m = Stacked.of([(za, ma), (zm, mm)])
    both, _ = f.update(g, z, m)
    # equal up to the relinearisation between the sequential updates
    np.testing.assert_allclose(both.x, seq.x, atol=1e-4)
    np.testing.assert_allclose(both.P, seq.P, rtol=0.05, atol=1e-4)  # P entries ~1e-3


def _imu_mag_stream(n: int = 2001, rate: float = 250.0):
    """A 250 Hz IMU with a 50 Hz magnetometer, noisy accelerometer, slow rotation."""
    import heapq

    from uavest.ingest.types import MagSample

    rng = np.random.default_rng(3)
    t = np.arange(n) / rate
    gyro = np.tile([0.02, -0.01, 0.05], (n, 1)) + rng.normal(0, 0.01, (n, 3))
    accel = np.tile([0.0, 0.0, -9.81], (n, 1)) + rng.normal(0, 0.3, (n, 3))
    imu = [ImuSample(float(a), g, f, "I") for a, g, f in zip(t, gyro, accel, strict=True)]
    mags = [MagSample(float(a), np.array([0.2, 0.0, 0.4]) + rng.normal(0, 0.005, 3), "I")
            for a in t[::5]]
    return list(heapq.merge(imu, mags, key=lambda s: s.t)), accel


def test_full_rate_updates_once_per_reference_step_on_the_block_mean():
    """--rate 0 on a 250 Hz IMU: a step per sample, the accelerometer/magnetometer update
    every 10th step (the 25 Hz reference rate) on the mean specific force of the 10
    samples since the last update, with weight 1 (R as at the default rate); the steps
    between predict only."""
    samples, accel = _imu_mag_stream()
    st = AttitudeStream(samples, AttitudeOptions(rate_hz=0))
    steps = [x for x in st if isinstance(x, Step)]
    assert st.summary["steps_per_update"] == 10
    assert st.summary["preintegrated_samples_per_step"] == 1
    with_upd = [i for i, s in enumerate(steps) if s.updates]
    assert len(steps) == 2000 and len(with_upd) == 200
    assert set(np.diff(with_upd)) == {10}
    ref = AttitudeStream(samples, AttitudeOptions())  # the default 25 Hz steps
    ref_steps = [x for x in ref if isinstance(x, Step)]
    for i, s in zip(with_upd, ref_steps, strict=True):
        (m,) = s.updates
        (m0,) = ref_steps[with_upd.index(i)].updates
        assert s.t == ref_steps[with_upd.index(i)].t
        # the same stacked accel+mag update as the default rate's step ending there
        np.testing.assert_array_equal(m[0], m0[0])
        np.testing.assert_array_equal(m[1].R, m0[1].R)
    del accel


def test_update_rate_zero_updates_every_step_with_weighted_noise():
    samples, _ = _imu_mag_stream()
    st = AttitudeStream(samples, AttitudeOptions(rate_hz=0, update_hz=0))
    steps = [x for x in st if isinstance(x, Step)]
    assert st.summary["steps_per_update"] == 1
    assert all(s.updates for s in steps)
    ref = [x for x in AttitudeStream(samples, AttitudeOptions(rate_hz=0)) if isinstance(x, Step)]
    # R of an every-step accelerometer update is 10x that of a reference-step update
    ra = steps[-1].updates[0][1].R
    rb = next(s for s in reversed(ref) if s.updates).updates[0][1].R
    assert ra.shape == rb.shape and ra[0, 0] > rb[0, 0]


def test_update_rate_is_checked():
    import pytest

    with pytest.raises(ValueError, match="update rate"):
        AttitudeOptions(update_hz=-1.0)


def test_trapezoid_preintegration_of_snapshots():
    """Several snapshots per step (DataFlash IMU faster than the filter): the step's
    rotation is the product over its intervals of Exp(mean of the end rates * dt)."""
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.004, 0.006, 301))
    gyro = rng.normal(0, 1.0, (301, 3))
    steps, sm = _steps(t, gyro, np.tile([0, 0, -9.8], (301, 1)), rate_hz=25.0)
    assert sm["integration"] == "trapezoid" and sm["preintegrated_samples_per_step"] > 1
    q = np.array([1.0, 0, 0, 0])
    for i in range(1, 301):
        q = quat_mul(q, quat_exp(0.5 * (gyro[i] + gyro[i - 1]) * (t[i] - t[i - 1])))
    q2 = np.array([1.0, 0, 0, 0])
    for st in steps:
        q2 = quat_mul(q2, quat_exp(st.u * st.dt))
    np.testing.assert_allclose(quat_log(q), quat_log(q2), atol=1e-9)


def test_a_window_stops_reading_the_log_past_its_end():
    """``--end``: the replay's window takes every sample up to its end, one a little out
    of order too, and stops reading at the first sample :data:`WINDOW_STOP_S` past it
    (reading on decoded the rest of the log only to drop it); without an end it reads
    everything."""
    from uavest.apps.replay import WINDOW_STOP_S, _windowed

    opts = AttitudeOptions(end=20.0)
    read: list[float] = []

    def log():
        for t in [*np.arange(0.0, 20.5, 0.5), 19.9, *np.arange(21.0, 100.0, 1.0)]:
            read.append(float(t))
            yield ImuSample(float(t), np.zeros(3), np.array([0.0, 0.0, -9.8]), "IMU[0]")

    got = [s.t for s in _windowed(log(), opts.in_window, opts.end)]
    assert got == [t for t in read if t <= 20.0] and 19.9 in got
    assert max(read) == 20.0 + WINDOW_STOP_S + 1.0  # the first sample past the stop
    read.clear()
    everything = list(_windowed(log(), AttitudeOptions().in_window, None))
    assert len(everything) == len(read) and max(read) == 99.0
