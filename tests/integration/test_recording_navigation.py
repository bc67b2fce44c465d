"""The navigation model's MCAP recording: ``/navigation/<label>/estimate`` read back with
the ``mcap`` reader and decoded by Google's ``protobuf`` from the schema in the file
equals the run's own records (velocity, position, their 3-sigma, the accelerometer bias),
and the attitude channels carry the gyro bias of the navigation state, not its velocity."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import REPO_ROOT, google_decoded

from uavest.apps.replay import ReplayConfig, replay
from uavest.sinks.base import Collector
from uavest.sinks.mcap import McapSink

LOG = REPO_ROOT / "logs" / "sim_200hz.tlog"


@pytest.mark.slow
def test_navigation_channels_equal_the_run(tmp_path):
    path = tmp_path / "nav.mcap"
    coll = Collector()
    doc = replay(LOG, ReplayConfig(filters=("ekf",), model="nav"),
                 sinks=[coll, McapSink(path, frame_rate_hz=None)], command="test")
    assert doc["model"]["value"] == "nav"
    got = google_decoded(path)
    nav, att = got["/navigation/ekf/estimate"], got["/attitude/ekf/estimate"]
    recs = coll.records["ekf"]
    assert len(nav) == len(recs) == len(att) > 100
    X = np.array([r.x for r in recs])
    P = np.array([r.P for r in recs])
    sd = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
    np.testing.assert_allclose([m.t for m in nav], [r.t for r in recs])
    np.testing.assert_allclose([list(m.velocity_ned_m_s) for m in nav], X[:, 4:7])
    np.testing.assert_allclose([list(m.position_ned_m) for m in nav], X[:, 7:10])
    np.testing.assert_allclose([list(m.sigma3_velocity_m_s) for m in nav], 3 * sd[:, 3:6])
    np.testing.assert_allclose([list(m.sigma3_position_m) for m in nav], 3 * sd[:, 6:9])
    np.testing.assert_allclose([list(m.accel_bias_m_s2) for m in nav], X[:, 13:16])
    np.testing.assert_allclose([list(m.bias_rad_s) for m in att], X[:, 10:13])
    # the simulator flies: the recorded position moves by more than its 3-sigma (the
    # whole log: its 3-sigma carries the receiver's bias, 4.5 m vertically, and in the
    # first 30 s the vehicle moves 2 m)
    assert X.shape[1] == 19  # with the GNSS bias states the drift sized
    p = X[:, 7:10]
    assert np.linalg.norm(p[-1] - p[0]) > 3 * sd[-1, 6:9].max()


@pytest.mark.slow
def test_report_of_a_navigation_recording_reproduces_the_replay_scores(tmp_path):
    """``uavest report`` on the navigation recording: velocity/position RMSE and the NEES
    band shares equal the replay's (the same scorer over the recorded states), and the page
    has the velocity/position error figure."""
    from uavest.report import write_report

    path = tmp_path / "nav.mcap"
    doc = replay(LOG, ReplayConfig(filters=("ekf", "ukf"), model="nav"),
                 sinks=[McapSink(path)], command="test")
    out = write_report(path, tmp_path / "rep")
    metrics = json.loads(out["metrics"].read_text())
    for lab in ("ekf", "ukf"):
        mine, theirs = metrics["filters"][lab], doc["filters"][lab]
        for key in ("vel_rmse_ms", "hpos_rmse_m", "vpos_rmse_m"):
            assert mine[key] == pytest.approx(theirs[key], rel=1e-6), (lab, key)
        assert mine["nees_vel_in95"] == pytest.approx(theirs["nees"]["velocity"]["in_band95"])
        assert mine["nees_pos_in95"] == pytest.approx(theirs["nees"]["position"]["in_band95"])
    html = out["html"].read_text()
    assert 'id="fig-navigation"' in html or "fig-navigation" in html
