"""Timestamps and bad data on synthetic .tlog files written in tmp_path.

A tlog is a sequence of records: 8-byte big-endian receive time in microseconds
followed by one packed MAVLink frame.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from pymavlink import mavutil

from uavest.ingest import AttitudeRef, ImuSample, IngestError, open_source, read_log

ml = mavutil.mavlink
T0_UNIX = 1_700_000_000.0


class TlogWriter:
    def __init__(self, path):
        self.path = path
        self.f = open(path, "wb")  # noqa: SIM115
        self.mav = ml.MAVLink(None, srcSystem=1, srcComponent=1)

    def write(self, msg, rx: float) -> None:
        self.f.write(struct.pack(">Q", int(rx * 1e6)) + msg.pack(self.mav))

    def close(self):
        self.f.close()


#: the gyro x of :func:`scaled`'s default count, 100 mrad/s, as read: the middle of its
#: unit (the senders truncate towards zero; docs/ingest.md)
GX = 0.1005
AZ = -1000.5 * 9.80665e-3  # -1000 milli-g: (-1001, -1000], its middle


def scaled(t_ms: int, gx: float = 100):
    return ml.MAVLink_scaled_imu_message(t_ms, 0, 0, -1000, int(gx), 0, 0, 200, 0, 400)


def attitude(t_ms: int, roll: float = 0.1):
    return ml.MAVLink_attitude_message(t_ms, roll, 0.0, 0.5, 0, 0, 0)


def write_steady(path, n=50, t0_ms=10_000, dt_ms=20):
    w = TlogWriter(path)
    for i in range(n):
        t = t0_ms + i * dt_ms
        rx = T0_UNIX + t * 1e-3
        w.write(scaled(t), rx)
        w.write(attitude(t), rx + 0.001)
        w.write(ml.MAVLink_simstate_message(0.1, 0, 0.5, 0, 0, -9.8, 0, 0, 0, 0, 0), rx + 0.002)
    w.close()


def test_steady_synthetic_log(tmp_path):
    p = tmp_path / "steady.tlog"
    write_steady(p)
    log = read_log(p)
    assert log.format == "tlog" and log.imu.source == "SCALED_IMU"
    assert len(log.imu) == 50
    np.testing.assert_allclose(log.imu.t, 10.0 + 0.02 * np.arange(50))
    # 100 mrad/s in SCALED_IMU's int16: [100, 101) mrad/s, read as its middle
    np.testing.assert_allclose(log.imu.gyro[0], [GX, 0, 0])
    np.testing.assert_allclose(log.imu.accel[0], [0, 0, AZ])
    np.testing.assert_allclose(log.mag.field[0], [0.2005, 0, 0.4005])
    assert log.imu_rate_hz == pytest.approx(50.0)
    sim = log.references["SIMSTATE"]
    assert sim.kind == "truth" and len(sim) == 50
    # SIMSTATE has no time field: latest vehicle time + 1 ms of receive time since then
    np.testing.assert_allclose(sim.t, log.references["ATTITUDE"].t + 0.001, atol=1e-6)
    assert log.stats.bad_total == 0


def test_duplicates_backwards_nan_out_of_range_are_counted_and_skipped(tmp_path):
    p = tmp_path / "bad.tlog"
    w = TlogWriter(p)
    for i in range(40):
        t = 10_000 + 20 * i
        rx = T0_UNIX + t * 1e-3
        w.write(scaled(t), rx)
        if i == 10:
            w.write(scaled(t), rx + 0.001)  # exact duplicate
        if i == 20:
            w.write(scaled(t - 500, gx=7), rx + 0.001)  # half a second back in time
        if i == 25:
            w.write(scaled(t, gx=5), rx + 0.001)  # same time, different content
        w.write(attitude(t, roll=float("nan") if i in (5, 6) else 0.1), rx + 0.002)
        if i == 30:
            w.write(
                ml.MAVLink_scaled_imu_message(t + 1, 0, 0, -1000, 32000, 32000, 0, 0, 0, 0),
                rx + 0.003,
            )
    w.close()
    log = read_log(p)
    st = log.stats
    assert st.duplicate == 1
    assert st.rejected["time_backwards:SCALED_IMU"] == 2
    assert st.nan == 2 and st.rejected["nan:ATTITUDE"] == 2
    assert st.out_of_range == 1
    assert len(log.imu) == 40 and np.all(np.diff(log.imu.t) > 0)
    # the bad ones (gx 7 and 5 mrad/s, the 32 g sample) did not get in: every kept sample
    # is a good one, at its own time
    np.testing.assert_allclose(log.imu.t, 10.0 + 0.02 * np.arange(40))
    np.testing.assert_allclose(log.imu.gyro, np.tile([GX, 0.0, 0.0], (40, 1)))
    np.testing.assert_allclose(log.imu.accel, np.tile([0.0, 0.0, AZ], (40, 1)))
    assert len(log.references["ATTITUDE"]) == 38


def test_reboot_is_a_reset_not_a_discard(tmp_path):
    p = tmp_path / "reboot.tlog"
    w = TlogWriter(p)
    for i in range(30):  # 100 s .. 100.58 s since boot
        t = 100_000 + 20 * i
        w.write(scaled(t), T0_UNIX + i * 0.02)
    for i in range(30):  # reboot: 0.5 s .. since boot, 5 s later in receive time
        t = 500 + 20 * i
        w.write(scaled(t), T0_UNIX + 5.6 + i * 0.02)
    w.close()
    log = read_log(p)
    assert log.stats.time_reset == 1
    assert len(log.imu) == 60
    assert np.all(np.diff(log.imu.t) > 0)
    # the gap across the reboot follows the receive-time gap
    assert np.diff(log.imu.t)[29] == pytest.approx(5.6 - 0.58, abs=1e-6)


def test_single_glitch_backwards_is_not_a_reset(tmp_path):
    p = tmp_path / "glitch.tlog"
    w = TlogWriter(p)
    for i in range(30):
        t = 100_000 + 20 * i
        w.write(scaled(t), T0_UNIX + i * 0.02)
        if i == 10:
            w.write(scaled(5), T0_UNIX + i * 0.02 + 0.001)
    w.close()
    log = read_log(p)
    assert log.stats.time_reset == 0
    assert log.stats.time_backwards == 1
    assert len(log.imu) == 30


def test_time_boot_ms_wrap(tmp_path):
    p = tmp_path / "wrap.tlog"
    w = TlogWriter(p)
    start = 2**32 - 200
    for i in range(20):
        t = (start + 20 * i) % 2**32
        w.write(scaled(t), T0_UNIX + i * 0.02)
    w.close()
    log = read_log(p)
    assert log.stats.time_wrap == 1 and log.stats.time_reset == 0
    assert len(log.imu) == 20
    np.testing.assert_allclose(np.diff(log.imu.t), 0.02, atol=1e-6)


def test_stream_is_time_ordered_and_typed(tmp_path):
    p = tmp_path / "steady.tlog"
    write_steady(p, n=20)
    src = open_source(p)
    items = list(src)
    assert src.format == "tlog"
    ts = [m.t for m in items]
    assert ts == sorted(ts)
    assert sum(isinstance(m, ImuSample) for m in items) == 20
    refs = [m for m in items if isinstance(m, AttitudeRef)]
    assert {r.kind for r in refs} == {"truth", "autopilot"}
    assert all(abs(np.linalg.norm(r.q) - 1) < 1e-12 for r in refs)
    assert src.stats.accepted["SCALED_IMU"] == 20


def test_params_and_imu_selection(tmp_path):
    p = tmp_path / "params.tlog"
    w = TlogWriter(p)
    w.write(ml.MAVLink_param_value_message(b"COMPASS_DEC", 0.2074, 9, 2, 0), T0_UNIX)
    for i in range(10):
        t = 1000 + 20 * i
        w.write(scaled(t), T0_UNIX + i * 0.02)
        w.write(ml.MAVLink_scaled_imu2_message(t, 0, 0, -1000, 0, 0, 0, 0, 0, 0), T0_UNIX)
    w.close()
    log = read_log(p, imu="SCALED_IMU2")
    assert log.params["COMPASS_DEC"] == pytest.approx(0.2074, rel=1e-6)
    assert log.imu.source == "SCALED_IMU2" and log.imu.instance == 1
    assert log.imu_sources == {"SCALED_IMU": 10, "SCALED_IMU2": 10}
    assert read_log(p).imu.source == "SCALED_IMU"  # tie: primary instance
    with pytest.raises(IngestError, match="not in log"):
        read_log(p, imu="IMU[3]")
    clipped = read_log(p, start=1.05, end=1.1)
    np.testing.assert_allclose(clipped.imu.t, [1.06, 1.08, 1.1])
    assert math.isclose(clipped.duration, 0.04)


def test_two_messages_back_in_time_are_not_a_reboot(tmp_path):
    # a reboot needs CONFIRM = 3 consistent messages; the IMU and mag parts of one
    # SCALED_IMU message must count once, not twice
    p = tmp_path / "two_back.tlog"
    w = TlogWriter(p)
    for i in range(30):
        t = 100_000 + 20 * i
        w.write(scaled(t), T0_UNIX + i * 0.02)
    for i in range(2):  # two messages "since boot 0.5 s", then the old clock goes on
        w.write(scaled(500 + 20 * i, gx=7), T0_UNIX + 0.6 + i * 0.02)
    for i in range(30):
        t = 100_640 + 20 * i
        w.write(scaled(t), T0_UNIX + 0.64 + i * 0.02)
    w.close()
    log = read_log(p)
    assert log.stats.time_reset == 0
    assert log.stats.rejected["time_backwards:SCALED_IMU"] == 2
    assert len(log.imu) == 60 and len(log.mag) == 60
    np.testing.assert_allclose(log.imu.gyro[:, 0], GX)


@pytest.mark.parametrize("byte,value", [(4, 0xFD), (4, 0xFE), (3, 0xFD), (2, 0xFE)])
def test_record_times_holding_a_frame_marker_are_still_a_tlog(tmp_path, byte, value):
    """A tlog's record times share their high bytes for minutes to days (byte 4 of a UNIX
    time in us changes every 16.8 s, byte 3 every 71.6 min): when one of them is a MAVLink
    frame marker (0xFD, 0xFE), a stream parser that starts at the file's first byte takes
    every record time for a frame start and swallows the real frame behind it. The
    format check must frame records as the reader does (it failed 3 live-link tests in CI
    that ran during such 16.8 s)."""
    b = bytearray(struct.pack(">Q", int(T0_UNIX * 1e6)))
    b[byte] = value
    t0 = struct.unpack(">Q", bytes(b))[0] * 1e-6
    p = tmp_path / "marker_times.tlog"
    w = TlogWriter(p)
    for i in range(40):
        t = 10_000 + 20 * i
        w.write(scaled(t), t0 + i * 1e-4)  # 4 ms in all: the marker byte stays put
    w.close()
    data = p.read_bytes()
    rec = len(data) // 40  # every record the same size
    assert all(data[k * rec + byte] == value for k in range(40))  # in every record time
    log = read_log(p)
    assert log.format == "tlog" and len(log.imu) == 40


def test_a_program_that_imported_mavutil_first_reads_mavlink2_messages(tmp_path):
    """pymavlink's mavutil picks its process-wide dialect once, when first imported, and
    it is MAVLink 1 unless MAVLINK20 was set then. A program (or a test) that imported
    mavutil before uavest made the tlog reader decode with that dialect: every message id
    above 255 (OBSTACLE_DISTANCE_3D) and every extension field (GPS_RAW_INT's h_acc) was
    lost without a word. Run in a fresh interpreter, so the import order is real."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from pymavlink.dialects.v20 import ardupilotmega as m2

    root = Path(__file__).resolve().parents[2]
    p = tmp_path / "v2.tlog"
    mav = m2.MAVLink(None, srcSystem=1, srcComponent=1)
    with open(p, "wb") as f:
        for i in range(20):
            t = 10_000 + 100 * i
            rx = int((T0_UNIX + t * 1e-3) * 1e6)
            gps = m2.MAVLink_gps_raw_int_message(
                t * 1000, 3, 473977000, 85456000, 408000, 80, 120, 500, 9000, 12,
                0, 1500, 2500, 300, 900, 0)
            imu = m2.MAVLink_scaled_imu_message(t, 0, 0, -1000, 100, 0, 0, 200, 0, 400)
            for m in (imu, gps):
                f.write(struct.pack(">Q", rx) + m.pack(mav))
    code = (
        "from pymavlink import mavutil\n"  # before uavest, MAVLINK20 unset
        "from uavest.ingest import open_source\n"
        f"g = [s for s in open_source({str(p)!r}) if type(s).__name__ == 'GnssSample']\n"
        "print(len(g), sum(s.h_acc == s.h_acc for s in g))\n")
    env = {k: v for k, v in os.environ.items() if k != "MAVLINK20"}
    env["PYTHONPATH"] = str(root) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=60, check=True).stdout.split()
    assert out == ["20", "20"], out  # every fix read, with its receiver accuracy
