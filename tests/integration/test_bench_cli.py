"""The bench harness and CLI: JSON shape, overrides, errors, and the UNGM ordering."""

import json

import pytest

from uavest.cli import main
from uavest.experiments.montecarlo import evaluate
from uavest.experiments.systems import build_system
from uavest.scenarios import ScenarioError, load_scenario

COMMON = {"rmse_mean", "rmse_median", "approx_error", "est_error", "nees_mean",
          "diverged_fraction", "us_per_step"}


def test_bench_json_shape(tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = main(["bench", "ungm", "--runs", "3", "--steps", "15", "--seed", "4",
               "--filters", "ekf,ukf(alpha=0.5),hybrid", "--json", str(out), "--no-progress"])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["scenario"] == "ungm" and doc["runs"] == 3 and doc["seed"] == 4
    assert set(doc["filters"]) == {"ekf", "ukf(alpha=0.5)", "hybrid"}
    for row in doc["filters"].values():
        assert COMMON <= set(row)
    assert "hybrid" in capsys.readouterr().out


def test_set_override_changes_the_problem(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    base = ["bench", "ungm", "--runs", "2", "--steps", "10", "--filters", "ukf", "--no-progress"]
    assert main(base + ["--json", str(a)]) == 0
    assert main(base + ["--set", "model.R=100", "--json", str(b)]) == 0
    ra = json.loads(a.read_text())["filters"]["ukf"]["rmse_mean"]
    rb = json.loads(b.read_text())["filters"]["ukf"]["rmse_mean"]
    assert ra != rb


def test_ablation_table_in_json(tmp_path):
    out = tmp_path / "abl.json"
    assert main(["bench", "ungm", "--runs", "2", "--steps", "10", "--filters", "enkf",
                 "--ablation", "--json", str(out), "--no-progress"]) == 0
    abl = json.loads(out.read_text())["ablation"]
    for fam in ("hybrid_literal", "hybrid"):
        assert set(abl[fam]) == {"random+equal", "expanded+equal", "random+confidence",
                                 "expanded+confidence"}
        assert all("approx_error" in c and "est_error" in c for c in abl[fam].values())


def test_unknown_scenario_and_bad_set_give_clear_errors(capsys):
    assert main(["bench", "no_such_scenario"]) == 2
    assert "unknown scenario" in capsys.readouterr().err
    assert main(["bench", "ungm", "--set", "nonsense"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err
    with pytest.raises(ScenarioError):
        load_scenario("missing.toml")


def test_speed_benchmark_runs(tmp_path):
    pytest.importorskip("filterpy", reason="filterpy is a benchmark-only dependency")
    out = tmp_path / "s.json"
    assert main(["bench", "ungm", "--speed", "--runs", "2", "--steps", "10", "--json",
                 str(out)]) == 0
    sp = json.loads(out.read_text())["speed"]
    assert sp["ukf_over_filterpy"] > 0 and sp["hybrid_over_ukf"] > 0


@pytest.mark.slow
def test_ungm_hybrid_beats_ukf_and_enkf_and_literal_loses_same_run():
    """Same seeded truths for all filters (30 runs; the 200-run numbers are in docs)."""
    sysm = build_system(load_scenario("ungm"))
    res = evaluate(sysm, ["ukf", "enkf", "hybrid", "hybrid_literal"], 30, seed=1)
    r = {k: v["rmse_mean"] for k, v in res.items()}
    assert r["hybrid"] < r["enkf"] < r["ukf"]
    assert r["hybrid_literal"] > r["enkf"]  # the measured negative result of the spec


@pytest.mark.parametrize("name", ["nonlinear2d", "linear_cv"])
def test_other_builtin_scenarios_run(name):
    sysm = build_system(load_scenario(name, ["steps=20"]))
    res = evaluate(sysm, ["ekf", "ukf", "hybrid"], 2, seed=0)
    assert all(v["rmse_mean"] >= 0 for v in res.values())


@pytest.mark.parametrize("name", ["ungm", "nonlinear2d", "linear_cv"])
def test_builtin_scenario_is_its_toml_file(name):
    # the TOML file is the only source of a built-in scenario (no Python copy)
    from pathlib import Path

    f = Path(__file__).resolve().parents[2] / "uavest" / "scenarios" / f"{name}.toml"
    by_path, by_name = load_scenario(str(f)), load_scenario(name)
    assert by_name["source"] == str(f)
    assert {k: v for k, v in by_path.items() if k != "source"} == \
        {k: v for k, v in by_name.items() if k != "source"}


def test_bench_radar_scenario_checks_filters_in_the_radar_preset(capsys):
    # under the radar preset "hybrid" is the local update, so these are two filters
    # (the bench preset would call them the same one and refuse the list)
    from uavest.cli import main

    rc = main(["bench", "radar_far", "--runs", "1", "--steps", "2", "--no-progress",
               "--filters", "hybrid(n_cloud=2),hybrid(update_mode=shift, n_cloud=2)"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "hybrid(update_mode=shift, n_cloud=2)" in out
