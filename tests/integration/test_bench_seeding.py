"""The seeding scheme: trial r of a bench is the same whatever the number of trials, and a
bench split into shards run in separate processes gives the same table as one process."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import numpy as np

from uavest.experiments.montecarlo import aggregate, run_trial, trial_data, trial_rows
from uavest.experiments.systems import build_system
from uavest.scenarios import load_scenario

SPECS = ["ekf", "ukf", "hybrid", "enkf"]


def _numbers(rows):
    """Trial rows without their wall times (the only thing allowed to differ)."""
    return [{lab: {k: v for k, v in r.items() if k != "seconds"} for lab, r in row.items()}
            for row in rows]


def _ungm(steps: int = 40):
    sc = load_scenario("ungm", [])
    sc["steps"] = steps
    return build_system(sc)


def test_trial_r_does_not_depend_on_the_number_of_trials():
    sysm = _ungm()
    two = trial_rows(sysm, SPECS, 3, range(2))
    four = trial_rows(sysm, SPECS, 3, range(4))
    # every number of trials 0 and 1, the filters' own draws included
    assert _numbers(two) == _numbers(four[:2])
    assert _numbers(four[2:3]) != _numbers(four[:1])  # and trials do differ
    X0, Z0 = trial_data(sysm, 3, 0)
    X0b, Z0b = trial_data(sysm, 3, 0)
    np.testing.assert_array_equal(Z0, Z0b)
    assert not np.array_equal(Z0, trial_data(sysm, 4, 0)[1])  # the seed matters


def _shard(args):
    seed, lo, hi = args
    return trial_rows(_ungm(), SPECS, seed, range(lo, hi))


def test_bench_split_over_two_processes_gives_the_same_table():
    n = 6
    whole = aggregate(trial_rows(_ungm(), SPECS, 1, range(n)), 1)
    with ProcessPoolExecutor(2) as ex:
        a, b = ex.map(_shard, [(1, 0, 3), (1, 3, n)])
    split = aggregate(a + b, 1)
    keys = ("rmse_mean", "rmse_median", "approx_error", "est_error", "nees_mean",
            "diverged_fraction", "resets")
    for lab in SPECS:
        assert [whole[lab][k] for k in keys] == [split[lab][k] for k in keys], lab


def test_a_filter_does_not_change_with_its_neighbours():
    sysm = _ungm()
    alone = run_trial(sysm, ["hybrid"], 0, 2)["hybrid"]
    beside = run_trial(sysm, SPECS, 0, 2)["hybrid"]
    assert {k: alone[k] for k in ("rmse", "nees")} == {k: beside[k] for k in ("rmse", "nees")}
