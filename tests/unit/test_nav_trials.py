"""The navigation Monte Carlo trial (uavest/experiments/nav.py): a pure function of
(case, filters, seed, trial), and EKF / UKF / hybrid recover after a GNSS outage on a
short seeded flight (the benchmark is benchmarks/nav_hybrid.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from uavest.experiments import nav

#: case (b) shortened: an 8 s outage from 8 s, scored once GNSS is back (16-24 s)
OUTAGE = replace(nav.CASES["outage"], duration=24.0, outage=(8.0, 16.0), window=(16.0, 24.0))


def _numbers(row: dict) -> dict:
    """Every metric but the cost (wall time)."""
    return {lab: {k: v for k, v in m.items() if k != "us_per_step"} for lab, m in row.items()}


def test_trial_is_deterministic_per_seed():
    case = replace(nav.CASES["heading"], duration=6.0, window=(0.0, 6.0))
    a = nav.run_trial(case, ["ekf", "hybrid"], seed=5, r=1)
    b = nav.run_trial(case, ["ekf", "hybrid"], seed=5, r=1)
    alone = nav.run_trial(case, ["hybrid"], seed=5, r=1)  # the others do not matter
    other = nav.run_trial(case, ["ekf", "hybrid"], seed=5, r=2)
    for lab in a:
        for k, v in _numbers(a)[lab].items():
            np.testing.assert_array_equal(v, _numbers(b)[lab][k], err_msg=f"{lab} {k}")
    for k, v in _numbers(alone)["hybrid"].items():
        np.testing.assert_array_equal(v, _numbers(a)["hybrid"][k], err_msg=k)
    assert not np.array_equal(a["ekf"]["mse_att"], other["ekf"]["mse_att"])
    # the flight itself: same seed and trial, same arrays
    f1, f2 = nav.flight(case, nav.NavSim(), 5, 1), nav.flight(case, nav.NavSim(), 5, 1)
    np.testing.assert_array_equal(f1.u, f2.u)
    np.testing.assert_array_equal(f1.prior.x, f2.prior.x)


@pytest.mark.slow
def test_filters_recover_after_a_gnss_outage():
    rows = nav.trial_rows(OUTAGE, ["ekf", "ukf", "hybrid"], seed=0, trials=range(2))
    agg = nav.aggregate(rows)
    for lab, a in agg.items():
        assert a["not_converged"] == 0, (lab, a)  # yaw error < 5 deg at the end
        assert a["resets"] == 0, (lab, a)
        assert a["vel_mps"] < 0.5, (lab, a)  # 3-D velocity, m/s, once GNSS is back
        assert a["pos_m"] < 3.0, (lab, a)  # horizontal, m
        assert a["yaw_deg"] < 5.0, (lab, a)
        assert math.isfinite(a["nees_mean"]) and a["us_per_step"] > 0.0
    assert agg["ukf"]["cost_vs_ukf"] == 1.0


def test_unknown_heading_prior_and_bad_rates():
    fl = nav.flight(replace(nav.CASES["heading"], duration=2.0), nav.NavSim(), 0, 3)
    assert fl.prior.P[2, 2] == pytest.approx(math.pi**2 / 3.0)
    assert abs(nav.quat_to_euler(fl.prior.x[:4])[2]) < 1e-12  # the filters start at yaw 0
    assert not fl.mag and len(fl.gnss) == 10  # no magnetometer; GNSS at 5 Hz for 2 s
    with pytest.raises(ValueError, match="whole multiple"):
        nav.NavSim(filter_rate=30)
