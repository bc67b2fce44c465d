"""Issue: every decision made from the start of the log is made when the evidence arrives.
The IMU was chosen from the first 2 s only: a log whose chosen IMU stops (a sensor
failure, a logging rate change) while another IMU keeps delivering left every filter
without steps from then on, silently. The choice is now re-decided: the other IMU takes
over once the chosen one is silent beyond the gap threshold, with a decision line, and
the filters re-align on it. Reproduced from the shared vtol.tlog by dropping every RAW_IMU
record after 100 s (SCALED_IMU2 continues)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import shared_log

from tests.field.test_imu_gap import _errors
from tests.hostile.corpus import drop_tlog_records
from uavest.cli import main

RAW_IMU = 27


def drop_after(src, dst, msgid: int, at: float) -> int:
    """Write ``src`` to ``dst`` without the ``msgid`` records received ``at`` s or more
    after the first record. Returns how many were dropped."""
    return drop_tlog_records(src, dst, (msgid,), at)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["attitude", "auto"])  # auto: vtol.tlog runs nav
def test_the_imu_choice_is_re_decided_when_the_chosen_imu_stops(tmp_path, capsys, model):
    f = tmp_path / "raw_imu_stops.tlog"
    assert drop_after(shared_log("vtol.tlog"), f, RAW_IMU, 100.0) > 300
    doc, err, times = _errors(f, model=model)
    assert doc["model"]["value"] == ("attitude" if model == "attitude" else "nav")
    sw = doc["imu_switches"]
    assert [(s["from"], s["to"]) for s in sw] == [("RAW_IMU", "SCALED_IMU2")]
    t_sw = sw[0]["t"]
    assert doc["imu_source"] == "RAW_IMU"  # the first choice stays on record
    dec = [d for d in doc["decisions"] if d["what"] == "IMU"]
    assert len(dec) == 2 and dec[1]["value"] == "SCALED_IMU2" and "silent" in dec[1]["why"]
    for name, (t, e) in err.items():
        # steps continue to the end of the log (before: none after the RAW_IMU stopped)
        assert times[name][-1] > t_sw + 90.0, name
        before = e[(t > t_sw - 60) & (t <= t_sw - 1)]
        after = e[(t > t_sw + 5) & (t <= t_sw + 65)]
        rms_b, rms_a = np.sqrt(np.mean(before**2)), np.sqrt(np.mean(after**2))
        # the navigation hybrid re-aligns to 2.2x its error before (3.6 -> 7.8 deg; the EKF
        # and UKF 1.5x): a known shortfall, bounded here at 3x, not hidden
        k = 3.0 if (model == "auto" and name == "hybrid") else 2.0
        assert np.isfinite(rms_a) and rms_a < max(k * rms_b, 3.0), (name, rms_b, rms_a)
    capsys.readouterr()
    assert main(["replay", str(f), "--filters", "ekf", "--model", model,
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "decision: IMU: SCALED_IMU2 from t=" in out and "RAW_IMU silent since" in out


def test_an_imu_given_with_the_option_is_never_switched(tmp_path, capsys):
    f = tmp_path / "raw_imu_stops.tlog"
    drop_after(shared_log("vtol.tlog"), f, RAW_IMU, 100.0)
    j = tmp_path / "r.json"
    assert main(["replay", str(f), "--filters", "ekf", "--imu", "RAW_IMU", "--no-progress",
                 "--model", "attitude", "--json", str(j)]) == 0
    out = capsys.readouterr().out
    assert "decision: IMU: RAW_IMU" in out and "SCALED_IMU2 from t=" not in out
    assert json.loads(j.read_text())["imu_switches"] == []
