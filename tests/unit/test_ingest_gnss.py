"""Raw GNSS and barometer measurements from synthetic tlogs written in tmp_path: units,
receiver accuracies, UNIX-time stamps mapped onto the vehicle clock, bad fixes counted."""

from __future__ import annotations

import math
import struct

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as ml

from uavest.ingest import read_log

T0_UNIX = 1_700_000_000.0
BOOT_UNIX = T0_UNIX - 100.0  # UNIX time of the vehicle's boot in these logs


class TlogWriter:
    def __init__(self, path):
        self.f = open(path, "wb")  # noqa: SIM115
        self.mav = ml.MAVLink(None, srcSystem=1, srcComponent=1)

    def write(self, msg, rx: float) -> None:
        self.f.write(struct.pack(">Q", int(round(rx * 1e6))) + msg.pack(self.mav))

    def close(self):
        self.f.close()


def imu(t_ms: int):
    return ml.MAVLink_raw_imu_message(t_ms * 1000, 0, 0, -1000, 0, 0, 0, 200, 0, 400)


def gps_raw(t_us: int, fix=3, lat=473977420, lon=85455940, alt=488_000, vel=500, cog=9000,
            eph=120, epv=180, sats=11, h_acc=900, v_acc=1600, vel_acc=150):
    return ml.MAVLink_gps_raw_int_message(t_us, fix, lat, lon, alt, eph, epv, vel, cog, sats,
                                          alt + 47_000, h_acc, v_acc, vel_acc, 0, 0)


def write_log(path, gps_time="boot", n=100, bad=None, system_time=True):
    """50 Hz IMU for n/50 s, GPS_RAW_INT at 5 Hz (time_usec boot or UNIX), SCALED_PRESSURE
    at 10 Hz, SYSTEM_TIME at 1 Hz; ``bad``: i -> GPS_RAW_INT field overrides."""
    w = TlogWriter(path)
    bad = bad or {}
    for i in range(n):
        t_ms = 10_000 + 20 * i
        rx = BOOT_UNIX + t_ms * 1e-3 + 0.003  # 3 ms link latency
        w.write(imu(t_ms), rx)
        if i % 50 == 0 and system_time:
            w.write(ml.MAVLink_system_time_message(int((BOOT_UNIX + t_ms * 1e-3) * 1e6),
                                                   t_ms), rx)
        if i % 5 == 0:
            w.write(ml.MAVLink_scaled_pressure_message(t_ms, 1013.25 - i * 0.01, 0.0, 2150),
                    rx + 0.001)
        if i % 10 == 0:
            fix_us = (t_ms - 60) * 1000  # the fix 60 ms before it is sent
            t_us = fix_us if gps_time == "boot" else int(BOOT_UNIX * 1e6) + fix_us
            w.write(gps_raw(t_us, **bad.get(i // 10, {})), rx + 0.002)
    w.close()


def test_gps_raw_int_units_accuracies_and_velocity(tmp_path):
    p = tmp_path / "g.tlog"
    write_log(p)
    log = read_log(p)
    g = log.gnss["GPS_RAW_INT"]
    assert len(g) == 10 and g.source == "GPS_RAW_INT" and g.instance == 0
    assert np.allclose(g.t, 10.0 - 0.06 + 0.2 * np.arange(10))
    assert np.allclose(g.lat_lon_alt[0], [47.397742, 8.545594, 488.0])
    # 5 m/s at course 90 deg: east; no vertical speed in GPS_RAW_INT
    assert np.allclose(g.vel_ned[:, :2], [[0.0, 5.0]] * 10, atol=1e-9)
    assert np.all(np.isnan(g.vel_ned[:, 2]))
    assert np.allclose(g.h_acc, 0.9) and np.allclose(g.v_acc, 1.6) and np.allclose(g.s_acc, 0.15)
    assert np.allclose(g.hdop, 1.2) and np.allclose(g.vdop, 1.8)
    assert np.all(g.fix_type == 3) and np.all(g.satellites == 11)
    assert log.stats.retimed == 0 and log.stats.bad_total == 0
    # the raw fix is still a position as before (not the autopilot's fused one)
    assert len(log.positions["GPS_RAW_INT"]) == 10


def test_scaled_pressure_hpa_to_pa(tmp_path):
    p = tmp_path / "b.tlog"
    write_log(p)
    b = read_log(p).baro["SCALED_PRESSURE"]
    assert len(b) == 20 and b.instance == 0
    assert np.allclose(b.pressure[:2], [101325.0, 101320.0])
    assert np.allclose(b.temperature, 21.5) and np.all(np.isnan(b.alt))
    assert np.allclose(b.t, 10.0 + 0.1 * np.arange(20))


def test_unix_time_usec_is_retimed_onto_the_vehicle_clock(tmp_path):
    p = tmp_path / "u.tlog"
    write_log(p, gps_time="unix")
    log = read_log(p)
    g = log.gnss["GPS_RAW_INT"]
    assert len(g) == 10 and log.stats.retimed == 10
    # through SYSTEM_TIME's UNIX - boot offset: the fix time on the vehicle clock
    assert np.allclose(g.t, 10.0 - 0.06 + 0.2 * np.arange(10), atol=1e-6)
    assert log.stats.late == 0 and log.stats.bad_total == 0 and log.stats.time_reset == 0
    assert g.t[0] >= log.imu.t[0] - 0.1 and g.t[-1] <= log.imu.t[-1]


def test_unix_time_without_system_time_uses_the_arrival(tmp_path):
    p = tmp_path / "n.tlog"
    write_log(p, gps_time="unix", system_time=False)
    log = read_log(p)
    g = log.gnss["GPS_RAW_INT"]
    # the first fix arrives with the first IMU sample only: from then on, receive times
    assert len(g) == 10 and log.stats.retimed == 10 and log.stats.bad_total == 0
    assert np.allclose(g.t, 10.0 + 0.2 * np.arange(10), atol=2e-3)


def test_bad_fixes_are_counted_and_skipped_never_a_crash(tmp_path):
    p = tmp_path / "bad.tlog"
    bad = {0: {"fix": 1, "lat": 0, "lon": 0},  # before the lock: no fix
           1: {"fix": 0},  # no GPS
           2: {"lat": 0, "lon": 0},  # a "fix" at 0/0
           3: {"fix": 2},  # 2-D: kept (the filter gates it)
           4: {"lat": 95 * 10**7},  # impossible latitude
           5: {"vel": 65535, "cog": 65535, "eph": 65535, "epv": 65535, "sats": 255,
               "h_acc": 0, "v_acc": 0, "vel_acc": 0}}  # unknowns: NaN, kept
    write_log(p, bad=bad)
    log = read_log(p)
    g = log.gnss["GPS_RAW_INT"]
    st = log.stats
    assert len(g) == 6
    assert st.no_fix == 3 and st.out_of_range == 1 and st.absent_sensor == 0
    assert list(g.fix_type[:2]) == [2, 3]
    k = int(np.flatnonzero(np.isnan(g.hdop))[0])
    assert np.all(np.isnan(g.vel_ned[k])) and g.satellites[k] == -1
    assert math.isnan(g.h_acc[k]) and math.isnan(g.v_acc[k]) and math.isnan(g.s_acc[k])


def test_gps2_raw_of_no_receiver_is_an_absent_sensor_and_gps_input(tmp_path):
    p = tmp_path / "g2.tlog"
    w = TlogWriter(p)
    for i in range(50):
        t_ms = 1000 + 20 * i
        rx = T0_UNIX + t_ms * 1e-3
        w.write(imu(t_ms), rx)
        if i % 10 == 0:
            w.write(ml.MAVLink_gps2_raw_message(t_ms * 1000, 0, 0, 0, 0, 65535, 65535, 0, 0,
                                                0, 0, 0), rx)
            w.write(ml.MAVLink_gps_input_message(
                t_ms * 1000, 0, 1 | 16, 0, 0, 3, 473977420, 85455940, 0.0, 0.9, 1.4,
                1.0, -2.0, 0.5, 0.2, 1.1, 2.2, 9), rx)
    w.close()
    log = read_log(p)
    assert "GPS2_RAW" not in log.gnss and log.stats.absent_sensor == 5
    assert log.stats.absent["GPS2_RAW"] == 5 and log.stats.bad_total == 0
    gi = log.gnss["GPS_INPUT"]
    assert len(gi) == 5
    assert np.isnan(gi.lat_lon_alt[0, 2])  # altitude flagged as ignored
    assert np.allclose(gi.vel_ned[0, :2], [1.0, -2.0]) and np.isnan(gi.vel_ned[0, 2])
    assert np.allclose([gi.h_acc[0], gi.v_acc[0], gi.s_acc[0]], [1.1, 2.2, 0.2])
    assert np.allclose([gi.hdop[0], gi.vdop[0]], [0.9, 1.4])
