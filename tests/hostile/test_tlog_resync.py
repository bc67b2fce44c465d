"""A tlog that holds records which are not MAVLink (issue 20): the SITL's console text as
one-byte records before the first frame, or a cut frame and stray bytes mid-file. The
reader must find its way back to the frames and lose no RAW_IMU, as pymavlink does."""

from __future__ import annotations

import struct

import pytest
from conftest import shared_log
from pymavlink import mavutil

from uavest.ingest import read_log

BANNER = (b"Init ArduCopter V4.7.0-dev (90700977)\n"
          b"Free RAM: 65535\nFirmware: ArduCopter V4.7.0-dev\n")


def _records(data: bytes) -> list[bytes]:
    """Split a clean tlog into its records (8-byte time + one MAVLink frame)."""
    out, o = [], 0
    while o + 10 <= len(data):
        mk = data[o + 8]
        if mk == 0xFD:
            n = 8 + 10 + data[o + 9] + 2 + (13 if data[o + 10] & 1 else 0)
        else:
            assert mk == 0xFE, f"not a clean tlog at {o}"
            n = 8 + 6 + data[o + 9] + 2
        out.append(data[o:o + n])
        o += n
    return out


def _raw_imu(path) -> int:
    return read_log(path).stats.messages["RAW_IMU"]


def _pymavlink_raw_imu(path) -> int:
    conn = mavutil.mavlink_connection(str(path))
    n = 0
    try:
        while conn.recv_match(type="RAW_IMU") is not None:
            n += 1
    finally:
        conn.close()
    return n


def test_console_text_before_the_first_frame(tmp_path):
    orig = shared_log("vtol.tlog")
    data = orig.read_bytes()
    t0 = struct.unpack(">Q", data[:8])[0]
    text = (BANNER * 4)[:150]
    banner = b"".join(struct.pack(">Q", t0 - 150_000 + 1000 * i) + text[i:i + 1]
                      for i in range(150))
    bad = tmp_path / "banner.tlog"
    bad.write_bytes(banner + data)
    want = _raw_imu(orig)
    log = read_log(bad)
    assert log.stats.messages["RAW_IMU"] == want > 700
    assert log.stats.messages["RAW_IMU"] >= _pymavlink_raw_imu(bad)
    assert log.stats.non_mavlink == 150  # the text is counted, not taken for corruption
    assert log.stats.corrupt == 0


@pytest.mark.parametrize("where", ["start", "middle"])
def test_cut_frame_and_stray_bytes(tmp_path, where):
    # before the first frame the former reader decoded nothing; mid-file pymavlink's own
    # robust parsing already recovered (kept here so that the resync does not break it)
    orig = shared_log("vtol.tlog")
    recs = _records(orig.read_bytes())
    k = 0 if where == "start" else len(recs) // 2
    ts = recs[k][:8]
    junk = ts + recs[k + 1][8:20]  # a frame cut after 12 bytes
    junk += b"".join(ts + bytes((b,)) for b in (0x00, 0xFE, 0x07, 0xFD, 0x80))
    bad = tmp_path / "junk.tlog"
    bad.write_bytes(b"".join(recs[:k]) + junk + b"".join(recs[k:]))
    want = _raw_imu(orig)
    log = read_log(bad)
    assert log.stats.messages["RAW_IMU"] == want
    assert log.stats.messages["RAW_IMU"] >= _pymavlink_raw_imu(bad)
    assert log.stats.corrupt >= 1  # the junk is counted
