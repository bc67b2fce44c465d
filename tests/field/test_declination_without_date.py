"""Issue: a log with its declination parameter 0, automatic declination on and a GNSS fix
but no UTC time skipped the magnetic model and used declination 0 (yaw off by the whole
declination). With a fix and no GNSS date the model is taken at the log's own date (a
tlog's receive times), else at the model's epoch, and the output says so; never 0.

Reproduced from the shared logs by modification: sample_px4_events.ulg with
``EKF2_MAG_DECL`` 0 (``EKF2_DECL_TYPE`` 7: automatic) and every ``time_utc_usec`` zeroed
(rewritten with pyulog); vtol.tlog with every ``COMPASS_DEC`` 0 and no ``SYSTEM_TIME``
(its GPS_RAW_INT carry boot time, so the GNSS date is gone). The declination used must be
the model's value at the position and the true date within 0.5 deg.
"""

from __future__ import annotations

import math

import pytest
from conftest import shared_log

from tests.hostile.corpus import tlog_records
from uavest.apps.replay import ReplayConfig, replay
from uavest.cli import main
from uavest.ingest import open_source
from uavest.models.attitude import wmm_declination


def _true_model_value(path) -> float:
    """The model's declination (deg) at the unmodified log's first dated fix."""
    src = open_source(path)
    if hasattr(src, "prescan_geo"):
        src.prescan_geo()
    for _ in src:
        pass
    g = src.params.geo
    assert g is not None, "the unmodified log has a dated fix"
    return math.degrees(wmm_declination(g["lat"], g["lon"], g["alt"], g["utc"])[0])


def _ulog_without_utc(src, dst) -> None:
    from pyulog import ULog

    u = ULog(str(src))
    u.initial_parameters["EKF2_MAG_DECL"] = 0.0
    assert u.initial_parameters.get("EKF2_DECL_TYPE", 0) & 1  # automatic declination on
    n = 0
    for d in u.data_list:
        if "time_utc_usec" in d.data:
            d.data["time_utc_usec"][:] = 0
            n += 1
    assert n > 0
    u.write_ulog(str(dst))


def _tlog_without_utc(src, dst) -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    data = src.read_bytes()
    parser = mav.MAVLink(None)
    out, last, dec, st = bytearray(), 0, 0, 0
    for off, ln, mid in tlog_records(data):
        if mid not in (mav.MAVLINK_MSG_ID_SYSTEM_TIME, mav.MAVLINK_MSG_ID_PARAM_VALUE):
            continue
        out += data[last:off]
        last = off + ln
        if mid == mav.MAVLINK_MSG_ID_SYSTEM_TIME:
            st += 1
            continue  # dropped: no UNIX time in the log but the receive times
        m = parser.decode(bytearray(data[off + 8:off + ln]))
        if m.param_id == "COMPASS_DEC":
            m.param_value = 0.0
            dec += 1
        h = m.get_header()
        w = mav.MAVLink(None, srcSystem=h.srcSystem, srcComponent=h.srcComponent)
        w.seq = h.seq
        out += data[off:off + 8] + m.pack(w, force_mavlink1=data[off + 8] == 0xFE)
    out += data[last:]
    assert dec > 0 and st > 0
    dst.write_bytes(bytes(out))


@pytest.mark.slow
def test_ulog_fix_without_utc_uses_the_model_at_its_epoch(tmp_path, capsys):
    base = shared_log("sample_px4_events.ulg")
    f = tmp_path / "no_utc.ulg"
    _ulog_without_utc(base, f)
    truth = _true_model_value(base)
    doc = replay(f, ReplayConfig(filters=("ekf",)))
    assert doc["declination_rad"] is not None
    assert math.degrees(doc["declination_rad"]) == pytest.approx(truth, abs=0.5)
    assert "model's epoch" in doc["declination_source"]
    assert main(["replay", str(f), "--filters", "ekf", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "declination: " in out and "no date in the log: the model's epoch" in out


@pytest.mark.slow
def test_tlog_fix_without_utc_uses_the_receive_dates(tmp_path):
    base = shared_log("vtol.tlog")
    f = tmp_path / "no_utc.tlog"
    _tlog_without_utc(base, f)
    truth = _true_model_value(base)
    src = open_source(f)
    src.prescan_geo()
    for _ in src:
        pass
    assert src.params.get("COMPASS_DEC") == 0.0 and src.params.geo is None  # the defect
    doc = replay(f, ReplayConfig(filters=("ekf",)))
    assert math.degrees(doc["declination_rad"]) == pytest.approx(truth, abs=0.5)
    assert "receive times" in doc["declination_source"]
    assert "COMPASS_DEC = 0" in doc["declination_source"]


def test_a_fix_never_gives_zero(tmp_path):
    """Without any date the model's epoch is used; with one, that date."""
    from uavest.ingest.types import LogParams
    from uavest.models.attitude import declination_and_source

    p = LogParams({"COMPASS_DEC": 0.0})
    p.set_geo(-35.3632, 149.1652, 584.0, float("nan"))  # a fix, no date
    assert p.geo is None and p.fix is not None
    d, why = declination_and_source(p)
    assert d is not None and abs(math.degrees(d)) > 5 and "model's epoch" in why
    p.set_date(1_533_737_161.0, "test")
    d2, why2 = declination_and_source(p)
    assert "2018-08-08" in why2 and abs(math.degrees(d2 - d)) < 1.0
