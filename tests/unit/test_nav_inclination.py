"""The magnetic inclination at a navigation start in flight (``start_inclination``):
the accelerometer is not gravity while the vehicle accelerates, so the vehicle's own
acceleration (the GNSS acceleration, turned into the body) comes out of each sample
before the angle to the magnetometer is taken. With 0.2 m/s^2 left in, the angle is
1.2 deg off, beyond the World Magnetic Model's tolerance, and the window's wrong angle
was taken (a simulated in-flight start: pitch 1.1 deg off for the whole run)."""

from __future__ import annotations

import numpy as np

from uavest.engine.attitude import _Raw
from uavest.engine.nav_align import WMM_INCLINATION_TOL, start_inclination
from uavest.geometry.rotation import euler_to_quat, quat_rotate_inv
from uavest.ingest.types import LogParams
from uavest.models.attitude import inclination_from_params

G = 9.80665


def _window(inc: float, a_ned: np.ndarray, n: int = 25) -> tuple[list[_Raw], np.ndarray]:
    """``n`` steps of a vehicle at roll 8 deg, pitch -5 deg, yaw 40 deg accelerating at
    ``a_ned`` (m/s^2) through a field of inclination ``inc`` (rad): each step's mean
    specific force (body FRD, m/s^2) and field (body, unit); and the acceleration in
    the body."""
    q = euler_to_quat(np.radians(8.0), np.radians(-5.0), np.radians(40.0))
    f_ned = a_ned - np.array([0.0, 0.0, G])
    m_ned = np.array([np.cos(inc), 0.0, np.sin(inc)])
    f, m = quat_rotate_inv(q, f_ned), quat_rotate_inv(q, m_ned)
    rng = np.random.default_rng(3)
    raws = [_Raw(t=0.04 * (k + 1), t0=0.04 * k, w=np.zeros(3),
                 a=f + 0.002 * rng.standard_normal(3), n=8,
                 mag=m + 0.0005 * rng.standard_normal(3)) for k in range(n)]
    return raws, quat_rotate_inv(q, a_ned)


def test_the_vehicles_acceleration_comes_out_of_the_accelerometer():
    inc = np.radians(63.5)
    a_ned = np.array([0.2, 0.0, 0.0])  # 0.2 m/s^2 north: 1.2 deg of false tilt
    raws, a_body = _window(inc, a_ned)
    plain, why0 = start_inclination(raws, LogParams(), None, None, False)
    fixed, why = start_inclination(raws, LogParams(), None, None, False, a_body)
    assert abs(plain - inc) > np.radians(0.5), np.degrees(plain - inc)
    assert abs(fixed - inc) < np.radians(0.05), np.degrees(fixed - inc)
    assert "less the GNSS acceleration" in why and "less" not in why0
    # standing still (no acceleration) it is the plain angle, and said as before
    still, _ = _window(inc, np.zeros(3))
    a, w0 = start_inclination(still, LogParams(), None, None, False)
    b, w1 = start_inclination(still, LogParams(), None, None, False, np.zeros(3))
    assert a == b and w0 == w1 and abs(a - inc) < np.radians(0.05)


def test_in_flight_the_magnetic_model_is_taken_once_the_acceleration_is_out():
    params = LogParams()
    params.set_geo(47.3977, 8.5456, 500.0, 1767225600.0)  # 2026-01-01
    wmm, _ = inclination_from_params(params)
    assert wmm is not None
    # a local field 0.4 deg off the model's, a vehicle accelerating at 0.2 m/s^2 south
    # (its false tilt in the field's plane adds 1.2 deg to the offset)
    raws, a_body = _window(wmm + np.radians(0.4), np.array([-0.2, 0.0, 0.0]))
    plain, why0 = start_inclination(raws, params, None, None, True)
    fixed, why = start_inclination(raws, params, None, None, True, a_body)
    assert abs(plain - wmm) > WMM_INCLINATION_TOL and "magnetic model" not in why0
    assert fixed == wmm and "the magnetic model" in why, why
    # an option wins over both
    opt, w = start_inclination(raws, params, np.radians(60.0), None, True, a_body)
    assert opt == np.radians(60.0) and w == "option"
