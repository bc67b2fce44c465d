"""Issue 11, item 1: one corrupted time stamp is an outlier, counted, never reorders or
drops the rest; a real clock jump (concatenated log) is still a reset."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from uavest.ingest import open_source
from uavest.ingest.timebase import RxFilter
from uavest.ingest.types import IngestStats
from uavest.ingest.ulog import time_outliers

from . import corpus as C


def _read(path):
    s = open_source(path)
    items = [(type(m).__name__, m.source, m.t) for m in s]
    return items, s.stats


def _cut(logs, frac=0.15):
    d = (logs / "vtol.tlog").read_bytes()
    recs = C.tlog_records(d)
    return d[: recs[int(len(recs) * frac)][0]]


def test_rx_filter_repairs_one_outlier_and_keeps_a_real_step():
    st = IngestStats()
    rx = [1.0, 1.1, 1.2, 9e12, 1.3, 1.4, 1.5, 50.0, 50.1, 50.2, 50.3, 50.4]
    out = [r for _, r in RxFilter(st).filter((i, r) for i, r in enumerate(rx))]
    assert st.time_outlier == 1
    assert out[3] == 1.2  # replaced by the previous good receive time
    assert out[7:] == rx[7:]  # the step to 50 s is confirmed by the next messages


@pytest.mark.parametrize("msgid", [30, 178])  # ATTITUDE (timed), AHRS2 (untimed)
def test_tlog_top_bit_of_one_receive_time(tmp_path, logs, msgid):
    """Issue: one flipped top bit made 1547 messages late/time_backwards (yaw 3.68 -> 93.7)."""
    d = _cut(logs)
    clean, st0 = _read(_write(tmp_path / "c.tlog", d))
    bad, st = _read(_write(tmp_path / "b.tlog", C.flip_tlog_rx_top_bit(d, msgid, 20)))
    assert st.time_outlier == 1
    assert st.late == 0 and st.time_backwards == st0.time_backwards
    assert collections.Counter(x[:2] for x in bad) == collections.Counter(x[:2] for x in clean)
    timed = [x for x in clean if x[1] not in ("AHRS2", "SIMSTATE")]
    assert [x for x in bad if x[1] not in ("AHRS2", "SIMSTATE")] == timed


def test_concatenated_tlog_is_still_a_reset(tmp_path, logs):
    d = _cut(logs, 0.1)
    items, st = _read(_write(tmp_path / "cc.tlog", d + d))
    assert st.time_reset == 1 and st.time_outlier == 0
    t = [x[2] for x in items]
    assert np.all(np.diff(t) >= 0)


def test_time_outliers_flags_spikes_not_steps():
    t = np.arange(100) * 0.004
    spike = t.copy()
    spike[40] = 1e6
    spike[70] = -50.0
    assert np.flatnonzero(time_outliers(spike)).tolist() == [40, 70]
    step = np.concatenate([t, t[-1] + 100 + t])
    assert not time_outliers(step).any()


@pytest.mark.parametrize("value", ["top", "zero"])
def test_ulog_one_bad_timestamp_is_repaired(tmp_path, logs, value):
    """Issue: one bad ULog time stamp gave 'IMU at 0.0 Hz, 68720 s', 1669 samples dropped."""
    d = (logs / "sample_px4_events.ulg").read_bytes()
    ts = C.ulog_timestamp(d, "sensor_combined", 500)
    bad = C.ulog_set_timestamp(d, "sensor_combined", 500, ts | (1 << 62) if value == "top" else 0)
    clean, _ = _read(_write(tmp_path / "c.ulg", d))
    got, st = _read(_write(tmp_path / "b.ulg", bad))
    assert st.time_outlier >= 1 and st.time_backwards == 0
    n = collections.Counter(x[0] for x in got)
    assert n == collections.Counter(x[0] for x in clean)


def test_dataflash_one_bad_timeus_is_not_a_reboot(tmp_path, logs):
    d = (logs / "test.BIN").read_bytes()
    ts = C.df_time(d, "IMU", 20)
    for delta in (5_000_000, -5_000_000, 1 << 50):
        items, st = _read(_write(tmp_path / "b.bin", C.df_set_time(d, "IMU", 20, ts + delta)))
        assert st.time_reset == 0
        assert st.out_of_range + st.time_backwards == 1  # the one record, counted
        assert sum(x[0] == "ImuSample" for x in items) == 89  # of 90


def _write(p, data):
    p.write_bytes(data)
    return p


@pytest.mark.slow
def test_flipped_vtol_rmse_within_one_percent(tmp_path, logs):
    """Closing-note fact: top bit of one ATTITUDE receive time in vtol.tlog."""
    from uavest.apps.replay import ReplayConfig, replay

    d = (logs / "vtol.tlog").read_bytes()
    cfg = ReplayConfig(filters=("ekf",))
    a = replay(logs / "vtol.tlog", cfg)
    b = replay(_write(tmp_path / "f.tlog", C.flip_tlog_rx_top_bit(d, 30, 100)), cfg)
    assert b["bad_data"]["time_outlier"] == 1 and b["repaired"] == {"time_outlier": 1}
    for k in ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg"):
        assert b["filters"]["ekf"][k] == pytest.approx(a["filters"]["ekf"][k], rel=0.01)


@pytest.mark.slow
def test_light_byte_flips_within_10_percent_or_flagged(tmp_path, logs):
    """Issue: byte flips at 1e-4 wrecked a tlog replay silently (yaw 3.68 -> 93.7, exit 0)."""
    from uavest.apps.replay import ReplayConfig, replay

    from .cases import RMSE_ABS, RMSE_REL

    d = _cut(logs, 0.2)
    cfg = ReplayConfig(filters=("ekf",))
    a = replay(_write(tmp_path / "c.tlog", d), cfg)["filters"]["ekf"]
    for seed in (0, 2):
        doc = replay(_write(tmp_path / f"f{seed}.tlog", C.flip_bits(d, 1e-4, seed)), cfg)
        assert doc["bad_data"]["corrupt"] > 0  # counted
        if doc["unreliable"]:
            continue
        b = doc["filters"]["ekf"]
        for k in ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg"):
            assert abs(b[k] - a[k]) <= max(RMSE_REL * a[k], RMSE_ABS)
