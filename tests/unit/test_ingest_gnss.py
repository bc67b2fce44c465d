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


def write_log(path, gps_time="boot", n=100, bad=None, system_time=True, gps_clock_s=0.0):
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
            t_us = fix_us if gps_time == "boot" else int((BOOT_UNIX + gps_clock_s) * 1e6) + fix_us
            over = dict(bad.get(i // 10, {}))
            w.write(gps_raw(over.pop("t_us", t_us), **over), rx + 0.002)
    w.close()


def test_gps_raw_int_units_accuracies_and_velocity(tmp_path):
    p = tmp_path / "g.tlog"
    write_log(p)
    log = read_log(p)
    g = log.gnss["GPS_RAW_INT"]
    assert len(g) == 10 and g.source == "GPS_RAW_INT" and g.instance == 0
    assert np.allclose(g.t, 10.0 - 0.06 + 0.2 * np.arange(10))
    assert np.allclose(g.lat_lon_alt[0], [47.397742, 8.545594, 488.0])
    # 500 cm/s at course 90 deg: east, read as the middle of its centimetre (ArduPilot
    # and PX4 truncate the speed to whole cm/s); no vertical speed in GPS_RAW_INT
    assert np.allclose(g.vel_ned[:, :2], [[0.0, 5.005]] * 10, atol=1e-9)
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
    assert np.allclose(g.t, 10.0 + 0.2 * np.arange(10), atol=3e-3)


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


def test_unix_time_off_by_the_leap_seconds_uses_the_arrival_never_a_reboot(tmp_path):
    # the receiver's UNIX time 18 s behind the autopilot's (GPS - UTC): pushed through the
    # vehicle clock it would look like a reboot (3 consistent backward jumps)
    p = tmp_path / "leap.tlog"
    write_log(p, gps_time="unix", gps_clock_s=-18.0)
    log = read_log(p)
    g = log.gnss["GPS_RAW_INT"]
    assert len(g) == 10 and log.stats.retimed == 10
    assert log.stats.time_reset == 0 and log.stats.bad_total == 0
    assert np.allclose(g.t, 10.0 + 0.2 * np.arange(10), atol=3e-3)  # arrival times
    assert np.allclose(log.imu.t, 10.0 + 0.02 * np.arange(100))  # the IMU clock untouched


def test_retime_unix_rules():
    from uavest.ingest.timebase import VehicleClock, retime_unix
    from uavest.ingest.types import IngestStats

    c = VehicleClock(IngestStats())
    assert retime_unix(1.7e9, 5.0, c, None) is None  # no vehicle time, no offset
    assert retime_unix(1.7e9 + 3.0, 5.0, c, 1.7e9) == 3.0  # offset only
    c.push(100.0, 1000.0, None)  # vehicle time 100 s received at rx 1000 s
    assert np.isclose(retime_unix(0.0, 1000.5, c, None), 100.5)  # arrival
    assert np.isclose(retime_unix(1.7e9 + 100.3, 1000.5, c, 1.7e9), 100.3)  # the fix time
    assert np.isclose(retime_unix(1.7e9 + 90.0, 1000.5, c, 1.7e9), 100.5)  # disagree: arrival
    assert retime_unix(1.7e9 + 100.3, 1000.5, c, 1.7e9, floor=100.4) == 100.4  # not late


def test_dataflash_gps_without_its_gpa_goes_on_without_accuracies():
    from uavest.ingest.mavlink import GPA_LOOKAHEAD, merge_gpa

    class Rec:
        def __init__(self, name, t, **kw):
            self.name, self.TimeUS = name, t
            self.__dict__.update(kw)

        def get_type(self):
            return self.name

    gps1, gpa1 = Rec("GPS", 1), Rec("GPA", 1)
    gps2 = Rec("GPS", 2)
    others = [Rec("IMU", 2) for _ in range(GPA_LOOKAHEAD + 1)]
    gpa2 = Rec("GPA", 2)  # too late for gps2
    recs = [gps1, Rec("IMU", 1), gpa1, gps2, *others, gpa2, Rec("GPS", 3)]
    out = [m for m, _ in merge_gpa((r, None) for r in recs)]
    assert sorted(map(id, out)) == sorted(map(id, recs))  # nothing lost or repeated
    assert gps1._gpa is gpa1 and not hasattr(gps2, "_gpa")
    assert out.index(gps1) < out.index(gpa1) and out[-1].name == "GPS"


def test_a_fix_without_gnss_time_is_timed_by_its_arrival(tmp_path):
    # time_usec 0 with a fix (no GNSS week yet): neither boot time 0 nor a reboot
    p = tmp_path / "zero.tlog"
    write_log(p, bad={k: {"t_us": 0} for k in range(3)})
    log = read_log(p)
    g = log.gnss["GPS_RAW_INT"]
    assert len(g) == 10 and log.stats.retimed == 3 and log.stats.bad_total == 0
    assert np.allclose(g.t[:3], 10.0 + 0.2 * np.arange(3), atol=3e-3)


class _Rec:
    """A DataFlash record stand-in for the converters."""

    def __init__(self, name, **kw):
        self.name = name
        self.__dict__.update(kw)

    def get_type(self):
        return self.name


def _df_gps(**kw):
    f = dict(TimeUS=1_000_000, Status=3, GMS=0, GWk=0, NSats=9, HDop=0.9, Lat=47.1, Lng=8.5,
             Alt=400.0, Spd=2.0, GCrs=180.0, VZ=-0.5, U=1)
    f.update(kw)
    return _Rec("GPS", **f)


def test_dataflash_gps_and_baro_conversions_and_their_bad_records():
    from uavest.ingest.convert import check, convert_dataflash

    g = _df_gps(I=1)
    g._gpa = _Rec("GPA", TimeUS=1_000_000, I=1, VDop=1.3, HAcc=1.1, VAcc=1.9, SAcc=0.3, VV=0)
    (r,) = convert_dataflash(g)  # instance 1: no former "GPS" position item
    assert r.cat == "gnss" and r.source == "GPS[1]" and check(r) is None
    lla, vel, acc = r.values
    assert np.allclose(vel[:2], [-2.0, 0.0], atol=1e-12) and np.isnan(vel[2])  # VV = 0
    assert np.allclose(acc, [1.1, 1.9, 0.3, 0.9, 1.3, 9])
    gnss, pos = convert_dataflash(_df_gps())
    assert gnss.source == "GPS[0]" and pos.cat == "pos" and not pos.primary
    assert np.all(np.isnan(gnss.values[2][[0, 1, 2, 4]]))  # no GPA: accuracies unknown
    assert check(convert_dataflash(_df_gps(Status=1))[0]) == "empty"
    assert check(convert_dataflash(_df_gps(Lat=0.0, Lng=0.0))[0]) == "empty"
    assert check(convert_dataflash(_df_gps(Lat=float("nan")))[0]) == "nan"
    assert check(convert_dataflash(_df_gps(Spd=5000.0))[0]) == "out_of_range"
    b = _Rec("BAR2", TimeUS=1, Press=95000.0, Temp=30.0, Alt=1.5)
    (rb,) = convert_dataflash(b)
    assert rb.source == "BARO[1]" and check(rb) is None
    assert np.allclose(rb.values[0], [95000.0, 30.0, 1.5])
    for press, kind in ((0.0, "empty"), (float("nan"), "nan"), (2.0e5, "out_of_range")):
        bad = _Rec("BARO", TimeUS=1, Press=press, Temp=30.0, Alt=0.0)
        assert check(convert_dataflash(bad)[0]) == kind


def test_ulog_gnss_and_baro_rows_bad_ones_counted():
    from uavest.ingest.types import IngestStats
    from uavest.ingest.ulog import ULogData

    d = ULogData.__new__(ULogData)
    d.stats, d.gnss, d.baro = IngestStats(), {}, {}
    n = 8
    lat = np.full(n, 47.0)
    lat[2] = np.nan  # NaN latitude
    lat[3] = 0.0  # 0/0: no fix
    lon = np.where(np.arange(n) == 3, 0.0, 8.0)
    data = {
        "timestamp": (1_000_000 + 200_000 * np.arange(n)).astype(np.uint64),
        "latitude_deg": lat, "longitude_deg": lon, "altitude_msl_m": np.full(n, 500.0),
        "vel_n_m_s": np.full(n, 1.0), "vel_e_m_s": np.full(n, 2.0), "vel_d_m_s": np.full(n, 0.1),
        "vel_ned_valid": np.array([1, 1, 1, 1, 0, 1, 1, 1]),
        "fix_type": np.array([0, 3, 3, 3, 3, 2, 3, 3]), "eph": np.full(n, 0.8),
        "epv": np.full(n, 1.4), "s_variance_m_s": np.full(n, 0.2), "hdop": np.zeros(n),
        "vdop": np.full(n, 1.1), "satellites_used": np.full(n, 12),
    }
    d._gnss("sensor_gps", data, 0)
    g = d.gnss["sensor_gps"]
    assert d.stats.no_fix == 2 and d.stats.nan == 1 and d.stats.bad_total == 1
    assert np.allclose(g["t"], [1.2, 1.8, 2.0, 2.2, 2.4])
    assert np.all(np.isnan(g["vel_ned"][1])) and np.allclose(g["vel_ned"][0], [1.0, 2.0, 0.1])
    assert list(g["fix_type"]) == [3, 3, 2, 3, 3]
    assert np.all(np.isnan(g["hdop"])) and np.allclose(g["h_acc"], 0.8)
    p = np.array([95000.0, 0.0, 95001.0, 3.0e5])
    d._baro("sensor_baro", {"timestamp": np.array([1, 2, 3, 4], dtype=np.uint64) * 100_000,
                            "pressure": p, "temperature": np.full(4, 20.0)}, 0)
    assert np.allclose(d.baro["sensor_baro"]["pressure"], [95000.0, 95001.0])
    assert d.stats.empty == 1 and d.stats.out_of_range == 1
    d._baro("sensor_baro[1]", {"timestamp": np.array([1, 2], dtype=np.uint64),
                               "pressure": np.zeros(2)}, 1)
    assert "sensor_baro[1]" not in d.baro and d.stats.absent["sensor_baro[1]"] == 2


def test_on_arrival_releases_every_sample_as_it_comes_and_counts_none_late(tmp_path):
    """``reorder_window=0``: nothing held or reordered (the engine's history orders):
    the fixes stamped 60 ms before they are sent come after newer IMU samples, not
    ``late``; each stream stays in time order; a RAW_IMU's magnetometer comes before its
    IMU sample (a step that ends at that sample is complete when it arrives); a short
    reorder window drops those fixes as ``late``, a long one orders them."""
    from uavest.ingest import GnssSample, ImuSample, MagSample, open_source

    p = tmp_path / "a.tlog"
    write_log(p, n=200)
    arr = open_source(p, reorder_window=0.0)
    got = list(arr)
    ordered = list(open_source(p, reorder_window=1.0))
    short = open_source(p, reorder_window=0.02)
    n_short = sum(isinstance(s, GnssSample) for s in short)
    assert arr.stats.late == 0 and short.stats.late > 0 and n_short < 20
    key = lambda s: (type(s).__name__, s.source, s.t)  # noqa: E731
    assert sorted(map(key, got)) == sorted(map(key, ordered))
    assert [s.t for s in got] != sorted(s.t for s in got)  # as they came
    for kind in (ImuSample, MagSample, GnssSample):
        ts = [s.t for s in got if isinstance(s, kind)]
        assert ts == sorted(ts) and len(ts) > 10
    fix = next(i for i, s in enumerate(got) if isinstance(s, GnssSample))
    assert any(isinstance(s, ImuSample) and s.t > got[fix].t for s in got[:fix])
    for i, s in enumerate(got):
        if isinstance(s, ImuSample):
            assert isinstance(got[i - 1], MagSample) and got[i - 1].t == s.t


def test_on_arrival_releases_a_receive_burst_in_time_order(tmp_path):
    """The messages of one read (one receive time, as a tlog records them) are released
    together in time order: a velocity stamped 1 ms before the IMU sample read with it
    comes first (a step ending at that IMU sample is complete when it arrives); across
    receive times nothing is reordered."""
    from uavest.ingest import ImuSample, PositionSample, open_source

    p = tmp_path / "b.tlog"
    w = TlogWriter(p)
    for i in range(40):
        t_ms = 10_000 + 20 * i
        rx = BOOT_UNIX + t_ms * 1e-3 + 0.003
        w.write(imu(t_ms), rx)
        if i % 5 == 4:  # in the IMU's burst, stamped before it
            w.write(ml.MAVLink_global_position_int_message(
                t_ms - 1, 473977420, 85455940, 488_000, 20_000, 100, 0, 0, 9000), rx)
        if i % 5 == 2:  # in a burst of its own after the IMU's, stamped before it
            w.write(ml.MAVLink_global_position_int_message(
                t_ms - 1, 473977420, 85455940, 488_000, 20_000, 100, 0, 0, 9000), rx + 1e-3)
    w.close()
    got = [s for s in open_source(p, reorder_window=0.0)
           if isinstance(s, ImuSample | PositionSample) and s.source != "GPS_RAW_INT"]
    same, own = 0, 0
    for i, s in enumerate(got):
        if isinstance(s, PositionSample):
            t_ms = round(s.t * 1000) + 1  # the IMU's time it was written with
            if t_ms % 100 == 80:  # read with that IMU sample: released before it
                assert isinstance(got[i + 1], ImuSample) and round(got[i + 1].t * 1000) == t_ms
                same += 1
            else:  # read after that IMU sample: released after it, as it came
                assert t_ms % 100 == 40
                assert isinstance(got[i - 1], ImuSample) and round(got[i - 1].t * 1000) == t_ms
                own += 1
    assert same == own == 8


def test_gps_raw_int_speed_is_read_as_the_middle_of_its_centimetre(tmp_path):
    """A stopped receiver stays at 0; 1 cm/s north is 0.015 m/s (a truncated speed)."""
    p = tmp_path / "g.tlog"
    write_log(p, bad={0: {"vel": 0}, 1: {"vel": 1, "cog": 0}})
    g = read_log(p).gnss["GPS_RAW_INT"]
    assert np.allclose(g.vel_ned[0, :2], [0.0, 0.0])
    assert np.allclose(g.vel_ned[1, :2], [0.015, 0.0])
