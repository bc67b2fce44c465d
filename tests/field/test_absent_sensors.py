"""Issue: ArduPilot sends an all-zero SCALED_IMU3 when there is no third IMU. Those records
are a sensor that is not fitted, not bad data: counted apart, named on one info line, and no
UNRELIABLE warning. Reproduced from the shared vtol.tlog by inserting one zero SCALED_IMU3
after every RAW_IMU record (same receive time), as the autopilot does."""

from __future__ import annotations

import struct

import pytest
from conftest import shared_log

from tests.hostile.corpus import tlog_records
from uavest.cli import main
from uavest.ingest import open_source


def _zero_imu3(src, dst, with_real: bool = False) -> int:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    data = src.read_bytes()
    out, n, last = bytearray(), 0, 0
    for off, ln, mid in tlog_records(data):
        rec = data[off:off + ln]
        out += rec
        if mid == 27:  # RAW_IMU
            (t_us,) = struct.unpack(">Q", rec[:8])
            n += 1
            if with_real and 200 < n <= 400:
                msg = mav.MAVLink_scaled_imu3_message(n, 0, 0, 1000, 1, 1, 1, 0, 0, 0)
            else:
                msg = mav.MAVLink_scaled_imu3_message(n, 0, 0, 0, 0, 0, 0, 0, 0, 0)
            out += struct.pack(">Q", t_us) + msg.pack(m)
        last = off + ln
    out += data[last:]
    dst.write_bytes(bytes(out))
    return n


def _stats(path):
    src = open_source(path)
    for _ in src:
        pass
    return src.stats


@pytest.mark.slow
def test_zero_imu_instance_is_an_absent_sensor_not_bad_data(tmp_path, capsys):
    base = shared_log("vtol.tlog")
    f = tmp_path / "zero_imu3.tlog"
    n = _zero_imu3(base, f)
    clean, st = _stats(base), _stats(f)
    assert st.absent_sensor == n > 500
    assert st.bad_total == clean.bad_total  # not one zero record counted as bad
    assert main(["replay", str(f), "--filters", "ekf", "--no-progress"]) == 0
    out = capsys.readouterr()
    text = out.out + out.err
    assert "UNRELIABLE" not in text
    assert "absent sensors" in text and "SCALED_IMU3" in text


@pytest.mark.slow
def test_zeros_after_real_data_are_still_bad(tmp_path):
    """An instance that sent real data and then zeros is a fault: the zeros before its
    first real record are "not fitted", the ones after are counted as bad (empty)."""
    base = shared_log("vtol.tlog")
    g = tmp_path / "imu3_zero_real_zero.tlog"
    n = _zero_imu3(base, g, with_real=True)
    st, clean = _stats(g), _stats(base)
    assert st.absent_sensor == 200
    assert st.empty - clean.empty == n - 400
