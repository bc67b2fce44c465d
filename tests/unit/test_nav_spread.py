"""benchmarks/nav_spread.py: each navigation filter's covariance against the first one's
at the same steps of a replay (docs/navigation.md, the hybrid's re-spread)."""

from __future__ import annotations

import pytest
from conftest import REPO_ROOT, load_benchmark

LOG = REPO_ROOT / "logs" / "sim_200hz.tlog"


def test_the_ukfs_covariance_follows_the_ekfs_and_a_too_long_skip_is_refused():
    bench = load_benchmark("nav_spread")
    est = bench.replay_estimates(str(LOG), "ekf,ukf", 0, None)
    res = bench.spread_table(est, 20.0)
    assert res["ekf"][:3] == (1.0, 1.0, 1.0)
    assert all(0.8 < r < 1.25 for r in res["ukf"][:3]), res
    assert 0.01 < res["ekf"][3] < 5.0  # the position std, m
    with pytest.raises(SystemExit, match="lower --skip"):
        bench.spread_table(est, 600.0)  # the same replay's steps
