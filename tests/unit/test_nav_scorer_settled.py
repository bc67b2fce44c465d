"""The scorer's ``settled`` block: the same scores over the steps from ``settle_s`` after
the estimator's own first step, so that a start in flight (its alignment's transient)
does not make the whole of a short run's figure; and the live command's ``--settle``."""

from __future__ import annotations

import numpy as np
import pytest

from uavest.cli import main
from uavest.eval.navigation import NavScorer
from uavest.geometry.geodesy import LocalFrame
from uavest.geometry.rotation import euler_to_quat

SRC = "HIL_STATE_QUATERNION"
T0 = 3.0  # s: the estimator's first step (the reference starts at 0)
ROLL_START, ROLL_LATE = 4.0, 0.1  # deg: the error before and after 10 s from T0
VEL_START, VEL_LATE = 1.0, 0.05  # m/s
POS_START, POS_LATE = 5.0, 0.5  # m, north


def _scorer() -> tuple[NavScorer, LocalFrame, np.ndarray]:
    """A scorer with 30 s of truth (level, still at the origin) and an estimator whose
    roll, north velocity and north position are off by the START errors for the first
    10 s after its first step at ``T0`` and by the LATE ones after."""
    frame = LocalFrame(47.0, 8.0, 500.0)
    sc = NavScorer()
    q_ref = np.array([1.0, 0.0, 0.0, 0.0])
    for t in np.arange(0.0, 30.0 + 1e-9, 0.1):
        sc.add_attitude(SRC, float(t), q_ref)
        sc.add_position(SRC, float(t), np.zeros(3), np.zeros(3), np.array([47.0, 8.0, 500.0]))
    t = np.arange(T0, 29.0, 0.02)
    P = np.diag([np.radians(1.0) ** 2] * 3 + [0.5 ** 2] * 3 + [3.0 ** 2] * 3)
    for tk in t:
        early = tk < T0 + 10.0
        x = np.zeros(16)
        x[:4] = euler_to_quat(np.radians(ROLL_START if early else ROLL_LATE), 0.0, 0.0)
        x[4] = VEL_START if early else VEL_LATE
        x[7] = POS_START if early else POS_LATE
        sc.add_estimate("ekf", float(tk), x, P)
    return sc, frame, t


def test_settled_block_scores_only_the_steps_after_the_estimators_first_step_plus_settle():
    sc, frame, t = _scorer()
    whole = sc.scores("ekf", SRC, frame, settle_s=10.0)
    s = whole["settled"]
    assert s["after_s"] == 10.0
    # from the estimator's own first step (T0), not from the reference's start
    assert s["t"][0] == pytest.approx(T0 + 10.0, abs=0.021) and s["t"][1] == t[-1]
    assert s["n"] == int((t >= T0 + 10.0).sum()) < len(t)
    assert s["roll_rmse_deg"] == pytest.approx(ROLL_LATE, rel=1e-6)
    assert s["vel_rmse_ms"] == pytest.approx(VEL_LATE, rel=1e-9)
    assert s["hpos_rmse_m"] == pytest.approx(POS_LATE, abs=1e-6)
    # the whole run carries the start: its figures are the larger ones
    assert whole["vel_rmse_ms"] > 5 * s["vel_rmse_ms"]
    assert whole["hpos_rmse_m"] > 5 * s["hpos_rmse_m"]
    # the NEES blocks are the settled steps' own: a 4-deg roll error at a 1-deg std is
    # above the band (NEES 16), 0.1 deg is not (0.01)
    a, w = s["nees"]["attitude"], whole["nees"]["attitude"]
    assert a["n"] == s["n"] and a["above_band95"] == 0.0
    assert w["above_band95"] == pytest.approx(1 - s["n"] / len(t), abs=1e-9)


@pytest.mark.parametrize("settle", [None, 0.0, 40.0])
def test_no_settled_block_when_not_asked_or_the_run_is_not_longer(settle):
    sc, frame, _ = _scorer()
    got = sc.scores("ekf", SRC, frame, settle_s=settle)
    assert "settled" not in got and got["vel_rmse_ms"] > 0.5


@pytest.mark.parametrize("value", ["-1", "nan", "inf", "4000"])
def test_live_settle_out_of_range_is_one_line_before_the_link_opens(value, capsys):
    rc = main(["run", "--connect", "udpin:127.0.0.1:9", "--trackers", "none", "--settle",
               value, "--heartbeat-timeout", "0.5"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--settle must be from 0 to 3600 s" in err, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
