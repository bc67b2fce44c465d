"""``uavest evaluate``: same numbers on every backend, failures per input, resume."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import pytest
from evaluate_fixtures import REPO, cli_env, evaluate_cmd, make_windows, numbers, run_cli

from uavest.fleet import (
    PoolBackend,
    SerialBackend,
    build_plan,
    evaluate,
    execute,
)

MC = dict(trials=12, shard_size=3, filters=["ekf", "ukf", "hybrid"], steps=30, seed=2)


@pytest.fixture(scope="module")
def windows(tmp_path_factory):
    return make_windows(tmp_path_factory.mktemp("logs"), 3)


def _stored(out) -> dict:
    return {p.stem: json.loads(p.read_text()) for p in (out / "results").glob("*.json")}


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert numbers(a[k]) == numbers(b[k]), k


@pytest.mark.slow
def test_same_numbers_serial_pool_and_dask_threads(tmp_path, windows):
    distributed = pytest.importorskip("distributed")
    from uavest.fleet import DaskBackend

    inputs = [str(w) for w in windows]
    ser = evaluate(inputs, tmp_path / "serial", workers=0)
    mc_ser = evaluate(["ungm"], tmp_path / "mc-serial", workers=0, **MC)
    pool = PoolBackend(2)
    evaluate(inputs, tmp_path / "pool", backend=pool)
    evaluate(["ungm"], tmp_path / "mc-pool", backend=pool, **MC)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        dask = DaskBackend(client)
        evaluate(inputs, tmp_path / "dask", backend=dask)
        evaluate(["ungm"], tmp_path / "mc-dask", backend=dask, **MC)
    assert ser["counts"]["ok"] == 3 and not ser["failures"]
    assert mc_ser["groups"]["mc:ungm"]["trials_evaluated"] == 12
    for other in ("pool", "dask"):
        _same(_stored(tmp_path / "serial"), _stored(tmp_path / other))
        _same(_stored(tmp_path / "mc-serial"), _stored(tmp_path / f"mc-{other}"))
        s = json.loads((tmp_path / f"mc-{other}" / "summary.json").read_text())
        assert numbers(s["groups"]) == numbers(mc_ser["groups"])


@pytest.mark.slow
def test_shards_give_the_bench_table(tmp_path):
    """The aggregate of the shards is the table of one bench run over the same trials."""
    from uavest.experiments.montecarlo import evaluate as bench
    from uavest.experiments.systems import build_system
    from uavest.scenarios import load_scenario

    s = evaluate(["ungm"], tmp_path, workers=0, **MC)
    sc = load_scenario("ungm")
    sc["steps"] = 30
    ref = bench(build_system(sc), MC["filters"], 12, MC["seed"])
    agg = s["groups"]["mc:ungm"]["aggregate"]
    for lab in MC["filters"]:
        for k in ("rmse_mean", "rmse_median", "nees_mean", "diverged_fraction", "resets"):
            assert agg[lab][k] == ref[lab][k], (lab, k)
    assert sum(a["wins"] for a in agg.values()) == 12


@pytest.mark.slow
def test_bad_logs_are_listed_with_their_reason(tmp_path, windows):
    folder = tmp_path / "flights"
    (folder / "day2").mkdir(parents=True)
    (folder / "a.tlog").write_bytes(windows[0].read_bytes())
    (folder / "day2" / "b.TLOG").write_bytes(windows[1].read_bytes())
    (folder / "empty.ulg").write_bytes(b"")
    (folder / "day2" / "corrupt.bin").write_bytes(bytes(range(256)) * 300)
    (folder / "notes.txt").write_text("not a log")
    s = evaluate([str(folder)], tmp_path / "out", workers=2)
    rows = {r["input"].split("/")[-1]: r for r in s["groups"]["logs"]["rows"]}
    assert set(rows) == {"a.tlog", "b.TLOG", "empty.ulg", "corrupt.bin"}
    assert rows["a.tlog"]["status"] == rows["b.TLOG"]["status"] == "ok"
    assert rows["a.tlog"]["filters"]["hybrid"]["att_rmse_deg"] > 0
    assert rows["empty.ulg"]["status"] == "failed"
    assert rows["empty.ulg"]["reason"].startswith("empty file")
    assert rows["corrupt.bin"]["status"] == "failed"
    assert "not an ArduPilot DataFlash log" in rows["corrupt.bin"]["reason"]
    assert {f["input"].split("/")[-1] for f in s["failures"]} == {"empty.ulg", "corrupt.bin"}
    assert s["groups"]["logs"]["aggregate"]["ekf"]["logs"] == 2
    html = (tmp_path / "out" / "report.html").read_text()
    assert "empty file" in html and "<svg" in html
    csv = (tmp_path / "out" / "rows.csv").read_text()
    assert "corrupt.bin" in csv and "empty.ulg" in csv


@pytest.mark.slow
def test_rerun_skips_and_changed_configuration_recomputes(tmp_path, windows):
    inputs = [str(w) for w in windows[:2]]
    plan = build_plan(inputs)
    _, st = execute(plan, tmp_path, SerialBackend())
    assert (st.computed, st.skipped) == (2, 0)
    _, st = execute(build_plan(inputs), tmp_path, SerialBackend())
    assert (st.computed, st.skipped) == (0, 2)
    # a renamed copy has the same content: its stored result is used
    moved = tmp_path / "moved.tlog"
    moved.write_bytes(windows[0].read_bytes())
    _, st = execute(build_plan([str(moved)]), tmp_path, SerialBackend())
    assert (st.computed, st.skipped) == (0, 1)
    # a filter parameter or a replay option changes the key
    _, st = execute(build_plan(inputs, filters=["ekf", "hybrid(n_cloud=8)"]), tmp_path,
                    SerialBackend())
    assert (st.computed, st.skipped) == (2, 0)
    _, st = execute(build_plan(inputs, replay={"rate_hz": 20.0}), tmp_path, SerialBackend())
    assert (st.computed, st.skipped) == (2, 0)
    # a failed input is not retried unless asked; results are complete JSON files only
    assert not list((tmp_path / "results").glob(".tmp-*"))


@pytest.mark.slow
def test_interrupted_run_resumes_with_only_the_rest(tmp_path):
    """SIGINT half-way through a pool run; the rerun computes exactly the missing shards
    and leaves the earlier results untouched; the table equals an uninterrupted run's."""
    out = tmp_path / "out"
    args = ["ungm", "--trials", "48", "--shard-size", "2", "--steps", "60", "--seed", "5",
            "--filters", "ekf,ukf,hybrid", "--workers", "2", "--out", str(out),
            "--no-progress"]
    proc = subprocess.Popen(evaluate_cmd() + args, env=cli_env(), cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    res = out / "results"
    while time.time() < deadline and len(list(res.glob("*.json")) if res.is_dir() else []) < 8:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    first = _stored(out)
    assert 8 <= len(first) < 24, len(first)  # interrupted part-way
    assert not list(res.glob(".tmp-*"))
    mtimes = {p.name: p.stat().st_mtime_ns for p in res.glob("*.json")}
    r = run_cli(args)
    assert r.returncode == 0, r.stderr
    after = _stored(out)
    assert len(after) == 24
    s = json.loads((out / "summary.json").read_text())
    assert s["counts"]["computed"] == 24 - len(first)
    assert s["counts"]["reused"] == len(first)
    run_ids = {d["run_id"] for k, d in after.items() if k not in first}
    assert len(run_ids) == 1 and run_ids.isdisjoint({d["run_id"] for d in first.values()})
    assert {p.name: p.stat().st_mtime_ns for p in res.glob("*.json")
            if p.name in mtimes} == mtimes
    whole = evaluate(["ungm"], tmp_path / "whole", workers=0, trials=48, shard_size=2,
                     steps=60, seed=5, filters=["ekf", "ukf", "hybrid"])
    assert numbers(s["groups"]) == numbers(whole["groups"])


@pytest.mark.slow
def test_pool_worker_killed_every_time_is_reported_and_others_finish(tmp_path, monkeypatch):
    monkeypatch.setenv("UAVEST_EVALUATE_CRASH_ON", "ungm*3:6*")
    s = evaluate(["ungm"], tmp_path, backend=PoolBackend(2), **MC)
    g = s["groups"]["mc:ungm"]
    assert (g["ok"], g["failed"], g["trials_evaluated"]) == (3, 1, 9)
    (fail,) = s["failures"]
    assert fail["input"] == "ungm[3:6]"
    assert fail["reason"] == "worker died (signal 9, SIGKILL)"
    assert fail["attempts"] == 2
    # its neighbour that was running when the pool broke was rerun and is ok
    ok = {r["input"] for r in g["rows"] if r["status"] == "ok"}
    assert ok == {"ungm[0:3]", "ungm[6:9]", "ungm[9:12]"}
    # a worker death is not a stored verdict: the next run tries it again
    monkeypatch.delenv("UAVEST_EVALUATE_CRASH_ON")
    s2 = evaluate(["ungm"], tmp_path, workers=0, **MC)
    assert (s2["counts"]["computed"], s2["counts"]["ok"]) == (1, 4)


@pytest.mark.slow
def test_dask_processes_worker_killed_mid_task(tmp_path, monkeypatch):
    """A LocalCluster of worker processes (the CLI's --scheduler local): a task that
    kills its worker every time is reported, the others finish with the serial numbers."""
    pytest.importorskip("distributed")
    from uavest.fleet import DaskBackend

    monkeypatch.setenv("UAVEST_EVALUATE_CRASH_ON", "ungm*3:6*")
    dask = DaskBackend.connect("local", workers=2)
    try:
        s = evaluate(["ungm"], tmp_path / "dask", backend=dask, **MC)
    finally:
        dask.close()
    g = s["groups"]["mc:ungm"]
    assert (g["ok"], g["failed"]) == (3, 1)
    (fail,) = s["failures"]
    assert fail["input"] == "ungm[3:6]" and fail["reason"].startswith("worker died")
    monkeypatch.delenv("UAVEST_EVALUATE_CRASH_ON")
    evaluate(["ungm"], tmp_path / "serial", workers=0, **MC)
    a, b = _stored(tmp_path / "dask"), _stored(tmp_path / "serial")
    for k, d in a.items():
        if d["status"] == "ok":
            assert numbers(d) == numbers(b[k])


@pytest.mark.slow
def test_cli_errors_are_one_line(tmp_path):
    r = run_cli([str(tmp_path / "nothing-here"), "--out", str(tmp_path / "o")])
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "no such file, folder or scenario" in r.stderr
    r = run_cli(["ungm", "--trials", "2", "--filters", "ekf,nosuch", "--out",
                 str(tmp_path / "o")])
    assert r.returncode == 2 and "nosuch" in r.stderr and r.stderr.count("\n") == 1


def test_scheduler_without_dask_installed_is_a_clear_error(tmp_path):
    code = ("import sys; sys.modules['dask'] = None; sys.modules['distributed'] = None; "
            "from uavest.cli.evaluate import main; "
            f"sys.exit(main(['ungm', '--trials', '2', '--scheduler', 'tcp://127.0.0.1:1', "
            f"'--out', {str(tmp_path)!r}]))")
    r = subprocess.run([__import__("sys").executable, "-c", code], capture_output=True,
                       text=True, env=cli_env(), cwd=REPO, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip() == ("uavest evaluate: error: --scheduler needs Dask: "
                                "pip install 'uavest[dask]'")


@pytest.mark.slow
def test_cli_on_a_local_dask_cluster_prints_the_dashboard(tmp_path):
    pytest.importorskip("distributed")
    r = run_cli(["ungm", "--trials", "4", "--shard-size", "2", "--steps", "10", "--filters",
                 "ekf,ukf", "--scheduler", "local", "--workers", "1", "--out",
                 str(tmp_path), "--no-progress"])
    assert r.returncode == 0, r.stderr
    assert "dask dashboard: http://127.0.0.1:" in r.stdout
    assert "ungm: 4 of 4 trials" in r.stdout
    assert (tmp_path / "report.html").is_file() and (tmp_path / "aggregate.csv").is_file()


@pytest.mark.slow
def test_logs_run_the_model_replay_chooses_and_score_velocity_and_position(tmp_path, windows):
    """Under the default (auto) a log with a GNSS fix stream runs the navigation model, as
    ``uavest replay`` does, and its rows and aggregate carry velocity and position RMSE;
    ``--model attitude`` gives the attitude-only rows without them."""
    for model, nav in (("auto", True), ("attitude", False)):
        out = tmp_path / model
        r = run_cli([str(windows[0]), "--workers", "0", "--filters", "ekf", "--out", str(out),
                     "--no-progress", "--model", model])
        assert r.returncode == 0, r.stderr
        logs = json.loads((out / "summary.json").read_text())["groups"]["logs"]
        row = logs["rows"][0]
        assert row["model"] == ("nav" if nav else "attitude")
        f = row["filters"]["ekf"]
        assert (f["vel_rmse_ms"] is not None) is nav and (f["hpos_rmse_m"] is not None) is nav
        agg = logs["aggregate"]["ekf"]
        assert (agg["vel_rmse_ms_mean"] is not None) is nav
        if nav:
            assert 0 < f["vel_rmse_ms"] < 1.0, f  # the simulator's window, not diverged
