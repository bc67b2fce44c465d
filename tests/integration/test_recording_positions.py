"""A recording whose positions carry only lat/lon/alt (a live link's GLOBAL_POSITION_INT)
still has a trajectory in the report: the fixes in the local tangent plane (NED, m) at
the first fix."""

import json

import numpy as np
import pytest

from uavest.engine.records import RunInfo, StepRecord
from uavest.geometry.geodesy import LocalFrame
from uavest.ingest.types import AttitudeRef, PositionSample
from uavest.report import read_recording, write_report
from uavest.report.build import ATTITUDE_FIGURES, attitude_data, lla_to_local_ned
from uavest.sinks.mcap import McapSink


def _lla_run(path, with_ned: bool = False):
    origin = LocalFrame(47.397, 8.545, 488.0)
    t = np.arange(1, 201) * 0.1
    ned = np.stack([300 * np.sin(0.05 * t), 300 * (1 - np.cos(0.05 * t)), -20 * t / t[-1]],
                   axis=1)  # a 300 m arc, climbing 20 m
    lat, lon, h = origin.ned_to_geodetic(ned)
    sink = McapSink(path)
    sink.open(RunInfo("test", "synthetic", 0, filters={"ekf": {}}))
    sink.start("ekf", 0.0, np.zeros(7), np.eye(6))
    q = np.array([1.0, 0, 0, 0])
    for k, tk in enumerate(t, start=1):
        sink.sample(AttitudeRef(tk, q, "truth", "SIMSTATE"))
        sink.sample(PositionSample(tk, ned[k - 1] if with_ned else None, None,
                                   np.array([lat[k - 1], lon[k - 1], h[k - 1]]),
                                   "GLOBAL_POSITION_INT"))
        sink.record(StepRecord("ekf", k, tk, np.array([1.0, 0, 0, 0, 0, 0, 0]),
                               np.eye(6) * 1e-4))
    sink.close()
    return ned


@pytest.mark.slow
def test_lla_only_positions_give_a_local_ned_trajectory(tmp_path):
    path = tmp_path / "lla.mcap"
    ned = _lla_run(path)
    rec = read_recording(path)
    pos = rec.json["/position/GLOBAL_POSITION_INT"]
    assert all("ned_m" not in m and len(m["lat_lon_alt"]) == 3 for m in pos)
    data = attitude_data(rec)
    (src, (t, got)), = data["positions"].items()
    assert src == "GLOBAL_POSITION_INT (lat/lon/alt)" and len(t) == 200
    np.testing.assert_allclose(got[0], 0.0, atol=1e-9)
    # the first fix is the origin: the same NED as the truth relative to its first point
    # (exact tangent plane; the lat/lon/alt went through the JSON exactly)
    origin = LocalFrame(*pos[0]["lat_lon_alt"])
    np.testing.assert_allclose(got, origin.geodetic_to_ned(*np.array(
        [m["lat_lon_alt"] for m in pos]).T), atol=1e-9)
    # a 300 m flight: the tangent plane at the first fix vs the one at the original origin
    # differ by less than a few cm
    np.testing.assert_allclose(got, ned - ned[0], atol=0.05)
    paths = write_report(path, tmp_path / "rep")
    page = paths["html"].read_text()
    assert "local tangent plane at the first fix" in paths["markdown"].read_text()
    assert json.loads(paths["metrics"].read_text())["kind"] == "attitude"
    assert all(f"id='{f}'" in page for f in ATTITUDE_FIGURES)
    assert "no position in this recording" not in page


def test_a_local_ned_position_wins_over_lat_lon_alt(tmp_path):
    path = tmp_path / "ned.mcap"
    ned = _lla_run(path, with_ned=True)
    data = attitude_data(read_recording(path))
    (src, (_, got)), = data["positions"].items()
    assert src == "GLOBAL_POSITION_INT"
    np.testing.assert_array_equal(got, ned)


def test_lla_to_local_ned_small_cases():
    assert lla_to_local_ned(np.zeros((0, 3))).shape == (0, 3)
    # 0.001 deg of latitude north at 47 deg: about 111.2 m north
    n = lla_to_local_ned([[47.0, 8.0, 500.0], [47.001, 8.0, 500.0]])
    assert 111.0 < n[1, 0] < 111.4 and abs(n[1, 1]) < 1e-6
