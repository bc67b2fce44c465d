"""Raw GNSS and barometer streams of the shared real logs: which log carries which, their
rates, units and times on the IMU's clock (never the autopilot's fused positions)."""

from __future__ import annotations

import numpy as np
from conftest import shared_log

from uavest.ingest import read_log


def test_vtol_tlog_gps_raw_int_and_scaled_pressure():
    log = read_log(shared_log("vtol.tlog"))
    assert set(log.gnss) == {"GPS_RAW_INT"} and set(log.baro) == {"SCALED_PRESSURE"}
    g = log.gnss["GPS_RAW_INT"]
    assert len(g) == 798
    dt = np.diff(g.t)
    assert abs(np.median(dt) - 0.2) < 1e-3  # 5 Hz (with the telemetry gaps of the log)
    assert np.all(dt > 0)
    # on the IMU's clock: the first fix 0.12 s before the first IMU sample, none after
    assert g.t[0] > log.imu.t[0] - 0.2 and g.t[-1] <= log.imu.t[-1]
    assert np.all(g.fix_type == 6) and np.all(g.satellites == 10)
    assert np.allclose(g.lat_lon_alt[0], [-35.3629847, 149.1649392, 587.85])
    assert np.all(np.isnan(g.vel_ned[:, 2])) and np.nanmax(np.abs(g.vel_ned[:, :2])) < 40
    assert np.allclose(np.nanmedian(g.hdop), 1.21)
    b = log.baro["SCALED_PRESSURE"]
    assert len(b) == 793 and 9.0e4 < np.median(b.pressure) < 9.6e4  # Pa, ~590 m AMSL
    assert log.stats.retimed == 0 and log.stats.late == 0
    # the autopilot's fused outputs stay positions, never GNSS measurements
    assert "GLOBAL_POSITION_INT" in log.positions and "GLOBAL_POSITION_INT" not in log.gnss


def test_dataflash_gps_with_its_gpa_accuracies_and_baro():
    log = read_log(shared_log("test.BIN"))
    assert set(log.gnss) == {"GPS[0]"} and set(log.baro) == {"BARO[0]"}
    g = log.gnss["GPS[0]"]
    assert len(g) == 5 and np.all(g.fix_type == 3) and np.all(g.satellites == 11)
    assert abs(np.median(np.diff(g.t)) - 0.2) < 1e-3 and g.t[0] > log.imu.t[0]
    # the first fix: GPS HDop 0.77 with its GPA (same TimeUS) VDop 1.22, HAcc 1.61 m,
    # VAcc 2.41 m, SAcc 0.51 m/s; Spd 0.2 m/s at course 36.87 deg, VZ 0.35 m/s down
    assert np.isclose(g.t[0], 81.855471)
    assert np.allclose(g.lat_lon_alt[0], [-35.3626277, 149.1653034, 588.82])
    assert np.allclose([g.hdop[0], g.vdop[0], g.h_acc[0], g.v_acc[0], g.s_acc[0]],
                       [0.77, 1.22, 1.61, 2.41, 0.51])
    assert np.allclose(g.vel_ned[0], [0.16, 0.12, 0.35], atol=1e-6)
    b = log.baro["BARO[0]"]
    assert len(b) == 8 and np.allclose(b.pressure[0], 94144.234375)
    assert np.allclose(b.temperature[0], 32.36) and np.allclose(b.alt[0], 0.028, atol=1e-4)
    assert "GPS" in log.positions  # the former position of the fix is unchanged


def test_ulogs_which_carry_which_streams():
    assert read_log(shared_log("sample.ulg")).gnss == {}  # no GNSS, no baro topics
    for name in ("sample_logging_tagged_and_default_params.ulg", "sample_px4_events.ulg"):
        log = read_log(shared_log(name))
        assert set(log.gnss) == {"vehicle_gps_position", "sensor_gps"}, name
        assert set(log.baro) == {"sensor_baro", "sensor_baro[1]"}, name
        # PX4 SITL: 146 + 8 records before the lock (fix_type 0) counted, not bad data
        assert log.stats.no_fix == 154 and log.stats.bad_total == 0
        for g in log.gnss.values():
            assert np.all(g.fix_type >= 2) and np.all(np.diff(g.t) > 0)
            assert log.imu.t[0] <= g.t[0] and g.t[-1] <= log.imu.t[-1] + 0.1
            assert np.allclose(g.lat_lon_alt[:, :2], [47.397742, 8.545594], atol=1e-5)
            assert np.all(np.isnan(g.hdop))  # PX4 SITL reports 0: not reported
            assert np.allclose(g.s_acc, 0.25) and np.all(g.h_acc > 0)
        for b in log.baro.values():
            assert np.all((b.pressure > 9.5e4) & (b.pressure < 9.62e4))  # Pa, ~488 m AMSL
    ev = read_log(shared_log("sample_px4_events.ulg"))
    assert len(ev.gnss["vehicle_gps_position"]) == 437 and len(ev.gnss["sensor_gps"]) == 23
    assert len(ev.baro["sensor_baro"]) == 31


def test_ulog_stream_yields_the_gnss_and_baro_of_the_arrays():
    from uavest.ingest import open_source
    from uavest.ingest.types import BaroSample, GnssSample

    p = shared_log("sample_px4_events.ulg")
    n = {"g": 0, "b": 0}
    last = -np.inf
    for m in open_source(p):
        assert m.t >= last
        last = m.t
        n["g"] += isinstance(m, GnssSample)
        n["b"] += isinstance(m, BaroSample)
    assert n == {"g": 437 + 23, "b": 62}


def test_a_px4_sitl_ulog_is_not_taken_for_an_ardupilot_sitl():
    from uavest.engine.navigation import sitl_evidence

    # both PX4 SITL logs carry SIM_BAT_DRAIN: PX4's battery simulator, not ArduPilot's
    for name in ("sample_logging_tagged_and_default_params.ulg", "sample_px4_events.ulg"):
        params = read_log(shared_log(name)).params
        assert "SIM_BAT_DRAIN" in params, name
        assert sitl_evidence(params) is None, name
