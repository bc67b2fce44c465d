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
