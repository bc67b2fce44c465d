"""The live job says when a gyro bias ramps, as a replay does: the built-in simulator's
IMU with a drifting gyro (``imu.gyro_drift``, as an ArduPilot SITL's SIM_DRIFT_SPEED),
the flight's tlog through the live job (:func:`uavest.apps.live.run_samples`, ``uavest
run --connect FILE --model nav``). That a bias which only wanders is not called a ramp is
the replay's test (tests/field/test_nav_replay.py, logs/sim_200hz.tlog) and the trend's
(tests/unit/test_nav_stream.py): the same sink and function."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.apps.live import LiveConfig, run_samples
from uavest.cli.run import format_live
from uavest.ingest import open_source
from uavest.scenarios import load_typed
from uavest.sim import Simulator

#: rad/s^2 (0.34 deg/s per minute): a ramp a 60-s flight's bias estimate shows on every
#: axis (the SITL's 1.45e-5 needs the SITL's 150 s)
DRIFT = 1e-4


def _live(tmp_path, drift: float) -> dict:
    """A 60-s flight of the simulator (seed 2, IMU at 100 Hz), its tlog through the live
    job with the navigation EKF: the result document."""
    sc = load_typed("sim_default", [f"imu.gyro_drift={drift}"])
    sim = Simulator(sc, seed=2, imu_rate=100.0, rates={
        "RAW_IMU": 100, "SIMSTATE": 50, "GPS_RAW_INT": 5, "SCALED_PRESSURE": 10})
    path = tmp_path / f"drift_{drift:g}.tlog"
    assert sim.run(None, duration=60.0, speed=0, tlog=path).reason == "duration"
    cfg = LiveConfig(connect=str(path), model="nav", filters=("ekf",), trackers=())
    src = open_source(path, reorder_window=cfg.reorder_window)
    return run_samples(src, cfg, params=src.params, status=False, sinks=[], stats=src.stats)


@pytest.mark.slow
def test_the_live_job_says_a_ramping_gyro_bias(tmp_path):
    """With the drift the first filter's bias estimate is a line on every axis, rising at
    about the drift's rate (a random-walk bias lags it: 0.4-1.0 of it), and the run's
    summary names the option that models it; a result whose filter had the drift states
    (a ``gyro_drift`` row) does not repeat it."""
    doc = _live(tmp_path, DRIFT)
    tr = doc["gyro_bias_trend"]
    assert tr["filter"] == "ekf" and tr["ramps"], tr
    rate = np.radians(tr["deg_s_per_min"]) / 60.0  # rad/s^2
    assert np.all((rate > 0.4 * DRIFT) & (rate < 1.0 * DRIFT)), tr
    hint = [ln for ln in format_live(doc).splitlines() if ln.startswith("gyro bias: ramps")]
    assert len(hint) == 1 and "--noise gyro_drift_walk=" in hint[0], hint
    doc["attitude"]["ekf"]["gyro_drift"] = {"deg_s_per_min": [0.3] * 3,
                                            "sd_deg_s_per_min": [0.01] * 3}
    assert "gyro bias: ramps" not in format_live(doc)
