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


def _after_each_raw_imu(src, dst, make) -> int:
    """Copy the tlog ``src`` to ``dst`` with the message ``make(mav, n)`` after the n-th
    RAW_IMU record (same receive time, as the autopilot sends its instances)."""
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
            out += struct.pack(">Q", t_us) + make(mav, n).pack(m)
        last = off + ln
    out += data[last:]
    dst.write_bytes(bytes(out))
    return n


def _zero_imu3(src, dst, with_real: bool = False) -> int:
    def make(mav, n):
        if with_real and 200 < n <= 400:
            return mav.MAVLink_scaled_imu3_message(n, 0, 0, 1000, 1, 1, 1, 0, 0, 0)
        return mav.MAVLink_scaled_imu3_message(n, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    return _after_each_raw_imu(src, dst, make)


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


def _imu3_mag(src, dst, mag_mgauss: int, good_from: int = 0, good_to: int = 0) -> int:
    """A SCALED_IMU3 after every RAW_IMU: no IMU (zeros) and a magnetometer field of
    ``mag_mgauss`` on each axis (in range for the records ``good_from`` < n <= ``good_to``:
    500 mG)."""
    def make(mav, n):
        f = 500 if good_from < n <= good_to else mag_mgauss
        return mav.MAVLink_scaled_imu3_message(n, 0, 0, 0, 0, 0, 0, f, f, f)
    return _after_each_raw_imu(src, dst, make)


@pytest.mark.slow
def test_a_magnetometer_never_in_range_is_unusable_not_bad_data(tmp_path, capsys):
    """The ArduCopter SITL sends HIGHRES_IMU's field 10^6 too large: every reading of
    that instance out of range. Found replaying a live SITL session's tlog: 'UNRELIABLE:
    48 % of the log's records were bad' while the records' IMU part was used. Such an
    instance is named on one line and ignored; a field that was in range and then goes
    out of it is still bad data."""
    base = shared_log("vtol.tlog")
    f = tmp_path / "imu3_mag_x1000.tlog"
    n = _imu3_mag(base, f, 30000)  # 30 G per axis: out of range (|B| <= 10 G)
    clean, st = _stats(base), _stats(f)
    assert st.unusable_sensor == n > 500
    assert st.bad_total == clean.bad_total
    assert main(["replay", str(f), "--filters", "ekf", "--model", "attitude",
                 "--no-progress"]) == 0
    text = "".join(capsys.readouterr())
    assert "UNRELIABLE" not in text
    assert "unusable sensors" in text and "SCALED_IMU3" in text
    g = tmp_path / "imu3_mag_good_then_bad.tlog"
    _imu3_mag(base, g, 30000, good_from=200, good_to=400)
    st = _stats(g)
    assert st.unusable_sensor == 200
    assert st.out_of_range - clean.out_of_range == n - 400
