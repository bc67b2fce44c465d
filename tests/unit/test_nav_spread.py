"""benchmarks/nav_spread.py: each navigation filter's covariance against the first one's
at the same steps of a replay (docs/navigation.md, the hybrid's re-spread)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / "benchmarks" / "nav_spread.py"
LOG = ROOT / "logs" / "sim_200hz.tlog"


def _bench():
    spec = importlib.util.spec_from_file_location("nav_spread", BENCH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_ukfs_covariance_follows_the_ekfs_and_a_too_long_skip_is_refused():
    bench = _bench()
    res = bench.spreads(str(LOG), "ekf,ukf", 0, 20.0, None)
    assert res["ekf"][:3] == (1.0, 1.0, 1.0)
    assert all(0.8 < r < 1.25 for r in res["ukf"][:3]), res
    assert 0.01 < res["ekf"][3] < 5.0  # the position std, m
    with pytest.raises(SystemExit, match="lower --skip"):
        bench.spreads(str(LOG), "ekf", 0, 600.0, None)
