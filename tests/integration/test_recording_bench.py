"""``uavest bench SCENARIO --mcap PATH --trial K``: the recording of one Monte Carlo trial,
read back with the ``mcap`` reader, holds exactly what the trial's engine run computed
(generic ``/state/*`` channels for the benchmark systems, the radar channels for a
tracker trial); the trial's numbers do not depend on the recorder; ``uavest report``
recomputes the trial's metrics from the file."""

import json
import re

import numpy as np
import pytest
from mcap.reader import make_reader

from uavest.cli import main
from uavest.experiments.montecarlo import run_trial, trial_data
from uavest.experiments.radar import data_rng, run_trackers
from uavest.experiments.systems import build_system
from uavest.report import read_recording, write_report
from uavest.report.build import RADAR_FIGURES, STATE_FIGURES
from uavest.scenarios import load_scenario, load_typed
from uavest.sinks.base import Collector
from uavest.sinks.mcap import McapSink
from uavest.tracking.scenario import generate_run

SPECS = ["ekf", "ukf"]


def _figure_ids(page: str) -> tuple:
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", page)
    return tuple(re.findall(r"<figure class='report-figure' id='([^']+)'>", page))


@pytest.fixture(scope="module")
def ungm(tmp_path_factory):
    d = tmp_path_factory.mktemp("bench")
    path, js, js0 = d / "ungm.mcap", d / "with.json", d / "without.json"
    base = ["bench", "ungm", "--runs", "3", "--steps", "25", "--seed", "7", "--filters",
            ",".join(SPECS), "--no-progress"]
    assert main(base + ["--json", str(js), "--mcap", str(path), "--trial", "1"]) == 0
    assert main(base + ["--json", str(js0)]) == 0
    sc = load_scenario("ungm")
    sc["steps"] = 25
    sysm = build_system(sc)
    coll = Collector()
    row = run_trial(sysm, SPECS, 7, 1, [coll])
    return {"path": path, "doc": json.loads(js.read_text()), "doc0": json.loads(js0.read_text()),
            "sysm": sysm, "coll": coll, "row": row, "rec": read_recording(path)}


def test_trial_numbers_do_not_depend_on_the_recorder(ungm):
    sysm = ungm["sysm"]
    plain = run_trial(sysm, SPECS, 7, 1)
    for lab in SPECS:
        a, b = dict(plain[lab]), dict(ungm["row"][lab])
        a.pop("seconds"), b.pop("seconds")
        assert a == b, lab
    for lab in SPECS:  # the bench table too, with and without --mcap (timing aside)
        a, b = dict(ungm["doc"]["filters"][lab]), dict(ungm["doc0"]["filters"][lab])
        a.pop("us_per_step"), b.pop("us_per_step")
        assert a == b, lab


def test_ungm_recording_round_trips(ungm):
    rec, coll = ungm["rec"], ungm["coll"]
    assert not rec.truncated
    X, Z = trial_data(ungm["sysm"], 7, 1)
    for lab in SPECS:
        recs = coll.records[lab]
        assert len(recs) == 25
        for ch in ("estimate", "error", "health"):
            assert rec.counts[f"/state/{lab}/{ch}"] == 25, (lab, ch)
        est = rec.json[f"/state/{lab}/estimate"]
        a = coll.arrays(lab)
        np.testing.assert_array_equal([m["t"] for m in est], a["t"])
        np.testing.assert_array_equal([m["x"] for m in est], a["x"])
        np.testing.assert_array_equal([m["P"] for m in est], a["P"].reshape(25, -1))
        np.testing.assert_allclose([m["sigma3"] for m in est],
                                   3 * np.sqrt(a["P"][:, 0, 0])[:, None], rtol=1e-15)
        err = rec.json[f"/state/{lab}/error"]
        e = np.array([m["err"] for m in err])
        np.testing.assert_array_equal(e, a["x"] - X)
        np.testing.assert_allclose(np.mean([m["nees"] for m in err]), ungm["row"][lab]["nees"],
                                   rtol=1e-12)
        np.testing.assert_allclose(np.sqrt(np.mean(np.sum(e**2, axis=1))),
                                   ungm["row"][lab]["rmse"], rtol=1e-12)
        assert {m["dof"] for m in err} == {1}
        hl = rec.json[f"/state/{lab}/health"]
        np.testing.assert_array_equal([m["nis"] for m in hl], a["nis"])
        assert [m["resets"] for m in hl] == [r.resets for r in recs]
    assert rec.counts["/truth/state"] == rec.counts["/measurement/z"] == 25
    np.testing.assert_array_equal([m["x"] for m in rec.json["/truth/state"]], X)
    np.testing.assert_array_equal([m["z"] for m in rec.json["/measurement/z"]], Z)
    # the independent reader (plain mcap) sees the same channels with titled JSON schemas
    with open(ungm["path"], "rb") as f:
        seen = {}
        for schema, channel, _ in make_reader(f).iter_messages():
            seen[channel.topic] = schema.name
            if schema.encoding == "jsonschema":
                assert json.loads(schema.data)["title"] == schema.name
    assert seen["/state/ekf/estimate"] == "uavest.StateEstimate"
    assert seen["/state/ekf/error"] == "uavest.StateError"
    assert seen["/state/ekf/health"] == "uavest.FilterHealth"
    assert seen["/truth/state"] == "uavest.StateTruth"
    assert seen["/measurement/z"] == "uavest.Measurement"
    assert not any(t.startswith(("/attitude/", "/tf/")) for t in seen)


def test_ungm_metadata(ungm):
    rec = ungm["rec"]
    assert rec.metadata["run"]["seed"] == "7"
    assert rec.metadata["run"]["source"] == "scenario:ungm"
    cfg = {k: json.loads(v) for k, v in rec.metadata["config"].items()}
    assert cfg["scenario"] == "ungm" and cfg["trial"] == 1 and cfg["state_dim"] == 1
    filters = {k: json.loads(v) for k, v in rec.metadata["filters"].items()}
    assert list(filters) == SPECS and filters["ukf"]["params"]["alpha"] == 1.0
    assert rec.json["/run/info"][0]["config"]["trial"] == 1


@pytest.mark.slow
def test_report_on_a_ungm_bench_recording(ungm, tmp_path):
    paths = write_report(ungm["path"], tmp_path)
    m = json.loads(paths["metrics"].read_text())
    assert m["kind"] == "state" and m["trial"] == 1 and m["scenario"] == "ungm"
    for lab in SPECS:
        got, row = m["filters"][lab], ungm["row"][lab]
        assert got["rmse"] == pytest.approx(row["rmse"], rel=1e-12)
        assert got["nees_mean"] == pytest.approx(row["nees"], rel=1e-12)
        assert got["resets"] == row["resets"] and got["steps"] == 25
        assert 0.0 <= got["frac_in_3sigma"] <= 1.0 and got["nis_mean"] > 0
    assert _figure_ids(paths["html"].read_text()) == STATE_FIGURES
    assert "| ekf |" in paths["markdown"].read_text()


def test_trial_out_of_range_is_a_usage_error(tmp_path, capsys):
    assert main(["bench", "ungm", "--runs", "2", "--steps", "5", "--mcap",
                 str(tmp_path / "x.mcap"), "--trial", "2", "--no-progress"]) == 2
    assert "--trial" in capsys.readouterr().err


@pytest.mark.slow
def test_radar_bench_trial_recording(tmp_path):
    path = tmp_path / "radar.mcap"
    specs = ["ekf", "ukf"]
    assert main(["bench", "radar_uav", "--runs", "2", "--steps", "12", "--seed", "3",
                 "--filters", ",".join(specs), "--mcap", str(path), "--trial", "1",
                 "--report", str(tmp_path / "rep"), "--no-progress"]) == 0
    rec = read_recording(path)
    for topic in ("/radar/scan", "/radar/detections", "/radar/truth/state", "/radar/truth"):
        assert rec.counts[topic] == 12, topic
    # the recording is trial 1's tracker run: the same tracks as running it again
    sc = load_typed("radar_uav", ["steps=12"])
    coll = Collector()
    run_trackers(sc, specs, generate_run(sc, data_rng(3, 1), 12), 3, 1, [coll])
    for lab in specs:
        st = rec.json[f"/tracks/{lab}/state"]
        assert len(st) == rec.counts[f"/tracks/{lab}"] == 12
        for m, r in zip(st, coll.records[lab], strict=True):
            assert [x["id"] for x in m["tracks"]] == [x.id for x in r.tracks]
            for x, y in zip(m["tracks"], r.tracks, strict=True):
                np.testing.assert_array_equal(x["x"], y.x)
    cfg = {k: json.loads(v) for k, v in rec.metadata["config"].items()}
    assert cfg["trial"] == 1 and cfg["scenario"] == "radar_uav"
    html = tmp_path / "rep" / "radar.html"
    assert html.exists()
    assert _figure_ids(html.read_text()) == RADAR_FIGURES
    # a second recording of the same trial through the sink API directly gives the same
    # scans (the bench path adds nothing of its own)
    p2 = tmp_path / "again.mcap"
    run_trackers(sc, specs, generate_run(sc, data_rng(3, 1), 12), 3, 1, [McapSink(p2)])
    assert read_recording(p2).json["/radar/scan"] == rec.json["/radar/scan"]
