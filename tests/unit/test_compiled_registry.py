"""The one registry of optional compiled kernels (:mod:`uavest.compiled`): every kernel
module is registered once, the self-check harness refuses a module whose kernels
disagree with their numpy reference or fail, with one warning, and ``UAVEST_NUMBA=0``
gives the numpy paths silently; the shared Cholesky helper refuses non-finite pivots."""

from __future__ import annotations

import logging
import math
import types

import numpy as np
import pytest

from uavest import compiled
from uavest.compiled import Kernels


def _kernels(cases, name="fake") -> Kernels:
    # a module that imports: the harness only compares what ``cases`` yields
    return Kernels(name, "uavest.compiled", f"{name} kernels", cases, 1e-12, 1e-12,
                   "uavest.test")


@pytest.fixture
def numba_on(monkeypatch):
    pytest.importorskip("numba", reason="numba not installed (the optional uavest[fast])")
    monkeypatch.delenv("UAVEST_NUMBA", raising=False)


def test_every_kernel_module_is_registered_once():
    import uavest.core.hybrid  # noqa: F401 - registers shift and local
    import uavest.core.unscented  # noqa: F401
    import uavest.geometry.rotation  # noqa: F401
    import uavest.models.navigation  # noqa: F401
    import uavest.models.radar  # noqa: F401

    assert set(compiled.REGISTRY) == {"manifold", "ut", "shift", "local", "nav", "radar"}
    mods = [k.module for k in compiled.REGISTRY.values()]
    assert len(set(mods)) == len(mods)
    assert all(v in (None, True, False) for v in compiled.status().values())
    with pytest.raises(ValueError, match="registered twice"):
        compiled.register("ut", "x", "x", lambda nb: (), rtol=0.0, atol=0.0)


def test_agreeing_kernels_are_used(numba_on):
    k = _kernels(lambda nb: [("a", np.ones(3), np.ones(3) + 1e-14), ("b", 0, 0)])
    assert isinstance(k.get(), types.ModuleType) and k.loaded is k.get()


def test_a_self_check_reference_that_asks_for_the_kernels_gets_numpy(numba_on):
    """While the kernels are being decided, a nested ``get`` (a self-check's numpy
    reference reaching a function that dispatches on the same kernels, e.g. the
    magnetometer's back-dating of rows) takes numpy: the reference stays numpy and the
    decision does not recurse (before, it did until Python's limit, and the kernels fell
    back to numpy with a RecursionError warning)."""
    seen = []

    def cases(nb):
        seen.append(k.get())
        return [("a", 1.0, 1.0)]

    k = _kernels(cases)
    assert isinstance(k.get(), types.ModuleType)
    assert seen == [None]


@pytest.mark.parametrize("cases, reason", [
    (lambda nb: [("ok", 1.0, 1.0), ("x", np.ones(2), np.array([1.0, 1.1]))],
     "x: max difference 0.1"),
    (lambda nb: [("x", np.ones(2), np.ones(3))], "x: shape (2,) against (3,)"),
    (lambda nb: [("x", None, np.ones(2))], "x: no result"),
    (lambda nb: [("x", np.array([math.nan]), np.array([math.nan]))], "x: max difference"),
])
def test_disagreeing_kernels_fall_back_with_one_warning(numba_on, caplog, cases, reason):
    k = _kernels(cases)
    with caplog.at_level(logging.WARNING, logger="uavest.test"):
        assert k.get() is None
        assert k.get() is None  # decided once: no second check, no second warning
    assert k.loaded is False
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 1 and reason in msgs[0] and "using numpy" in msgs[0]


def test_failing_kernels_fall_back_with_one_warning(numba_on, caplog):
    def cases(nb):
        raise RuntimeError("does not compile")
        yield  # pragma: no cover

    k = _kernels(cases)
    with caplog.at_level(logging.WARNING, logger="uavest.test"):
        assert k.get() is None
    (rec,) = caplog.records
    assert "unavailable (RuntimeError: does not compile)" in rec.getMessage()
    bad = Kernels("m", "uavest.no_such_module", "m kernels", lambda nb: (), 0.0, 0.0,
                  "uavest.test")
    assert bad.get() is None


def test_switched_off_is_silent(monkeypatch, caplog):
    monkeypatch.setenv("UAVEST_NUMBA", "0")
    calls = []
    k = _kernels(lambda nb: calls.append(1) or ())
    with caplog.at_level(logging.DEBUG, logger="uavest.test"):
        assert k.get() is None
    assert not calls and not caplog.records


def test_the_one_cholesky_refuses_non_finite_pivots(numba_on):
    from uavest.compiled.helpers import chol_into, factor, solve_lower

    P = np.array([[4.0, 2.0, 0.4], [2.0, 5.0, 1.0], [0.4, 1.0, 3.0]])
    L = np.empty((3, 3))
    assert chol_into(P, L)
    np.testing.assert_allclose(L, np.linalg.cholesky(P), rtol=1e-14, atol=0)
    for bad in (np.inf, np.nan, -1.0, 0.0):  # an infinite pivot is no factor either
        Q = P.copy()
        Q[1, 1] = bad
        F = np.full((3, 3), np.nan)
        assert not chol_into(Q, F)
        # the failed pivot set to 1 and the factor completed: a diagonal in (0, inf), so
        # that an inverse taken before the status is read cannot divide by zero
        assert F[1, 1] == 1.0
        assert np.all((np.diag(F) > 0.0) & (np.diag(F) < np.inf)), (bad, F)
        assert np.all(np.triu(F, 1) == 0.0)
    ok, L1 = factor(np.array([[np.inf]]))
    assert not ok
    ok, L2 = factor(P[:2, :2])
    assert ok
    np.testing.assert_allclose(L2 @ solve_lower(L2, np.array([1.0, -2.0])), [1.0, -2.0],
                               rtol=1e-14)


_NEW_SIGNATURES = r"""
import importlib, json, sys
from uavest.apps.live import load_kernels
from uavest.cli import main
from uavest.compiled import REGISTRY

load_kernels(lambda s: None)


def signatures():
    out = {}
    for k in REGISTRY.values():
        m = importlib.import_module(k.module)
        for name, f in vars(m).items():
            if hasattr(f, "signatures") and getattr(f, "__module__", None) == m.__name__:
                out[f"{k.name}.{name}"] = {str(s) for s in f.signatures}
    return out


before = signatures()
for args in json.loads(sys.argv[1]):
    try:
        main(args)
    except SystemExit as e:
        assert not e.code, (args, e.code)
new = {k: sorted(v - before.get(k, set())) for k, v in signatures().items()}
print(json.dumps({k: v for k, v in new.items() if v}))
"""


@pytest.mark.slow  # a subprocess: four short runs
def test_a_run_compiles_nothing_after_the_self_checks(numba_on, tmp_path):
    """The self-checks compile every kernel specialisation (argument types, state and
    measurement sizes) that the shipped runs use, so that ``load_kernels`` (before a live
    run opens its link) leaves nothing to compile at the first estimates: the 2-D and 3-D
    radar scenarios' local hybrid trackers and the attitude and navigation models' filters
    run in a fresh process without a new signature. (Before: a fresh install's live job compiled the
    local hybrid's kernels for n = 4 and 6 and read-only weights at its first scans, and
    the attitude-manifold mean and inverse rotation at its first estimates.)"""
    import json
    import os
    import subprocess
    import sys

    from conftest import REPO_ROOT as ROOT

    runs = [["track", "radar_crossing", "--filters", "hybrid", "--seed", "0"],
            ["track", "radar_uav", "--filters", "hybrid", "--seed", "0"],
            ["replay", str(ROOT / "logs" / "sim_200hz.tlog"), "--model", "attitude",
             "--end", "3", "--filters", "ukf,hybrid", "--json", str(tmp_path / "r.json")],
            ["replay", str(ROOT / "logs" / "sim_200hz.tlog"), "--model", "nav",
             "--end", "3", "--filters", "ekf,ukf,hybrid"]]
    r = subprocess.run([sys.executable, "-c", _NEW_SIGNATURES, json.dumps(runs)],
                       capture_output=True, text=True, cwd=tmp_path, timeout=600,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stderr[-3000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {}


def _slow_cases(nb):
    import time

    time.sleep(0.3)  # a slow first load (numba's compilation on a fresh machine)
    return [("a", 1.0, 1.0)]


def test_the_first_load_is_timed_and_a_replay_does_not_count_it(numba_on, monkeypatch):
    """Each module's first ``get()`` is timed (``load_s``, ``load_seconds()``), once; a
    replay during which one loads leaves that time out of its speed (``wall_s``) and
    reports it (``kernel_load_s``), as it leaves out the imports."""
    import time

    from conftest import REPO_ROOT

    from uavest.apps.replay import ReplayConfig, replay
    from uavest.geometry.rotation import MANIFOLD_KERNELS

    k = _kernels(_slow_cases)
    assert k.get() is not None and k.load_s >= 0.3
    t = k.load_s
    k.get()
    assert k.load_s == t  # (only the first)
    monkeypatch.setitem(compiled.REGISTRY, "fake", k)
    assert compiled.load_seconds() >= t

    log = str(REPO_ROOT / "logs" / "sim_200hz.tlog")
    cfg = ReplayConfig(filters=("ekf",), start=0.0, end=5.0)
    replay(log, cfg)  # (everything else loaded)
    slow = Kernels("manifold", MANIFOLD_KERNELS.module, "slow manifold", _slow_cases,
                   1.0, 1.0, "uavest.test")
    monkeypatch.setattr(MANIFOLD_KERNELS, "loaded", None)
    monkeypatch.setattr(MANIFOLD_KERNELS, "cases", slow.cases)
    t0 = time.perf_counter()
    doc = replay(log, cfg)
    total = time.perf_counter() - t0
    assert MANIFOLD_KERNELS.loaded
    assert doc["kernel_load_s"] >= 0.3
    assert doc["wall_s"] <= total - doc["kernel_load_s"]
    assert replay(log, cfg)["kernel_load_s"] == 0.0  # (loaded by then)
