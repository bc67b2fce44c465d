"""Issue: ArduPilot logs DataFlash ``IMU`` as snapshots of the filtered gyro at the logging
rate; at 25 Hz uavest read them as interval averages (``hold``, its choice for any IMU at
20 Hz or more) and scored worse than ``--integration trapezoid``. The default must follow
what the message is (uavest/ingest/semantics.py, docs/ingest.md "IMU message semantics").

Reproduced from the shared test.BIN by writing a copy with every other ``IMU``/``IMU2``
record removed (45 Hz -> 22.6 Hz snapshots, as a 25 Hz logging rate gives), replayed with
the default, with ``--integration trapezoid`` and with ``--integration hold`` in the same
run: the default is trapezoid, no worse than it, and better than hold.
"""

from __future__ import annotations

import numpy as np
from conftest import shared_log

from tests.hostile.corpus import df_records
from uavest.apps.replay import ReplayConfig, replay
from uavest.cli import main
from uavest.ingest.semantics import default_integration

FILTERS = ("ekf", "ukf")


def _decimate(src, dst, keep_every: int = 2) -> int:
    """Copy of DataFlash log ``src`` keeping one ``IMU``/``IMU2`` record in ``keep_every``
    (per message name, i.e. per IMU instance); returns the IMU records kept."""
    data = src.read_bytes()
    out, last, seen, kept = bytearray(), 0, {}, 0
    for off, ln, name in df_records(data):
        if name in ("IMU", "IMU2", "IMU3"):
            k = seen[name] = seen.get(name, -1) + 1
            if k % keep_every:
                out += data[last:off]
                last = off + ln
            elif name == "IMU":
                kept += 1
    dst.write_bytes(bytes(out + data[last:]))
    return kept


def _mean_rmse(row: dict) -> float:
    return float(np.mean([row["roll_rmse_deg"], row["pitch_rmse_deg"], row["yaw_rmse_deg"]]))


def test_dataflash_imu_snapshots_default_to_trapezoid(tmp_path):
    f = tmp_path / "imu_25hz.bin"
    assert _decimate(shared_log("test.BIN"), f) > 15
    docs = {m: replay(f, ReplayConfig(filters=FILTERS, integration=m))
            for m in ("auto", "trapezoid", "hold")}
    auto = docs["auto"]
    assert 20.0 <= auto["imu_rate_hz"] < 25.5  # today's rate rule would say "hold"
    assert auto["integration"] == "trapezoid"
    assert auto["integration_why"] == "DataFlash IMU: filtered snapshots"
    for name in FILTERS:
        d, t, h = (_mean_rmse(docs[m]["filters"][name]) for m in ("auto", "trapezoid", "hold"))
        assert d <= t + 1e-9, (name, d, t)
        assert d < h, (name, d, h)


def test_the_choice_is_printed(tmp_path, capsys):
    f = tmp_path / "imu_25hz.bin"
    _decimate(shared_log("test.BIN"), f)
    assert main(["replay", str(f), "--filters", "ekf", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "integration: trapezoid (DataFlash IMU: filtered snapshots)" in out


def test_semantics_per_format():
    """Each format's IMU message and its default (the table of docs/ingest.md)."""
    assert default_integration("RAW_IMU", 4.0)[0] == "trapezoid"
    assert default_integration("SCALED_IMU2", 50.0)[0] == "trapezoid"
    assert default_integration("HIGHRES_IMU", 100.0)[0] == "trapezoid"
    assert default_integration("IMU[1]", 400.0) == ("trapezoid",
                                                     "DataFlash IMU: filtered snapshots")
    assert default_integration("IMT[0]", 400.0)[0] == "hold"
    assert default_integration("sensor_combined", 250.0)[0] == "hold"
    assert default_integration("sensor_combined[1]", 10.0)[0] == "hold"
    assert default_integration("somebody_elses_imu", 10.0)[0] == "trapezoid"
    assert default_integration("somebody_elses_imu", 100.0)[0] == "hold"
