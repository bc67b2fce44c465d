"""Issue 11, items 2 and 3: references chosen on evidence; declination from every source."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uavest.eval.attitude import choose_reference
from uavest.ingest.types import LogParams, RefSeries
from uavest.models.attitude import declination_and_source

from . import corpus as C


def _ref(kind, t):
    t = np.asarray(t, float)
    return RefSeries(t, np.tile([1.0, 0, 0, 0], (t.size, 1)), kind, "x")


def test_one_sample_truth_loses_to_a_full_autopilot_reference():
    refs = {"vehicle_attitude_groundtruth": _ref("truth", [0.0]),
            "vehicle_attitude": _ref("autopilot", np.arange(0, 10, 0.01))}
    ref, ap, rejected = choose_reference(refs, (0.0, 10.0))
    assert ref == "vehicle_attitude" and ap == "vehicle_attitude"
    assert "1 usable sample" in rejected["vehicle_attitude_groundtruth"]


def test_reference_must_cover_the_window():
    refs = {"SIMSTATE": _ref("truth", np.arange(0, 2, 0.1)),
            "ATTITUDE": _ref("autopilot", np.arange(0, 100, 0.1))}
    ref, _, rejected = choose_reference(refs, (0.0, 100.0))
    assert ref == "ATTITUDE" and "covers 2 %" in rejected["SIMSTATE"]


def test_nothing_scorable():
    ref, ap, rejected = choose_reference({"ATT": _ref("autopilot", [1.0, 2.0])}, (0, 10))
    assert ref is None and ap is None and "ATT" in rejected


def test_timestamp_sample_zero_falls_back_to_timestamp(logs):
    """Issue: vehicle_attitude_groundtruth with timestamp_sample = 0 kept one sample."""
    from uavest.ingest import read_log

    log = read_log(logs / "sample_logging_tagged_and_default_params.ulg")
    gt = log.references["vehicle_attitude_groundtruth"]
    assert len(gt) > 1000 and log.stats.duplicate == 0


def test_truth_without_usable_times_is_replaced_by_vehicle_attitude(tmp_path, logs):
    """With the groundtruth times unusable (all equal), the replay scores against
    vehicle_attitude and says why."""
    from uavest.apps.replay import ReplayConfig, replay

    d = (logs / "sample_logging_tagged_and_default_params.ulg").read_bytes()
    d = C.ulog_set_all_timestamps(d, "vehicle_attitude_groundtruth", 0)
    p = tmp_path / "gt0.ulg"
    p.write_bytes(d)
    doc = replay(p, ReplayConfig(filters=("ekf",)))
    assert doc["reference"] == "vehicle_attitude"
    assert "usable sample" in doc["references_rejected"]["vehicle_attitude_groundtruth"]
    assert doc["filters"]["ekf"]["n"] > 200


def test_nothing_to_score_exits_2(tmp_path, logs, capsys):
    from uavest.cli import main

    d = (logs / "vtol.tlog").read_bytes()
    p = tmp_path / "short.tlog"
    p.write_bytes(d[: len(d) // 100])
    rc = main(["replay", str(p), "--filters", "ekf", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "nothing to score against" in err[0]


@pytest.mark.parametrize("params, deg, source", [
    ({"EKF2_MAG_DECL": 3.323, "EKF2_DECL_TYPE": 7}, 3.323, "EKF2_MAG_DECL"),
    ({"ATT_MAG_DECL": 2.0}, 2.0, "ATT_MAG_DECL"),
    ({"COMPASS_DEC": 0.2074, "COMPASS_AUTODEC": 1}, math.degrees(0.2074), "COMPASS_DEC"),
    ({"COMPASS_DEC": 0.0, "COMPASS_AUTODEC": 0}, 0.0, "COMPASS_DEC"),
])
def test_declination_parameters_and_units(params, deg, source):
    d, src = declination_and_source(params)
    assert math.degrees(d) == pytest.approx(deg, abs=1e-6) and source in src


def test_autodec_zero_is_unknown_and_the_model_is_used():
    """Issue: COMPASS_DEC = 0 (boot value with COMPASS_AUTODEC on) gave yaw 5.9 deg."""
    p = LogParams({"COMPASS_DEC": 0.0, "COMPASS_AUTODEC": 1.0})
    assert declination_and_source(p)[0] is None
    p.set_geo(-35.3632, 149.1652, 584.0, 1_767_225_600.0)  # Canberra SITL home, 2026-01-01
    d, src = declination_and_source(p)
    assert "World Magnetic Model" in src and "COMPASS_AUTODEC" in src
    assert 11.0 < math.degrees(d) < 13.5
    p2 = LogParams({"EKF2_MAG_DECL": 0.0, "EKF2_DECL_TYPE": 7})
    p2.set_geo(47.3977, 8.5456, 488.0, 1_710_773_351.0)
    d2, src2 = declination_and_source(p2)
    assert "WMM2020" in src2 and 3.0 < math.degrees(d2) < 3.8


def test_px4_events_scores_yaw_with_the_logs_declination(logs):
    """Issue: EKF2_MAG_DECL ignored: yaw 3.50 deg on sample_px4_events.ulg (0.28 by hand)."""
    from uavest.apps.replay import ReplayConfig, replay

    doc = replay(logs / "sample_px4_events.ulg", ReplayConfig(filters=("ekf",)))
    assert "EKF2_MAG_DECL" in doc["declination_source"]
    assert math.degrees(doc["declination_rad"]) == pytest.approx(3.323, abs=1e-3)
    assert doc["filters"]["ekf"]["yaw_rmse_deg"] < 1.0
