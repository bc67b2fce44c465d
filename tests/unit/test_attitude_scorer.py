"""AttitudeScorer: references scored against each other once per step, however many
estimators there are and whether the references arrived before or after the step."""

from __future__ import annotations

import numpy as np

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
