"""The report's navigation error figure uses the scorer's own reference interpolation: a
step inside a reference gap longer than ``MAX_REF_GAP_S`` is left out of the figure's
errors exactly as :class:`uavest.eval.navigation.NavScorer` leaves it out of the scores
(``np.interp`` drew an error there, interpolated across the gap, that no score counts)."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.eval.navigation import MAX_REF_GAP_S, NavScorer
from uavest.report.build import navigation_metrics

SRC = "GLOBAL_POSITION_INT"
GAP = (8.0, 12.0)  # s: no reference sample strictly inside


def _v(t):
    """A velocity history (K, 3) m/s NED."""
    return np.column_stack([np.sin(0.3 * t), np.cos(0.2 * t), 0.1 * t])


def _case():
    rng = np.random.default_rng(21)
    tr = np.round(np.arange(0.0, 20.0 + 1e-9, 0.2), 6)
    tr = tr[(tr <= GAP[0]) | (tr >= GAP[1])]
    assert np.diff(tr).max() > 2 * MAX_REF_GAP_S  # the gap is one the scorer masks
    vr = _v(tr)
    pr = np.cumsum(0.2 * vr, axis=0)
    t = np.arange(0.5, 19.5, 0.05)
    v = _v(t) + 0.05 * rng.standard_normal((len(t), 3))
    p = np.column_stack([np.interp(t, tr, pr[:, i]) for i in range(3)])
    p += 0.3 * rng.standard_normal(p.shape)
    s3 = np.full((len(t), 3), 0.3)
    nav = {"filters": {"ekf": {"t": t, "v": v, "p": p, "s3v": s3, "s3p": s3}},
           "ref": (SRC, tr, vr, pr), "origin": None, "ref_lla": None}
    return nav, tr, vr, t, v, p


def test_steps_in_a_reference_gap_are_not_drawn():
    nav, tr, _, t, _, _ = _case()
    m = navigation_metrics(nav, {})["ekf"]
    # a step more than MAX_REF_GAP_S from the reference samples around it
    in_gap = (t > GAP[0] + MAX_REF_GAP_S + 1e-6) & (t < GAP[1] - MAX_REF_GAP_S - 1e-6)
    near = (t < GAP[0] - 0.1) | (t > GAP[1] + 0.1)
    assert in_gap.sum() > 20 and near.sum() > 200
    for key in ("ev", "ep"):
        assert np.isnan(m[key][in_gap]).all(), key
        assert np.isfinite(m[key][near]).all(), key


def test_figure_errors_are_the_ones_the_scorer_scores():
    """The RMS of the drawn velocity errors equals the scorer's ``vel_rmse_ms`` on the same
    estimates and reference (the same steps, the same interpolated reference)."""
    nav, tr, vr, t, v, p = _case()
    m = navigation_metrics(nav, {})["ekf"]
    sc = NavScorer()
    x = np.zeros(16)
    x[0] = 1.0
    for k in range(len(t)):
        x[4:7], x[7:10] = v[k], p[k]
        sc.add_estimate("ekf", float(t[k]), x, np.eye(15))
    for k in range(len(tr)):
        sc.add_position(SRC, float(tr[k]), None, vr[k], None)
    want = sc.scores("ekf", None)["vel_rmse_ms"]
    drawn = m["ev"][np.isfinite(m["ev"]).all(axis=1)]
    assert drawn.shape[0] < len(t)  # the gap's steps are out
    assert float(np.sqrt(np.mean(np.sum(drawn ** 2, axis=1)))) == pytest.approx(want, rel=1e-12)
