"""Unit and frame conversions of the ingest layer (no files needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink import mavutil
from scipy.spatial.transform import Rotation

from uavest.ingest import euler_to_quat
from uavest.ingest.convert import G0, Raw, check, convert_dataflash, convert_mavlink

ml = mavutil.mavlink


def _by_cat(raws):
    return {r.cat: r for r in raws}


@pytest.mark.parametrize(
    "msg",
    [
        ml.MAVLink_scaled_imu_message(5, 1000, -2000, 500, 1000, -500, 250, 1000, 200, -300),
        ml.MAVLink_scaled_imu2_message(5, 1000, -2000, 500, 1000, -500, 250, 1000, 200, -300),
        ml.MAVLink_scaled_imu3_message(5, 1000, -2000, 500, 1000, -500, 250, 1000, 200, -300),
        ml.MAVLink_raw_imu_message(5000, 1000, -2000, 500, 1000, -500, 250, 1000, 200, -300),
    ],
)
def test_milli_units_to_si(msg):
    """Milli-units to SI, each count the middle of its unit (truncated towards zero)."""
    r = _by_cat(convert_mavlink(msg))
    gyro, accel = r["imu"].values
    np.testing.assert_allclose(accel, np.array([1000.5, -2000.5, 500.5]) * 9.80665e-3,
                               rtol=1e-12)
    np.testing.assert_allclose(gyro, [1.0005, -0.5005, 0.2505], rtol=1e-12)
    np.testing.assert_allclose(r["mag"].values[0], [1.0005, 0.2005, -0.3005], rtol=1e-12)
    assert r["imu"].source == msg.get_type()
    expected_instance = {"SCALED_IMU2": 1, "SCALED_IMU3": 2}.get(msg.get_type(), 0)
    assert r["imu"].instance == expected_instance


def test_a_truncated_count_is_read_as_the_middle_of_its_unit():
    """ArduPilot passes float milli-units to RAW_IMU's int16 fields (a C conversion:
    truncated towards zero), and uavest's simulator encodes them as it does. Values
    spread over (-5, 5) counts, so encoded, read back within half a count of the value
    and without bias; read as plain counts they were half a count short, towards zero,
    in each half."""
    from uavest.ingest.convert import MRAD_TO_RAD, count_middle
    from uavest.sim.protocol import _c_i16

    g = np.random.default_rng(7)
    x = g.uniform(-5.0, 5.0, 20000)
    x = x[np.abs(x) >= 1.0]  # (0 stands for (-1, 1): its middle is exact only on average)
    n = np.array([_c_i16(float(v)) for v in x], dtype=float)
    assert np.array_equal(n, np.trunc(x))
    assert _c_i16(4e4) == 32767 and _c_i16(-4e4) == -32768
    back = np.array([count_middle(float(k)) for k in n])
    assert np.all(np.abs(back - x) <= 0.5)
    for half in (x > 0, x < 0):
        assert abs(np.mean(back[half] - x[half])) < 0.01
        assert abs(np.mean(n[half] - x[half]) + 0.5 * np.sign(x[half][0])) < 0.01
    assert count_middle(0.0) == 0.0 and math.isnan(count_middle(float("nan")))
    msg = ml.MAVLink_raw_imu_message(5000, 0, 0, -999, 0, 0, -231, 0, 0, 0)
    gyro, accel = _by_cat(convert_mavlink(msg))["imu"].values
    # vtol.tlog's first sample: zgyro -231 where SIMSTATE has -0.2311 rad/s
    assert gyro[2] == -231.5 * MRAD_TO_RAD and gyro[0] == 0.0 and accel[2] < -999 * 9.80665e-3


def test_all_zero_imu_is_empty_not_a_measurement():
    (imu,) = convert_mavlink(ml.MAVLink_scaled_imu3_message(5, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert check(imu) == "empty"


def test_highres_imu_is_already_si():
    msg = ml.MAVLink_highres_imu_message(
        7, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 1013.0, 0.0, 10.0, 20.0, 0x1FF
    )
    r = _by_cat(convert_mavlink(msg))
    np.testing.assert_allclose(r["imu"].values[1], [0.1, 0.2, -9.8], rtol=1e-6)
    np.testing.assert_allclose(r["imu"].values[0], [0.01, 0.02, 0.03], rtol=1e-6)
    np.testing.assert_allclose(r["mag"].values[0], [0.2, 0.0, 0.4], rtol=1e-6)
    # only accel/gyro updated: no magnetometer sample
    msg2 = ml.MAVLink_highres_imu_message(
        7, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 0.0, 0.0, 0.0, 0.0, 0x3F
    )
    assert [r.cat for r in convert_mavlink(msg2)] == ["imu"]


def test_attitude_euler_matches_scipy_zyx():
    (r,) = convert_mavlink(ml.MAVLink_attitude_message(1, 0.1, 0.2, 0.3, 0, 0, 0))
    q = r.values[0]
    x, y, z, w = Rotation.from_euler("ZYX", [0.3, 0.2, 0.1]).as_quat()
    np.testing.assert_allclose(q, [w, x, y, z], atol=1e-12)
    assert r.kind == "autopilot" and r.source == "ATTITUDE"


def test_quaternion_is_body_frd_to_ned():
    # yaw 90 deg: the body x axis (nose) points east in NED
    q = euler_to_quat(0.0, 0.0, math.pi / 2)
    rot = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    np.testing.assert_allclose(rot.apply([1.0, 0, 0]), [0, 1.0, 0], atol=1e-12)
    # pitch up 90 deg: nose points up, i.e. -z in NED
    q = euler_to_quat(0.0, math.pi / 2, 0.0)
    rot = Rotation.from_quat([q[1], q[2], q[3], q[0]])
    np.testing.assert_allclose(rot.apply([1.0, 0, 0]), [0, 0, -1.0], atol=1e-12)


def test_euler_vectorised_matches_scalar():
    rng = np.random.default_rng(1)
    e = rng.uniform([-3, -1.5, -3], [3, 1.5, 3], size=(50, 3))
    qv = euler_to_quat(e[:, 0], e[:, 1], e[:, 2])
    for i in range(50):
        np.testing.assert_allclose(qv[i], euler_to_quat(*e[i]), atol=1e-12)
        assert qv[i, 0] >= 0


def test_reference_kinds():
    (s,) = convert_mavlink(ml.MAVLink_simstate_message(0.1, 0.2, 0.3, 0, 0, -9.8, 0, 0, 0, 1, 2))
    (a,) = convert_mavlink(ml.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0))
    (q,) = convert_mavlink(ml.MAVLink_attitude_quaternion_message(1, 0.5, 0.5, 0.5, 0.5, 0, 0, 0))
    assert (s.kind, a.kind, q.kind) == ("truth", "ahrs2", "autopilot")
    np.testing.assert_allclose(s.values[0], a.values[0])
    np.testing.assert_allclose(q.values[0], [0.5, 0.5, 0.5, 0.5])


def test_bad_values_are_classified():
    (nan_att,) = convert_mavlink(ml.MAVLink_attitude_message(1, float("nan"), 0, 0, 0, 0, 0))
    assert check(nan_att) == "nan"
    (bad_q,) = convert_mavlink(ml.MAVLink_attitude_quaternion_message(1, 0.9, 0, 0, 0, 0, 0, 0))
    assert check(bad_q) == "out_of_range"
    (ok_q,) = convert_mavlink(
        ml.MAVLink_attitude_quaternion_message(1, 1.0 + 5e-4, 0, 0, 0, 0, 0, 0)
    )
    assert check(ok_q) is None and abs(np.linalg.norm(ok_q.values[0]) - 1) < 1e-12
    fast = ml.MAVLink_scaled_imu_message(1, 0, 0, -1000, 30000, 30000, 0, 0, 0, 0)
    assert check(_by_cat(convert_mavlink(fast))["imu"]) == "out_of_range"
    hard = ml.MAVLink_scaled_imu_message(1, 0, 0, -1000, 0, 0, 0, 0, 0, 0)
    assert check(_by_cat(convert_mavlink(hard))["imu"]) is None
    assert check(Raw("mag", "MAG[0]", 0, (np.array([11.0, 0, 0]),))) == "out_of_range"
    (bad_e,) = convert_mavlink(ml.MAVLink_attitude_message(1, 0.0, 2.0, 0, 0, 0, 0))
    assert check(bad_e) == "out_of_range"  # |pitch| > pi/2


def test_position_units():
    gp = ml.MAVLink_global_position_int_message(
        1, -353629904, 1491649392, 587850, 6750, -188, 6, 0, 0
    )
    (r,) = convert_mavlink(gp)
    ned, vel, lla = r.values
    assert ned is None
    np.testing.assert_allclose(lla, [-35.3629904, 149.1649392, 587.85])
    np.testing.assert_allclose(vel, [-1.88, 0.06, 0.0])


def test_sim_state_is_attitude_and_position_truth():
    q = euler_to_quat(0.1, -0.2, 1.0)
    args = (*q, 0.1, -0.2, 1.0, 0, 0, -9.8, 0, 0, 0)
    # ArduPilot fills the float lat/lon in degE7; the MAVLink 2 extension has the integers
    m = ml.MAVLink_sim_state_message(*args, 473977472.0, 85454760.0, 433.09, 0, 0,
                                     -0.5, 0.25, 1.5)
    m.lat_int, m.lon_int = 473977462, 85454756  # (set: a MAVLink 1 dialect lacks them)
    ref, pos = convert_mavlink(m)
    assert (ref.cat, ref.kind, pos.cat, ref.source) == ("ref", "truth", "pos", "SIM_STATE")
    np.testing.assert_allclose(ref.values[0], q, atol=1e-6)
    ned, vel, lla = pos.values
    assert ned is None and check(pos) is None
    np.testing.assert_allclose(lla, [47.3977462, 8.5454756, 433.09], atol=1e-5)
    np.testing.assert_allclose(vel, [-0.5, 0.25, 1.5], atol=1e-6)
    # without the extension (0): the float fields, in degE7 or in degrees
    for lat, lon in ((473977472.0, 85454760.0), (47.3977472, 8.545476)):
        _, pos = convert_mavlink(ml.MAVLink_sim_state_message(*args, lat, lon, 433.09, 0, 0,
                                                              0, 0, 0))
        np.testing.assert_allclose(pos.values[2][:2], [47.3977472, 8.545476], atol=1e-5)


def test_hil_state_quaternion_is_attitude_and_position_truth():
    """PX4 SITL's ground truth (and uavest's simulator's): lat/lon degE7, alt mm, velocity
    cm/s NED."""
    q = euler_to_quat(0.1, -0.2, 1.0)
    m = ml.MAVLink_hil_state_quaternion_message(
        5_000_000, [float(c) for c in q], 0.1, 0.2, 0.3, 473977462, 85454756, 433090,
        -50, 25, 150, 100, 100, 0, 0, -1000)
    ref, pos = convert_mavlink(m)
    assert (ref.cat, ref.kind, pos.cat, ref.source) == ("ref", "truth", "pos",
                                                        "HIL_STATE_QUATERNION")
    np.testing.assert_allclose(ref.values[0], q, atol=1e-6)
    ned, vel, lla = pos.values
    assert ned is None and check(pos) is None
    np.testing.assert_allclose(lla, [47.3977462, 8.5454756, 433.09], atol=1e-9)
    np.testing.assert_allclose(vel, [-0.5, 0.25, 1.5], atol=1e-9)


class _DF:
    """Minimal stand-in for a pymavlink DataFlash record."""

    def __init__(self, name, **kw):
        self._name = name
        self.__dict__.update(kw)

    def get_type(self):
        return self._name


def test_dataflash_units_and_instances():
    imu2 = _DF("IMU2", TimeUS=1, GyrX=0.1, GyrY=0.2, GyrZ=0.3, AccX=0, AccY=0, AccZ=-G0)
    (r,) = convert_dataflash(imu2)
    assert (r.source, r.instance) == ("IMU[1]", 1)
    np.testing.assert_allclose(r.values[1], [0, 0, -G0])
    mag = _DF("MAG", TimeUS=1, I=2, MagX=219, MagY=179, MagZ=-517)
    (r,) = convert_dataflash(mag)
    assert (r.source, r.instance) == ("MAG[2]", 2)
    np.testing.assert_allclose(r.values[0], [0.219, 0.179, -0.517])
    att = _DF("ATT", TimeUS=1, Roll=-7.18, Pitch=2.58, Yaw=337.1)
    (r,) = convert_dataflash(att)
    x, y, z, w = Rotation.from_euler("ZYX", [337.1 - 360, 2.58, -7.18], degrees=True).as_quat()
    np.testing.assert_allclose(r.values[0], np.sign(w) * np.array([w, x, y, z]), atol=1e-12)
    sim = _DF("SIM", TimeUS=1, Roll=0.0, Pitch=0.0, Yaw=90.0)
    (r,) = convert_dataflash(sim)
    assert r.kind == "truth"
    np.testing.assert_allclose(r.values[0], euler_to_quat(0, 0, math.pi / 2), atol=1e-12)


def test_raw_imu_instance_is_the_field_not_the_message_id():
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    msg = mav2.MAVLink_raw_imu_message(1, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 2, 0)
    assert _by_cat(convert_mavlink(msg))["imu"].instance == 2


def test_the_fast_check_of_imu_and_mag_items_is_the_numpy_check():
    """``check`` takes IMU and magnetometer items (float 3-vectors) on Python floats: the
    same kind as the numpy reference (``check_any``) on every edge: NaN, infinities,
    all zero, at and beyond the limits, overflowing squares, float32, lists (the
    reference's own path)."""
    from uavest.ingest.convert import MAX_ACCEL, MAX_GYRO, MAX_MAG, check_any

    nan, inf = float("nan"), float("inf")
    vecs = [[0.0, 0.0, 0.0], [0.1, -0.2, 9.8], [nan, 0, 0], [0, inf, 0], [0, 0, -inf],
            [1e200, 0, 0], [1e-320, 0, 0], [1.5e308, 1.5e308, 0], [-0.0, 0.0, -0.0],
            [1e308, nan, 0], [MAX_GYRO, 0, 0], [0, -MAX_GYRO * 1.0001, 0],
            [MAX_ACCEL * 0.6, MAX_ACCEL * 0.8, 0.0], [MAX_ACCEL, 1.0, 0.0],
            [MAX_MAG * 0.6, 0.0, MAX_MAG * 0.8], [0.0, MAX_MAG + 1e-9, 0.0]]
    seen = set()
    for dtype in (np.float64, np.float32):
        arrays = [np.array(v, dtype=dtype) for v in vecs]
        for a in arrays:
            items = [Raw("mag", "MAG[0]", 0, (a,))]
            items += [Raw("imu", "IMU[0]", 0, (a, b)) for b in arrays]
            for r in items:
                want = check_any(r)
                assert check(r) == want, (r.values, check(r), want)
                seen.add(want)
    assert seen == {None, "nan", "empty", "out_of_range"}
    listed = Raw("imu", "IMU[0]", 0, ([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
    assert check(listed) == check_any(listed) == "empty"


def test_the_fast_check_and_conversion_of_attitude_references_are_the_numpy_ones():
    """Attitude references (``ref``) are converted from Euler angles and checked on Python
    floats: the quaternion equals :func:`euler_to_quat` (numpy) to rounding over the whole
    range and past it, and the check gives the reference's kind (``check_any``) for unit,
    NaN, infinite, zero, at-the-tolerance and float32 quaternions."""
    from uavest.geometry.rotation import euler_to_quat
    from uavest.ingest.convert import QUAT_NORM_TOL, _ref_from_euler, check_any

    g = np.random.default_rng(5)
    for roll, pitch, yaw in g.uniform(-1.0, 1.0, (500, 3)) * [np.pi, np.pi / 2, 2 * np.pi]:
        r = _ref_from_euler("ATTITUDE", "autopilot", roll, pitch, yaw)
        np.testing.assert_allclose(r.values[0], euler_to_quat(roll, pitch, yaw), rtol=0,
                                   atol=1e-15)
        assert r.values[0][0] >= 0.0 and check(r) is None
    nan, inf = float("nan"), float("inf")
    for e in ((nan, 0.0, 0.0), (0.0, inf, 0.0), (4.0, 0.0, 0.0), (0.0, 0.0, -7.0)):
        r = _ref_from_euler("SIMSTATE", "truth", *e)
        assert check(r) == check_any(r) in ("nan", "out_of_range")
    qs = [[1.0, 0, 0, 0], [nan, 0, 0, 0], [0.5, 0.5, 0.5, -inf], [0.0, 0, 0, 0],
          [1.0 + QUAT_NORM_TOL * 0.99, 0, 0, 0], [1.0 + QUAT_NORM_TOL * 1.01, 0, 0, 0],
          [0.0, 0.6, 0.0, 0.8]]
    seen = set()
    for dtype in (np.float64, np.float32):
        for q in qs:
            r = Raw("ref", "ATTITUDE_QUATERNION", 0, (np.array(q, dtype=dtype),), "autopilot")
            want = check_any(r)
            assert check(r) == want, (q, dtype)
            seen.add(want)
    assert seen == {None, "nan", "out_of_range"}


def test_milli_imu_on_floats_gives_numpys_products():
    """RAW_IMU / SCALED_IMU* converted on Python floats: bitwise the numpy products of the
    previous form, a magnetometer item exactly when a field is non-zero or not finite."""
    from uavest.ingest.convert import MG_TO_MS2, MGAUSS_TO_GAUSS, MRAD_TO_RAD

    g = np.random.default_rng(2)
    for k in range(200):
        v = g.integers(-32768, 32768, 9)
        if k % 3 == 0:
            v[6:] = 0
        msg = ml.MAVLink_scaled_imu2_message(5, *(int(a) for a in v))
        r = _by_cat(convert_mavlink(msg))
        gyro, accel = r["imu"].values
        mid = v + 0.5 * np.sign(v)  # each count the middle of its unit
        assert np.array_equal(gyro, mid[3:6] * MRAD_TO_RAD)
        assert np.array_equal(accel, mid[:3] * MG_TO_MS2)
        assert ("mag" in r) == bool(np.any(v[6:]))
        if "mag" in r:
            assert np.array_equal(r["mag"].values[0], mid[6:] * MGAUSS_TO_GAUSS)
    msg = ml.MAVLink_scaled_imu2_message(5, 1, 2, 3, 4, 5, 6, 0, 0, 0)
    msg.ymag = float("nan")
    assert check(_by_cat(convert_mavlink(msg))["mag"]) == "nan"


def test_quaternion_references_on_floats_are_normalize_quat_bitwise():
    """Attitude references from a quaternion (SIMSTATE's SIM_STATE, HIL_STATE_QUATERNION,
    ATTITUDE_QUATERNION) are normalised on Python floats: bitwise
    :func:`normalize_quat`'s numbers for unit-ish quaternions of either sign, and left as
    they came (for the check to count) when not finite or too far from unit norm."""
    from uavest.ingest.convert import QUAT_NORM_TOL, _ref_from_quat, check_any, normalize_quat

    g = np.random.default_rng(8)
    for k in range(2000):
        q = g.normal(size=4)
        q /= np.linalg.norm(q)
        q *= 1.0 + g.uniform(-0.5, 0.5) * QUAT_NORM_TOL
        if k % 2:
            q[0] = -abs(q[0])
        got = _ref_from_quat("SIM_STATE", "truth", *q).values[0]
        assert np.array_equal(got, normalize_quat(q)), q
        assert got[0] >= 0.0
    nan = float("nan")
    for q in ([nan, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0], [-2.0, 0.0, 0.0, 0.0],
              [0.5, 0.5, 0.5, float("-inf")]):
        r = _ref_from_quat("SIM_STATE", "truth", *q)
        assert np.array_equal(r.values[0], np.array(q), equal_nan=True)
        assert check(r) == check_any(r) in ("nan", "out_of_range")


def test_the_fast_check_of_position_items_is_the_numpy_check():
    """Position items (a simulator's truth, the autopilot's fused position: NED, velocity,
    lat/lon/alt, each possibly absent) are checked on Python floats: the numpy reference's
    kind (``check_any``) on NaN, infinities, the limits, a 0/0 fix, float32 and lists."""
    from uavest.ingest.convert import MAX_POS, MAX_VEL, check_any

    nan, inf = float("nan"), float("inf")
    neds = [None, [1.0, -2.0, 3.0], [MAX_POS, 0, 0], [0, MAX_POS * 0.8, MAX_POS * 0.61],
            [nan, 0, 0], [1.5e308, 1.5e308, 0]]
    vels = [None, [0.1, 0.2, -0.3], [0, 0, MAX_VEL * 1.0001], [0, -inf, 0], [MAX_VEL, 0, 0]]
    llas = [None, [47.4, 8.5, 408.0], [0.0, 0.0, 10.0], [-90.5, 8.0, 0.0], [47.0, 180.1, 0],
            [47.0, 8.0, -1e5 - 1], [47.0, nan, 0.0], [0.0, 1e-9, 0.0]]
    seen = set()
    for dtype in (np.float64, np.float32, None):
        for ned in neds:
            for vel in vels:
                for lla in llas:
                    vals = tuple(None if v is None else (list(v) if dtype is None
                                                         else np.array(v, dtype=dtype))
                                 for v in (ned, vel, lla))
                    r = Raw("pos", "SIMSTATE", 0, vals, primary=False)
                    want = check_any(r)
                    assert check(r) == want, (vals, check(r), want)
                    seen.add(want)
    assert seen == {None, "nan", "empty", "out_of_range"}
