"""Issue 20, "honest output": what the commands print says what it is."""

from __future__ import annotations

import time

import numpy as np

from uavest.core.gaussian import Gaussian
from uavest.engine.records import Start, Step
from uavest.engine.runner import WARMUP_STEPS, FilterRunner


class _SlowFirst:
    """A filter whose first predict pays a one-time cost (as numba compilation does)."""

    name = "slow_first"

    def __init__(self) -> None:
        self.calls = 0

    def init(self, prior, space, rng=None):
        return prior

    def predict(self, s, transition, t, dt, u, rng):
        self.calls += 1
        if self.calls == 1:
            time.sleep(0.2)
        return s

    def update(self, s, z, m, rng):
        return s, None

    def estimate(self, s):
        return s


def test_us_per_step_leaves_out_the_warm_up():
    r = FilterRunner("f", _SlowFirst(), np.random.default_rng(0), guard=False)
    r.start(Start(0.0, Gaussian(np.zeros(2), np.eye(2)), None))
    n = 50
    for k in range(1, n + 1):
        r.step(Step(k, 0.01 * k, 0.01, None))
    assert r.steps == n and r.timed_steps == n - WARMUP_STEPS
    assert r.seconds > 0.2  # the total still holds the first step
    assert r.us_per_step < 0.2e6 / n / 10  # the first step's 0.2 s is not in the mean


def test_demo_never_overwrites_a_default_recording_silently(tmp_path):
    from uavest.cli.record import recording_path

    d = tmp_path / "uavest-demo.mcap"
    assert recording_path(str(d), chosen=False) == (str(d), None)
    d.write_bytes(b"old")
    p, note = recording_path(str(d), chosen=False)
    assert p == str(tmp_path / "uavest-demo-1.mcap") and str(d) in note
    (tmp_path / "uavest-demo-1.mcap").write_bytes(b"old")
    assert recording_path(str(d), chosen=False)[0] == str(tmp_path / "uavest-demo-2.mcap")
    # a path the user chose: overwritten, with a warning naming it
    p, note = recording_path(str(d), chosen=True)
    assert p == str(d) and "overwriting" in note and str(d) in note


def test_live_status_line_fits_100_columns_with_the_widest_values():
    from uavest.apps.live import status_line

    names = ["GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "HIGHRES_IMU", "SCALED_IMU2",
             "SCALED_IMU3", "ATTITUDE_QUATERNION", "OBSTACLE_DISTANCE_3D", "ADSB_VEHICLE",
             "SIMSTATE", "SYSTEM_TIME", "RAW_IMU", "GPS_RAW_INT"]
    wide = {n: 99999.0 for n in names}
    filters = {f"hybrid(n_cloud={k})": 123456 for k in range(6)}
    nis = {k: 1.2e6 for k in filters}
    for rates, res in ((wide, filters), ({"RAW_IMU": 200.0}, {"ekf": 0}), ({}, {})):
        line = status_line(rates, 10**9, nis, res, 99999.9)
        assert len(line) == 99, (len(line), line)  # padded: the rewrite clears the old one
    small = status_line({"RAW_IMU": 200.0}, 0, {"ekf": 1.5}, {"ekf": 0}, 3.2)
    assert "RAW_IMU 200" in small and "ekf:1.5/0" in small and "p99 3.2 ms" in small
    mid = status_line(wide, 3, {"ekf": 1.5, "ukf": 2.0}, {"ekf": 0, "ukf": 1}, 3.2)
    assert "ekf:1.5/0" in mid and "ukf:2.0/1" in mid  # the filters kept, rates shortened


def test_line_progress_off_a_terminal(capsys):
    from uavest.cli.progress import LineProgress

    quick = LineProgress(3, "evaluate", after=60.0)
    quick.update(1)
    quick.set_description("stage")
    quick.close()
    assert capsys.readouterr().err == ""  # a quick run prints nothing
    p = LineProgress(3, "evaluate", after=0.0, every=60.0)
    p.set_postfix_str("done 1")
    p.update(1)
    p.update(1)  # within ``every``: no line
    p.set_description("report: writing")  # a stage: always a line
    p.close()
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 3, lines
    assert lines[0].startswith("evaluate: 1/3, done 1 (")
    assert lines[1].startswith("report: writing: 2/3") and lines[2] == lines[1]


def test_report_prints_one_line_per_stage_when_not_a_terminal(tmp_path, capsys, monkeypatch):
    from conftest import shared_log

    import uavest.cli.progress as rep
    from uavest.cli import main

    monkeypatch.setattr(rep, "PROGRESS_AFTER_S", 0.0)
    m = tmp_path / "run.mcap"
    assert main(["replay", str(shared_log("vtol.tlog")), "--filters", "ekf", "--no-progress",
                 "--end", "660", "--mcap", str(m)]) == 0
    capsys.readouterr()
    assert main(["report", str(m), "--out", str(tmp_path / "rep")]) == 0
    err = capsys.readouterr().err
    assert "reading run.mcap" in err and "attitude: metrics and figures" in err
    assert "writing HTML and Markdown" in err
