"""The accelerometer density that follows the flight's roughness (uavest.engine.nav_rough):
its measure of roughness does not depend on the IMU's rate, a calm flight keeps the base
density, a rough one raises it, gaps and NaN are not counted as change, and a density
given as an option is used as it is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uavest.engine.nav_rough import ROUGH_BLOCK_S, RoughDensity
from uavest.engine.navigation import NavOptions, NavStream
from uavest.models.navigation import FAST_MAVLINK_PROFILE, ImuTransition, NavNoise


def _force(t: np.ndarray, seed: int = 0) -> np.ndarray:
    """A specific force (m/s^2, FRD, (T, 3)): gravity, a slow manoeuvre and a gusty part
    of sinusoids between 0.5 and 8 Hz, random phases."""
    rng = np.random.default_rng(seed)
    f = np.zeros((len(t), 3))
    f[:, 2] = -9.81
    f[:, 0] += 0.5 * np.sin(0.3 * t)
    for hz in np.linspace(0.5, 8.0, 12):
        f += 0.2 * np.sin(2 * np.pi * hz * t[:, None] + rng.uniform(0, 2 * np.pi, 3))
    return f


def _fed(rate: float, span: float = 30.0, scale: float = 1.0) -> RoughDensity:
    """A :class:`RoughDensity` fed the steps' mean force at ``rate`` Hz (the mean of the
    signal over each step, as a step builder's)."""
    fine = np.arange(0.0, span, 1e-3)
    f = _force(fine)
    f[:, :2] *= scale
    f[:, 2] = -9.81 + scale * (f[:, 2] + 9.81)
    k = int(round(1e3 / rate))
    rd = RoughDensity()
    for i in range(0, len(fine) - k, k):
        rd.add(f[i:i + k].mean(axis=0), k * 1e-3)
    return rd


def test_roughness_is_the_same_at_any_imu_rate_and_scales_with_the_force():
    rms = {rate: _fed(rate).rms for rate in (25.0, 50.0, 200.0, 1000.0)}
    assert rms[25.0] > 0.05, rms
    for r in rms.values():
        assert abs(r / rms[25.0] - 1.0) < 0.1, rms
    # twice the gusts: twice the roughness (the measure is linear in the force's change)
    assert _fed(50.0, scale=2.0).rms == pytest.approx(2.0 * rms[50.0], rel=0.02)
    # a steady force has none
    rd = RoughDensity()
    for _ in range(200):
        rd.add(np.array([0.1, 0.0, -9.81]), 0.02)
    assert rd.rms == 0.0


def test_gaps_and_nan_are_not_counted_as_change():
    rd = RoughDensity()
    for _ in range(100):
        rd.add(np.array([0.0, 0.0, -9.81]), ROUGH_BLOCK_S)
    rd.add(np.array([np.nan, 0.0, -9.81]), ROUGH_BLOCK_S)
    rd.add(np.array([0.0, 0.0, -9.81]), 0.0)
    assert rd.rms == 0.0
    # a step across an IMU gap, and the first block after it, are not compared
    rd.add(np.array([5.0, 0.0, -9.81]), 1.0)
    rd.add(np.array([5.0, 0.0, -9.81]), ROUGH_BLOCK_S)
    assert rd.rms == 0.0
    rd.add(np.array([6.0, 0.0, -9.81]), ROUGH_BLOCK_S)  # a real change, 1 m/s^2 in x
    assert rd.s == pytest.approx(1.0 / 3.0) and rd.w > 50
    assert rd.rms == pytest.approx(math.sqrt(1.0 / 3.0 / rd.w))


def _q_vel(model: ImuTransition, dt: float = 0.04) -> float:
    return float(model.Q(0.0, dt)[3, 3])


def test_the_step_density_follows_the_roughness_from_the_base_density():
    base = ImuTransition(NavNoise(accel_noise=0.002, accel_rough=0.02))
    calm, rough = RoughDensity(), RoughDensity()
    a_calm = np.array([0.0, 0.0, -9.81])
    rng = np.random.default_rng(1)
    for _ in range(500):
        m_calm = calm.model(base, a_calm, 0.04)
        m_rough = rough.model(base, a_calm + rng.normal(0.0, 0.3, 3), 0.04)
    # calm: the base density (to its 5 % rounding); rough: sqrt(q0^2 + (k r)^2)
    assert m_calm.noise.accel_noise == pytest.approx(0.002, rel=0.03)
    want = math.hypot(0.002, 0.02 * rough.rms)
    assert m_rough.noise.accel_noise == pytest.approx(want, rel=0.03)
    assert _q_vel(m_rough) > 2.0 * _q_vel(m_calm)
    # the rest of the model is the base's; the model is made again only on a new level
    assert m_rough.g == base.g and m_rough.space == base.space
    assert rough.model(base, a_calm + rng.normal(0.0, 0.3, 3), 0.04) is m_rough
    s = rough.summary()
    assert s is not None and s["min"] <= s["mean"] <= s["max"]
    assert 0.0 < s["roughness_ms2"] <= 1.1 * rough.rms


def test_a_zero_base_density_before_any_roughness_is_not_an_error():
    base = ImuTransition(NavNoise(accel_noise=0.0, accel_rough=0.02))
    rd = RoughDensity()
    m = rd.model(base, np.array([0.0, 0.0, -9.81]), 0.04)
    assert 0.0 < m.noise.accel_noise < 1e-8
    assert np.isfinite(m.Q(0.0, 0.04)).all()


def test_a_fixed_density_is_left_alone():
    base = ImuTransition(NavNoise(accel_noise=0.005))
    rd = RoughDensity()
    assert rd.model(base, np.array([3.0, 0.0, -9.81]), 0.04) is base
    assert rd.summary() is None


@pytest.mark.parametrize("noise, rough", [
    ({}, FAST_MAVLINK_PROFILE.accel_rough),
    ({"accel_noise": 0.01}, 0.0),  # a density given is used as it is
    ({"accel_noise": 0.01, "accel_rough": 0.03}, 0.03),
])
def test_an_accelerometer_density_given_turns_the_share_off(noise, rough):
    stream = NavStream(opts=NavOptions(noise=noise))
    stream._set_noise("RAW_IMU", 200.0)
    assert stream.noise.accel_rough == rough
    assert stream.noise.accel_noise == noise.get("accel_noise",
                                                 FAST_MAVLINK_PROFILE.accel_noise)
