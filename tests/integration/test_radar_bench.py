"""Radar bench end to end (few runs): keys, determinism, bound ratio sanity, --set."""

import numpy as np
import pytest

from uavest.eval.tracking import nees_band
from uavest.experiments.radar import run_bench
from uavest.scenarios import load_scenario, load_typed

KEYS = {
    "rmse_mean", "rmse_median", "approx_error", "est_error", "nees_mean", "diverged_fraction",
    "us_per_step", "pos_rmse", "vel_rmse", "pcrlb_pos", "nees_band", "gospa", "id_swaps",
    "false_tracks", "track_breaks", "nees_in_band_fraction", "pcrlb_ratio_rms", "cond_ratio",
}


def test_far_bench_keys_and_bound():
    sc = load_scenario("radar_far", ["radar.sigma_az_deg=1.0"])
    r = run_bench(sc, ["ekf", "ukf"], 8, 0, 40)
    for lab in ("ekf", "ukf"):
        assert KEYS <= set(r[lab])
        assert r[lab]["pcrlb_pos"] > 0
        # no estimator beats the bound by much (Monte Carlo slack with 8 runs)
        assert r[lab]["pos_rmse"] > 0.6 * r[lab]["pcrlb_pos"]
        assert r[lab]["gospa"] is None
    # the EKF is over-confident on the far case (its inconsistency is shown)
    assert r["ekf"]["nees_mean"] > r["ukf"]["nees_mean"]
    # the band is per scan (8 runs); the fraction of scans inside it shows it too
    assert r["ekf"]["nees_band"] == pytest.approx(list(nees_band(4, 8)))
    assert r["ukf"]["nees_in_band_fraction"] > 0.9
    assert r["ekf"]["nees_in_band_fraction"] < r["ukf"]["nees_in_band_fraction"]


def test_bench_is_deterministic_and_filter_independent():
    sc = load_scenario("radar_crossing")
    a = run_bench(sc, ["ukf"], 3, 5, 20)
    b = run_bench(sc, ["ekf", "ukf"], 3, 5, 20)
    assert a["ukf"]["pos_rmse"] == b["ukf"]["pos_rmse"]
    c = run_bench(sc, ["ukf"], 3, 6, 20)
    assert c["ukf"]["pos_rmse"] != a["ukf"]["pos_rmse"]


def test_set_override_changes_noise():
    lo = run_bench(load_scenario("radar_far", ["radar.sigma_az_deg=0.5"]), ["ukf"], 4, 0, 30)
    hi = run_bench(load_scenario("radar_far", ["radar.sigma_az_deg=5"]), ["ukf"], 4, 0, 30)
    assert lo["ukf"]["pcrlb_pos"] < hi["ukf"]["pcrlb_pos"]


@pytest.mark.parametrize("name", ["radar_multitarget", "radar_uav"])
def test_tracker_scenarios_run(name):
    r = run_bench(load_scenario(name), ["ukf"], 1, 0, 40)
    v = r["ukf"]
    assert KEYS <= set(v)
    assert v["pcrlb_pos"] is None and np.isfinite(v["gospa"])
    assert v["pos_rmse"] < 100.0
    # the per-scan NEES averages every assigned truth, not one sample per run: the band
    # is for the mean per-scan sample count (> runs = 1 with several targets)
    n_k = v["nees_samples_per_scan"]
    assert n_k > 1.5
    ndim = 2 if name == "radar_multitarget" else 3
    assert v["nees_band"] == pytest.approx(list(nees_band(2 * ndim, n_k)))
    assert 0.0 <= v["nees_in_band_fraction"] <= 1.0


@pytest.mark.parametrize(
    "sets,msg",
    [
        (["motion.truth_q=0.1"], "truth process noise"),
        (["motion.model=ct"], "motion.model"),
        (["targets=[{turns=[[10, 20, 3.0]]}]"], "scripted turn"),
        (["targets=[{start=[0.0, 0.0, 1.0, 1.0]}]"], "prior mean"),
    ],
)
def test_filter_mode_refuses_a_truth_off_the_filters_model(sets, msg):
    """The PCRLB of filter mode assumes the truth follows the filters' model; a scenario
    that breaks that must fail loudly, not print a wrong bound."""
    sc = load_scenario("radar_far", sets)
    with pytest.raises(ValueError, match=msg):
        run_bench(sc, ["ekf"], 2, 0, 5)


def test_filter_mode_error_is_a_one_line_cli_error(capsys):
    from uavest.cli import main

    rc = main(["bench", "radar_far", "--runs", "2", "--steps", "5", "--no-progress",
               "--set", "motion.truth_q=0.1"])
    assert rc == 2
    assert "truth process noise" in capsys.readouterr().err


def test_filter_mode_uav_bound_uses_the_true_poses():
    """Radar on a moving UAV in filter mode: the bound is computed with each scan's true
    sensor pose (not the origin)."""
    from uavest.eval.pcrlb import pcrlb, position_bound
    from uavest.experiments.radar import data_rng
    from uavest.tracking.scenario import build_models, generate_run, prior

    mean = [3000.0, 2000.0, 800.0, -20.0, 10.0, 0.0]
    sc = load_typed("radar_uav", ["mode=filter", "motion.truth_q=1.0",
                                  f"prior.mean={mean}", "prior.std=[100, 100, 100, 5, 5, 5]",
                                  f"targets=[{{start={mean}}}]"])
    r = run_bench(sc, ["ukf"], 4, 0, 30)
    motion, radar = build_models(sc)
    m0, P0 = prior(sc)
    runs = [generate_run(sc, data_rng(0, i), 30) for i in range(4)]
    truths = np.stack([rd.truths[0] for rd in runs])
    det = np.array([[np.any(o == 0) for o in rd.origins] for rd in runs], float)
    models = [radar.with_pose(p) for p in runs[0].poses_true]
    want = position_bound(
        pcrlb(np.linalg.inv(P0), truths, motion, lambda k: models[k - 1], 1.0, detected=det), 3
    ).mean()
    at_origin = position_bound(
        pcrlb(np.linalg.inv(P0), truths, motion, radar, 1.0, detected=det), 3
    ).mean()
    assert r["ukf"]["pcrlb_pos"] == pytest.approx(want, rel=1e-12)
    assert abs(want - at_origin) > 1e-3 * want
    assert r["ukf"]["pos_rmse"] > 0.6 * r["ukf"]["pcrlb_pos"]


def test_radar_hybrid_preset_is_the_local_update_and_spec_parameters_win():
    """``hybrid`` in radar tracking is the local-gain hybrid (n_cloud 64); a spec's own
    parameters win. (That it beats the core default on radar_far is a 100-run claim,
    measured by ``benchmarks/radar_bound.py``, not a unit test: 20 runs do not decide it.)"""
    from uavest.experiments.radar import make_radar_filter

    f = make_radar_filter("hybrid")
    assert (f.update_mode, f.n_cloud) == ("local", 64)
    assert make_radar_filter("hybrid(update_mode=shift)").update_mode == "shift"
    assert make_radar_filter("hybrid_sh").filter.update_mode == "local"


def test_one_filter_under_two_labels_draws_two_streams(capsys):
    # benchmarks/radar_bound.py shows a filter's stream-to-stream spread this way; the
    # command line refuses the same list (two names of one filter are a slip there)
    from uavest.cli import main

    sc = load_scenario("radar_far")
    labels = ["hybrid", "hybrid(update_mode=local,n_cloud=64)"]
    r = run_bench(sc, labels, 2, 0, 8)
    assert r[labels[0]]["pos_rmse"] != r[labels[1]]["pos_rmse"]
    alone = run_bench(sc, labels[1:], 2, 0, 8)
    assert alone[labels[1]]["pos_rmse"] == r[labels[1]]["pos_rmse"]
    assert main(["bench", "radar_far", "--runs", "1", "--filters", ",".join(labels)]) == 2
    assert "resolve to the same filter" in capsys.readouterr().err
