"""A log that carries the vehicle's sensor spec (a ``uavest sim --params`` recording):
``uavest replay`` takes it where the options leave a value open, says so, and its
attitude covariance then matches its errors, which the IMU source's default profile's
does not (docs/navigation.md, "The vehicle's sensor spec")."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from uavest.apps.replay import ReplayConfig, replay
from uavest.scenarios import load_typed
from uavest.sim.sensors import spec_noise

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def sim_tlog(tmp_path_factory) -> Path:
    tlog = tmp_path_factory.mktemp("spec") / "sim40.tlog"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, "-m", "uavest.cli.sim", "sim_default", "--out", "none",
                    "--speed", "0", "--duration", "40", "--imu-rate", "200", "--seed", "2",
                    "--params", "--rate", "RAW_IMU=200", "--rate", "EXTRA1=50",
                    "--rate", "EXTENDED_STATUS=5", "--rate", "POSITION=10",
                    "--rate", "HIL_STATE_QUATERNION=50", "--rate", "RAW_SENSORS=10",
                    "--tlog", str(tlog), "--quiet"], env=env, check=True, timeout=300)
    return tlog


def _in95(doc: dict) -> float:
    return float(doc["filters"]["ekf"]["nees"]["attitude"]["in_band95"])


@pytest.mark.slow
def test_replay_takes_the_logs_sensor_spec_and_options_win(sim_tlog):
    spec = spec_noise(load_typed("sim_default"))
    doc = replay(sim_tlog, ReplayConfig(filters=("ekf",), model="auto"))
    assert doc["model"]["value"] == "nav"
    assert doc["sensor_spec"]["taken"] == pytest.approx({**spec, "gnss_delay": 0.0},
                                                         rel=1e-6)
    why = {d["what"]: d["why"] for d in doc["decisions"]}
    assert why["GNSS delay"] == "the vehicle's sensor spec (SPEC_GPS_DLY)"
    assert why["magnetometer noise"] == "the vehicle's sensor spec (SPEC_MAG_NSR)"
    assert why["GNSS bias states"].startswith("the vehicle's sensor spec (SPEC_GPS_SDH")
    # options over the spec: the IMU profile's gyro and magnetometer noise given back
    given = replay(sim_tlog, ReplayConfig(filters=("ekf",), model="auto",
                                          noise={"gyro_noise": 0.001, "mag_noise": 0.08}))
    assert set(given["sensor_spec"]["taken"]) == {"gnss_bias_h", "gnss_bias_v",
                                                  "gnss_bias_tau", "gnss_delay"}
    assert "option" in {d["what"]: d["why"] for d in given["decisions"]}[
        "magnetometer noise"]
    # the sensors' own noise: the attitude NEES in its band (0.99 when measured); the
    # profile's, wider than the simulator's sensors, leaves it below (0.60)
    assert _in95(doc) >= 0.8, _in95(doc)
    assert _in95(given) < _in95(doc) - 0.2, (_in95(given), _in95(doc))
