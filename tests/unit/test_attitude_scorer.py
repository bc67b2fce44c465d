"""AttitudeScorer: references scored against each other once per step, however many
estimators there are and whether the references arrived before or after the step."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.eval.attitude import AttitudeScorer
from uavest.geometry.rotation import euler_to_quat


def _q(yaw_deg: float) -> np.ndarray:
    return euler_to_quat(0.0, 0.0, np.radians(yaw_deg))


def _run(labels: list[str], refs_first: bool) -> AttitudeScorer:
    sc = AttitudeScorer()
    steps = np.arange(0.5, 10.0, 1.0)
    P = np.eye(6) * 1e-2

    def refs(t):
        sc.add_reference("truth", "truth", t, _q(2.0 * t))
        sc.add_reference("auto", "autopilot", t, _q(2.0 * t + 0.1 * t * t))

    refs(0.0)  # both sources known before the first step
    for k, t in enumerate(steps):
        if refs_first:  # both references already past the step when its estimates come
            refs(float(k))
            refs(float(k) + 1.0)
        for lab in labels:
            sc.add_estimate(float(t), lab, _q(2.0 * t + 1.0), P)
        if not refs_first:
            refs(float(k))
            refs(float(k) + 1.0)
    sc.finish()
    return sc


def test_reference_rows_do_not_depend_on_the_number_of_estimators():
    rows = []
    for labels in (["ekf"], ["ekf", "ukf", "hybrid"]):
        for refs_first in (False, True):
            sc = _run(labels, refs_first)
            a = sc.scores("auto", "truth", False)
            assert a["n"] == 10, (labels, refs_first, a["n"])
            for lab in labels:
                assert sc.scores(lab, "truth", True)["n"] == 10
            rows.append(a["yaw_rmse_deg"])
    assert np.allclose(rows, rows[0], rtol=0, atol=1e-12)


def test_settled_scores_count_from_each_estimators_own_first_step():
    """``settle_s``: each estimator scored again over its steps that long after its own
    first step (one starts 2 s after the other), equal to the batch RMSE and NEES of
    exactly those steps; the references get no settled block."""
    sc = AttitudeScorer(settle_s=3.0)
    P = np.eye(6) * 1e-2
    t_all = np.arange(0.0, 10.0, 0.25)
    err = {"a": lambda t: 1.0 + t, "b": lambda t: 0.5 * t}  # yaw error, deg
    start = {"a": 0.0, "b": 2.0}
    for t in t_all:
        sc.add_reference("truth", "truth", float(t), _q(2.0 * t))
        sc.add_reference("auto", "autopilot", float(t), _q(2.0 * t + 0.3))
        for lab in ("a", "b"):
            if t >= start[lab]:
                sc.add_estimate(float(t), lab, _q(2.0 * t + err[lab](t)), P)
    sc.finish()
    for lab in ("a", "b"):
        row = sc.scores(lab, "truth", True)
        t = t_all[t_all >= start[lab] + 3.0]
        e = err[lab](t)
        s = row["settled"]
        assert s["n"] == len(t) and s["after_s"] == 3.0
        assert s["yaw_rmse_deg"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-9)
        assert s["nees_mean"] == pytest.approx(np.mean(np.radians(e) ** 2 / 1e-2), rel=1e-6)
        assert row["n"] == np.sum(t_all >= start[lab]) > s["n"]
    assert "settled" not in sc.scores("auto", "truth", False)
    # not asked, or no step that late: no block
    assert "settled" not in _run(["ekf"], False).scores("ekf", "truth", True)
    late = AttitudeScorer(settle_s=100.0)
    late.add_reference("truth", "truth", 0.0, _q(0.0))
    late.add_estimate(0.5, "ekf", _q(1.0), P)
    late.add_reference("truth", "truth", 1.0, _q(0.0))
    late.finish()
    assert "settled" not in late.scores("ekf", "truth", True)
