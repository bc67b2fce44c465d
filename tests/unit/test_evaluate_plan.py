"""uavest.fleet without worker processes: discovery, keys, the store, rows and tables."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from uavest.fleet import build_plan, discover_logs, plan_trials
from uavest.fleet.backends import _signal_text, reason_of
from uavest.fleet.html import render_html
from uavest.fleet.plan import Input
from uavest.fleet.run import summarize, terminal_report
from uavest.fleet.store import ResultStore, write_atomic
from uavest.fleet.summary import aggregate_csv, group_summary, log_row, rows_csv
from uavest.ingest.types import IngestError

REPO = Path(__file__).resolve().parents[2]


def _touch(p: Path, data: bytes = b"x") -> Path:
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data)
    return p


def test_discovery_folders_globs_and_files(tmp_path):
    a = _touch(tmp_path / "f" / "a.tlog", b"a")
    b = _touch(tmp_path / "f" / "deep" / "er" / "b.BIN", b"b")
    c = _touch(tmp_path / "f" / "c.Ulg", b"c")
    _touch(tmp_path / "f" / "readme.txt")
    odd = _touch(tmp_path / "odd.log", b"o")
    assert set(discover_logs([str(tmp_path / "f")])) == {a, b, c}
    assert discover_logs([str(tmp_path / "f" / "**" / "*.BIN")]) == [b]
    # an explicit file of any name; the same file twice is one input
    assert discover_logs([str(odd), str(a), str(a)]) == [odd, a]
    with pytest.raises(ValueError, match="no such file, folder or scenario"):
        discover_logs([str(tmp_path / "missing.tlog")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no .tlog, .bin or .ulg"):
        discover_logs([str(tmp_path / "empty")])
    with pytest.raises(ValueError, match="matches no log"):
        discover_logs([str(tmp_path / "*.nothing")])


def test_log_keys_follow_content_and_resolved_configuration(tmp_path):
    src = REPO / "logs" / "sim_200hz.tlog"
    a = tmp_path / "a.tlog"
    shutil.copy(src, a)
    b = tmp_path / "sub" / "renamed.tlog"
    b.parent.mkdir()
    shutil.copy(src, b)
    c = tmp_path / "c.tlog"
    data = bytearray(src.read_bytes())
    data[-1] ^= 1
    c.write_bytes(bytes(data))
    p = build_plan([str(a), str(b), str(c)])
    ka, kb, kc = (i.key for i in p.inputs)
    assert ka == kb != kc
    assert p.inputs[1].duplicate_of == str(a)
    assert len(p.tasks()) == 2
    cfg = p.configs["logs"]
    assert [f["label"] for f in cfg["filters"]] == ["ekf", "ukf", "hybrid"]
    assert cfg["filters"][2]["params"]["n_cloud"] == 16  # the attitude preset, resolved
    same = build_plan([str(a)])
    assert same.inputs[0].key == ka
    for other in (build_plan([str(a)], filters=["ekf", "ukf", "hybrid(tau=0.5)"]),
                  build_plan([str(a)], replay={"end": 10.0}),
                  build_plan([str(a)], seed=1)):
        assert other.inputs[0].key.split("-")[0] == ka.split("-")[0]  # same content
        assert other.inputs[0].key != ka


def test_unreadable_log_fails_at_plan_time(tmp_path, monkeypatch):
    p = _touch(tmp_path / "x.tlog")
    import uavest.fleet.plan as plan_mod

    def boom(path, chunk=0):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(plan_mod, "file_sha256", boom)
    (inp,) = build_plan([str(p)]).inputs
    assert inp.task is None and inp.error == "unreadable: Permission denied"


def test_shards_cover_the_trials_and_key_on_scenario_content(tmp_path):
    p = plan_trials("ungm", 10, seed=3, shard_size=4, filters=["ekf", "enkf", "hybrid"])
    assert [(t.lo, t.hi) for t in p.tasks()] == [(0, 4), (4, 8), (8, 10)]
    assert [i.name for i in p.inputs] == ["ungm[0:4]", "ungm[4:8]", "ungm[8:10]"]
    # the bench preset: EnKF gets the hybrid's member count
    specs = {f["label"]: f for f in p.configs["mc:ungm"]["filters"]}
    assert specs["enkf"]["params"]["members"] == 99
    copy = tmp_path / "my_ungm.toml"
    shutil.copy(REPO / "uavest" / "scenarios" / "ungm.toml", copy)
    p2 = plan_trials(str(copy), 10, seed=3, shard_size=4, filters=["ekf", "enkf", "hybrid"])
    # the same parameters under another name are another scenario (the name is content);
    # the file's path is not part of the key
    assert p2.inputs[0].key != p.inputs[0].key
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    shutil.copy(copy, moved / "my_ungm.toml")
    p3 = plan_trials(str(moved / "my_ungm.toml"), 10, 3, 4, ["ekf", "enkf", "hybrid"])
    assert p3.inputs[0].key == p2.inputs[0].key
    assert plan_trials("ungm", 10, 3, 4, ["ekf", "enkf", "hybrid"]).inputs[0].key == \
        p.inputs[0].key
    assert plan_trials("ungm", 10, 4, 4, ["ekf", "enkf", "hybrid"]).inputs[0].key != \
        p.inputs[0].key
    assert plan_trials("ungm", 10, 3, 4, ["ekf", "enkf", "hybrid"],
                       sets=["model.Q=5"]).inputs[0].key != p.inputs[0].key
    with pytest.raises(ValueError, match="radar scenario"):
        plan_trials("radar_far", 2)
    with pytest.raises(ValueError, match="--trials must be >= 1"):
        plan_trials("ungm", 0)


def test_store_writes_whole_files_only(tmp_path, monkeypatch):
    s = ResultStore(tmp_path)
    s.save("k", {"a": float("nan"), "b": 1})
    d = s.load("k")
    assert d["a"] is None and d["nulls"] == {"/a": "not computable"}
    (s.dir / ".tmp-stale.json-1").write_text("{")
    (s.dir / "bad.json").write_text("{")
    s2 = ResultStore(tmp_path)
    assert not list(s2.dir.glob(".tmp-*")) and s2.load("bad") is None

    import os

    def interrupted(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_atomic(s.dir / "z.json", "{}")
    assert not (s.dir / "z.json").exists() and not list(s.dir.glob(".tmp-*"))


def _doc(rmse: dict[str, tuple], status="ok", reason=None, ref="SIMSTATE") -> dict:
    filters = {lab: {"roll_rmse_deg": r[0], "pitch_rmse_deg": r[1], "yaw_rmse_deg": r[2],
                     "nees_mean": 1.0, "resets": 0, "us_per_step": 10.0}
               for lab, r in rmse.items()}
    return {"status": status, "reason": reason, "attempts": 1, "result": {
        "format": "tlog", "duration_s": 10.0, "imu_source": "RAW_IMU", "imu_rate_hz": 200.0,
        "reference": ref, "reference_kind": "truth", "steps": 250,
        "bad_data": {"bad_total": 2, "corrupt": 2, "messages": {}}, "realtime_factor": 5.0,
        "wall_s": 2.0, "filters": filters}}


CONFIG = {"filters": [{"label": "ekf"}, {"label": "ukf"}]}


def test_rows_aggregate_wins_and_duplicates():
    inputs = [Input("a.tlog", "log", "logs", "ka", "ha"),
              Input("b.tlog", "log", "logs", "kb", "hb"),
              Input("c.tlog", "log", "logs", "kc", "hc"),
              Input("a-copy.tlog", "log", "logs", "ka", "ha", duplicate_of="a.tlog"),
              Input("gone.tlog", "log", "logs", None, None, error="unreadable: denied")]
    docs = {"ka": _doc({"ekf": (1, 1, 1), "ukf": (2, 2, 2)}),
            "kb": _doc({"ekf": (3, 3, 3), "ukf": (1, 2, 2)}),
            "kc": {"status": "failed", "failure": "error", "attempts": 1,
                   "reason": "c.tlog: empty file (expected a .tlog, .bin or .ulg log)"}}
    g = group_summary("logs", inputs, docs, CONFIG, "h")
    rows = {r["input"]: r for r in g["rows"]}
    assert rows["a.tlog"]["winner"] == "ekf" and rows["b.tlog"]["winner"] == "ukf"
    assert rows["a.tlog"]["filters"]["ukf"]["att_rmse_deg"] == pytest.approx(2.0)
    assert rows["c.tlog"]["reason"] == "empty file (expected a .tlog, .bin or .ulg log)"
    assert rows["gone.tlog"]["reason"] == "unreadable: denied"
    a = g["aggregate"]
    assert a["ekf"]["logs"] == 2  # the copy counts once
    assert a["ekf"]["att_rmse_mean"] == pytest.approx(2.0)
    assert a["ekf"]["att_rmse_worst"] == pytest.approx(3.0)
    assert a["ekf"]["roll_rmse_median"] == pytest.approx(2.0)
    assert (a["ekf"]["wins"], a["ukf"]["wins"]) == (1, 1)
    assert (g["ok"], g["failed"], g["duplicates"]) == (3, 2, 1)
    csv = rows_csv({"logs": g})
    assert "gone.tlog" in csv and "unreadable: denied" in csv
    assert csv.count("\n") == 1 + 2 * 3 + 2  # header, 3 ok x 2 filters, 2 failed
    assert aggregate_csv({"logs": g}).splitlines()[1].startswith("logs,ekf,2,")


def test_a_log_without_reference_has_no_winner_and_nulls():
    inp = Input("n.tlog", "log", "logs", "k", "h")
    d = _doc({"ekf": (float("nan"),) * 3, "ukf": (float("nan"),) * 3}, ref=None)
    r = log_row(inp, d, ["ekf", "ukf"])
    assert r["winner"] is None and r["filters"]["ekf"]["att_rmse_deg"] is None


def test_report_documents_render(tmp_path):
    from uavest.fleet.plan import Plan

    inputs = [Input("<b>a.tlog", "log", "logs", "ka", "ha"),
              Input("z.tlog", "log", "logs", None, None, error="unreadable: denied")]
    plan = Plan(inputs, {"logs": CONFIG}, {"logs": "0" * 64})
    s = summarize(plan, {"ka": _doc({"ekf": (1, 1, 1), "ukf": (2, 2, 2)})})
    html = render_html(s, tmp_path)
    assert "&lt;b&gt;a.tlog" in html and "<b>a.tlog" not in html
    assert "unreadable: denied" in html and html.startswith("<!DOCTYPE html>")
    json.dumps(s, allow_nan=False)
    text = terminal_report(s)
    assert "z.tlog: unreadable: denied" in text and "att_rmse_mean" in text
    rec = tmp_path / "reports" / "<b>a" / "index.html"
    rec.parent.mkdir(parents=True)
    rec.write_text("x")
    assert "recording report" in render_html(s, tmp_path)


def test_failure_reasons():
    assert reason_of(IngestError("x.tlog: empty file")) == "x.tlog: empty file"
    assert reason_of(ZeroDivisionError("division by zero")) == \
        "ZeroDivisionError: division by zero"
    assert reason_of(RuntimeError()) == "RuntimeError"
    assert _signal_text(-9) == "worker died (signal 9, SIGKILL)"
    assert _signal_text(3) == "worker died (exit code 3)"


class _Bar:
    def __init__(self):
        self.n, self.total, self.posts, self.shown = 0, None, [], []

    def reset(self, total):
        self.total = total

    def update(self, k):
        self.n += k
        self.shown.append((self.n, self.posts[-1]))  # what a line printer prints now

    def set_postfix_str(self, s):
        self.posts.append(s)


def test_progress_counts_done_failed_remaining(tmp_path, monkeypatch):
    from uavest.fleet import SerialBackend, execute

    plan = plan_trials("ungm", 3, shard_size=1, steps=2, filters=["ekf"])
    execute(plan_trials("ungm", 1, shard_size=1, steps=2, filters=["ekf"]), tmp_path,
            SerialBackend())  # trial 0 stored already
    import uavest.fleet.worker as w

    real = w._run_shard

    def flaky(task):
        if task.lo == 2:
            raise RuntimeError("boom")
        return real(task)

    monkeypatch.setattr(w, "_run_shard", flaky)
    bar = _Bar()
    _, st = execute(plan, tmp_path, SerialBackend(), bar=bar)
    assert (bar.total, bar.n, st.skipped, st.computed, st.failed) == (2, 2, 1, 2, 1)
    assert bar.posts[0] == "done 0, failed 0, remaining 2, reused 1"
    assert bar.posts[-1] == "done 1, failed 1, remaining 0, reused 1"
    # the line printed at each update already counts that task (it said "1/2, done 0,
    # ... remaining 2" when the postfix came after the update)
    for n, post in bar.shown:
        done, failed, left = (int(x.split()[-1]) for x in post.split(", ")[:3])
        assert done + failed == n and left == bar.total - n, (n, post)
