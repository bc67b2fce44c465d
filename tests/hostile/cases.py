"""The hostile corpus: cases over every class the issue names, and a runner that runs one
case as a child process (timeout, memory measured with ``wait4``) and classifies it.

A case is a dict: ``name``, ``cls`` (the class of input), ``argv`` (after ``-m uavest``;
``{f}`` is replaced by the case's input file, ``{d}`` by its directory), ``data`` (bytes
of the input file, or a callable making it, or None), ``expect``: ``"error"`` (bad input:
exit 2 with a one-line message), ``"ok"`` (valid: exit 0) or ``"either"`` (a damaged log:
exit 0 with the damage counted, or exit 2 with a message), and ``light`` (a lightly
corrupted log whose RMSE must stay within 10 % of ``base``'s or be flagged).
Outcomes: ``clear_error``, ``recovered`` (exit 0, damage counted or flagged),
``ok`` (valid input run), ``unaffected`` (exit 0, nothing counted, the clean
result: the damage hit unused bytes), ``uncounted`` (exit 0 on a damaged log, nothing counted),
``traceback``, ``hang``, ``over_1gb``, ``invalid_accepted``, ``wrong_unflagged``,
``valid_refused``, ``bad_message`` (exit 2 without a one-line ``uavest ...: error:``).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

from . import corpus as C

ROOT = Path(__file__).resolve().parents[2]
GB = 1 << 30
RMSE_REL = 0.10  # lightly corrupted logs: within 10 % of the clean RMSE...
RMSE_ABS = 0.05  # ... or 0.05 deg (below the references' own accuracy)


def _bases() -> dict[str, bytes]:
    """The clean inputs: a part of vtol.tlog cut at a record boundary, test.BIN, and
    sample_px4_events.ulg."""
    L = C.logs_dir()
    t = (L / "vtol.tlog").read_bytes()
    recs = C.tlog_records(t)
    cut = recs[len(recs) * 2 // 5]
    return {
        "tlog": t[: cut[0]],
        "bin": (L / "test.BIN").read_bytes(),
        "ulog": (L / "sample_px4_events.ulg").read_bytes(),
    }


EXT = {"tlog": ".tlog", "bin": ".bin", "ulog": ".ulg"}
HEADER = {"tlog": 0, "bin": 8000, "ulog": None}  # ULog: up to the data section


def log_cases(full: bool = True) -> list[dict]:
    b = _bases()
    out: list[dict] = []

    def add(name, cls, fmt, data, expect="either", light=False, extra=()):
        out.append({"name": f"{fmt}:{name}", "cls": cls, "fmt": fmt, "data": data,
                    "ext": EXT[fmt], "expect": expect, "light": light, "base": fmt,
                    "argv": ["replay", "{f}", "--filters", "ekf", "--no-progress",
                             "--json", "{d}/out.json", *extra]})

    for fmt, d in b.items():
        add("clean", "clean log", fmt, d, expect="ok")
        for fr in (0.01, 0.1, 0.33, 0.5, 0.77, 0.95, 0.999):
            add(f"truncate {fr}", "truncation", fmt, C.truncate(d, fr))
        hdr = HEADER[fmt] if HEADER[fmt] is not None else C.ulog_data_start(d)
        for seed in range(6 if full else 2):
            add(f"flip 1e-4 s{seed}", "byte flips 1e-4", fmt,
                C.flip_bits(d, 1e-4, seed, skip=hdr), light=True)
        for seed in range(3 if full else 1):
            add(f"flip 1e-3 s{seed}", "byte flips 1e-3", fmt, C.flip_bits(d, 1e-3, seed, skip=hdr))
        add("flip 1e-2", "byte flips 1e-2", fmt, C.flip_bits(d, 1e-2, 9, skip=hdr))
        add("splice self", "splice", fmt, C.splice(d, d, 0.6, 0.3))
        add("splice cut", "splice", fmt, C.splice(d, d, 0.4, 0.61))
        other = b["ulog" if fmt != "ulog" else "tlog"]
        add("splice other format", "splice", fmt, C.splice(d, other, 0.5, 0.5))
        add("duplicate section", "duplicate/reorder", fmt, C.duplicate_section(d, 0.3, 0.5))
        add("duplicate tail", "duplicate/reorder", fmt, C.duplicate_section(d, 0.8, 1.0))
        add("swap sections", "duplicate/reorder", fmt, C.swap_sections(d, 0.2, 0.4, 0.6))
        add("swap halves", "duplicate/reorder", fmt, C.swap_sections(d, 0.0, 0.5, 1.0))
        add("concatenated with itself", "clock jump", fmt, d + d)
        for size, seed in ((100_000, 1), (2_000_000, 2)):
            h = max(hdr, 64)
            add(f"random {size} after header", "random after header", fmt,
                C.random_after_header(d, h, size, seed))
    # one corrupted time stamp
    t = b["tlog"]
    for mid, which in ((30, 10), (30, 300), (178, 50), (164, 50), (27, 100), (0, 5)):
        add(f"rx top bit msg {mid} #{which}", "one bad time stamp", "tlog",
            C.flip_tlog_rx_top_bit(t, mid, which), light=True)
    u = b["ulog"]
    for topic, which, how in (("sensor_combined", 500, "top"), ("sensor_combined", 3000, "zero"),
                              ("vehicle_attitude", 50, "top"), ("sensor_mag", 20, "top")):
        ts = C.ulog_timestamp(u, topic, which)
        v = ts | (1 << 62) if how == "top" else 0
        add(f"ts {topic} #{which} {how}", "one bad time stamp", "ulog",
            C.ulog_set_timestamp(u, topic, which, v), light=True)
    d = b["bin"]
    for name, which, delta in (("IMU", 20, 5_000_000), ("IMU", 30, -5_000_000),
                               ("ATT", 10, 1 << 50)):
        ts = C.df_time(d, name, which)
        add(f"TimeUS {name} #{which} {delta:+d}", "one bad time stamp", "bin",
            C.df_set_time(d, name, which, max(0, ts + delta)))
    add("corrupt parameter", "partial log", "ulog", C.ulog_corrupt_param(u, 3))
    add("corrupt parameter 2", "partial log", "ulog", C.ulog_corrupt_param(u, 40))
    add("header only", "truncation", "ulog", u[: C.ulog_data_start(u) + 10])
    add("magic only", "truncation", "ulog", u[:16])
    return out


def _file_cases() -> list[dict]:
    rnd = C.random_after_header(b"", 0, 300_000, 5)
    cases = [
        ("empty file", b"", ".tlog"), ("zeros", bytes(1 << 20), ".bin"),
        ("random bytes", rnd, ".tlog"), ("random .ulg", rnd, ".ulg"),
        ("text file", b"hello, world\n" * 1000, ".log"),
        ("ULog magic + random", b"ULog\x01\x12\x35\x01" + bytes(8) + rnd, ".ulg"),
        ("DataFlash magic + random", b"\xa3\x95\x80" + rnd, ".bin"),
    ]
    out = [{"name": f"file:{n}", "cls": "garbage file", "data": d, "ext": e, "expect": "error",
            "argv": ["replay", "{f}", "--filters", "ekf", "--no-progress"]}
           for n, d, e in cases]
    for n, path in (("FIFO", "{d}/fifo.tlog"), ("/dev/zero", "/dev/zero"),
                    ("/dev/null", "/dev/null"), ("directory", "{d}"),
                    ("missing", "{d}/missing.tlog"), ("symlink loop", "{d}/loop.tlog")):
        out.append({"name": f"special:{n}", "cls": "special file", "data": None,
                    "special": n, "expect": "error",
                    "argv": ["replay", path, "--filters", "ekf", "--no-progress"]})
    return out


def _option_cases() -> list[dict]:
    log = str(C.logs_dir() / "sample_px4_events.ulg")
    R = ["replay", log, "--no-progress", "--end", "1e12"]
    bad_replay = [
        ["--declination", "nan"], ["--declination", "inf"], ["--declination", "1e9"],
        ["--declination", "abc"], ["--noise", "gyro_noise=nan"], ["--noise", "gyro_noise=-1"],
        ["--noise", "gyro_noise=abc"], ["--noise", "nosuch=1"], ["--noise", "gyro_noise"],
        ["--noise", "gyro_noise=inf"], ["--mag-delay", "-100"], ["--mag-delay", "nan"],
        ["--mag-delay", "1e9"], ["--rate", "-1"], ["--rate", "nan"], ["--start", "nan"],
        ["--update-rate", "-1"], ["--update-rate", "nan"], ["--update-rate", "inf"],
        ["--start", "10", "--end", "5"], ["--filters", ""], ["--filters", "ekf,ekf"],
        ["--filters", "kf"], ["--filters", "ukf(alpha=nan)"], ["--filters", "ukf(alpha=0)"],
        ["--filters", "hybrid_sh(b=5)"], ["--filters", "hybrid(n_cloud=0)"],
        ["--filters", "nosuch"], ["--filters", "ukf("], ["--filters", ","],
        ["--seed", "abc"], ["--imu", "NOSUCH"], ["--start", "1e13"],
        ["--integration", "magic"], ["--mag-mode", "x"],
    ]
    out = [{"name": f"replay {' '.join(a)!r}", "cls": "bad replay option", "data": None,
            "expect": "error", "argv": R + a + (["--filters", "ekf"]
                                                     if "--filters" not in a else [])}
           for a in bad_replay]
    B = ["bench", "--no-progress"]
    bad_bench = [
        ["--runs", "0"], ["--runs", "-1"], ["--runs", "1000000000"], ["--runs", "abc"],
        ["--runs", "2.5"], ["--steps", "0"], ["--steps", "2.5"], ["--steps", "-3"],
        ["--filters", ""], ["--filters", "ekf,ekf"], ["--filters", "kf"],
        ["--filters", "hybrid(n_cloud=0)"], ["--filters", "ukf(alpha=nan)"],
        ["--set", "model.Q=nan"], ["--set", "model.R=inf"], ["--set", "steps=2.5"],
        ["--set", "runs=0"], ["--set", "filters=ukf"], ["--set", "noequals"],
        ["--set", "=5"], ["--set", "model.Q=-1"], ["--set", "prior.filter_var=[-1.0]"],
        ["nosuch_scenario"], ["{d}/missing.toml"],
        ["radar_multitarget", "--runs", "1000000"], ["--runs", "100000000", "--steps", "1000"],
        ["radar_crossing", "--set", "radar.pd=7.5"],
        ["radar_crossing", "--set", "radar.clutter_rate=-3"],
        ["radar_crossing", "--set", "radar.clutter_rate=1e7"],
        ["radar_crossing", "--set", "prior.mean=[1.0, 2.0]"],
        ["radar_crossing", "--set", "motion.model=zigzag"],
        ["radar_crossing", "--filters", "kf"],
    ]
    for a in bad_bench:
        out.append({"name": f"bench {' '.join(a)!r}", "cls": "bad bench option/--set",
                    "data": None, "expect": "error", "argv": B + a})
    T = ["track", "radar_multitarget", "--no-progress"]
    bad_track = [
        ["--set", "steps=-1"], ["--set", "steps=0"], ["--set", "radar.pd=7.5"],
        ["--set", "radar.clutter_rate=-3"], ["--set", "radar.clutter_rate=1e7"],
        ["--set", "prior.mean=[1.0]"], ["--set", "motion.model=zigzag"],
        ["--set", 'tracker.confirm_m="four"'], ["--set", "tracker.confirm_m=2.5"],
        ["--set", "motion.q=nan"], ["--set", "filters=ukf"], ["--filters", "kf"],
        ["--filters", "ekf,ekf"], ["--filters", ""], ["--set", "ndim=7"],
        ["--set", "tracker.gate_prob=2"],
    ]
    for a in bad_track:
        out.append({"name": f"track {' '.join(a)!r}", "cls": "bad track option/--set",
                    "data": None, "expect": "error", "argv": T + a})
    out.append({"name": "track ungm (not radar)", "cls": "bad track option/--set",
                "data": None, "expect": "error", "argv": ["track", "ungm"]})
    # scenario files
    toml_base = (ROOT / "uavest" / "scenarios" / "radar_multitarget.toml").read_text()
    edits = [
        ("pd = 0.9", "pd = 7.5"), ("clutter_rate = 10.0", "clutter_rate = -3"),
        ("clutter_rate = 10.0", "clutter_rate = 1e7"), ("confirm_m = 4", 'confirm_m = "four"'),
        ("kind = \"radar\"", "kind = \"radar\"\nfilters = \"ukf\""),
        ("[motion]", "[motion]\nmodel = \"zigzag\""), ("pd = 0.9", "pd = nan"),
        ("kind = \"radar\"", "kind = \"radar\"\nsteps = 2.5"), ("[tracker]", "[tracker"),
        ("kind = \"radar\"", "kind = \"radar\"\nruns = 0"),
    ]
    for i, (a, b_) in enumerate(edits):
        txt = toml_base.replace(a, b_, 1)
        for cmd in ("bench", "track"):
            out.append({"name": f"{cmd} toml {b_.splitlines()[-1]!r}", "cls": "bad scenario TOML",
                        "data": txt.encode(), "ext": f"_{i}.toml", "expect": "error",
                        "argv": [cmd, "{f}", "--no-progress"]})
    for cmd, name in (("bench", "R = inf"), ("bench", "Q = nan")):
        txt = (ROOT / "uavest" / "scenarios" / "ungm.toml").read_text()
        key = name.split()[0]
        lines = [ln if not ln.strip().startswith(f"{key} =") else name for ln in txt.splitlines()]
        out.append({"name": f"{cmd} ungm toml {name!r}", "cls": "bad scenario TOML",
                    "data": "\n".join(lines).encode(), "ext": ".toml", "expect": "error",
                    "argv": [cmd, "{f}", "--no-progress"]})
    # valid controls: must run
    for a in (["bench", "ungm", "--runs", "2", "--steps", "5", "--filters", "ekf,ukf"],
              ["bench", "linear_cv", "--runs", "2", "--steps", "5", "--filters", "kf"],
              ["track", "radar_crossing", "--set", "steps=5", "--filters", "ekf"],
              R + ["--filters", "ekf", "--declination", "12"],
              R + ["--filters", "ekf", "--noise", "gyro_noise=0.01"]):
        out.append({"name": f"valid {' '.join(a[:3])}", "cls": "valid control", "data": None,
                    "expect": "ok", "argv": a + (["--no-progress"] if "--no-progress" not in a
                                                   else [])})
    return out


def all_cases(full: bool = True) -> list[dict]:
    """Every case; the ones built from the shared logs only when those are there (so the
    suite collects without them and the log tests skip with the reason)."""
    L = C.logs_dir()
    have = all((L / n).is_file() for n in ("vtol.tlog", "test.BIN", "sample_px4_events.ulg"))
    return (log_cases(full) if have else []) + _file_cases() + _option_cases()


# ------------------------------------------------------------------------------ running


# the child: ``python -m uavest ARGS`` that writes its own peak RSS (KiB) on the way out
_CHILD = """
import os, resource, runpy, sys
def _rss():
    with open(os.environ["UAVEST_HOSTILE_RSS"], "w") as f:
        f.write(str(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss))
import atexit
atexit.register(_rss)
sys.argv = ["uavest"] + sys.argv[1:]
runpy.run_module("uavest", run_name="__main__")
"""


def _limit():
    resource.setrlimit(resource.RLIMIT_AS, (4 * GB, 4 * GB))  # a safety net; RSS is measured


def run(case: dict, workdir: Path, timeout: float = 120.0) -> dict:
    """Run ``case`` in a child process; returns {rc, stderr, stdout, maxrss, secs, doc}."""
    workdir.mkdir(parents=True, exist_ok=True)
    f = workdir / ("input" + case.get("ext", ".dat"))
    if case.get("data") is not None:
        data = case["data"]() if callable(case["data"]) else case["data"]
        f.write_bytes(data)
    sp = case.get("special")
    if sp == "FIFO" and not (workdir / "fifo.tlog").exists():
        os.mkfifo(workdir / "fifo.tlog")
    if sp == "symlink loop" and not (workdir / "loop.tlog").is_symlink():
        os.symlink(workdir / "loop.tlog", workdir / "loop.tlog")
    argv = [a.replace("{f}", str(f)).replace("{d}", str(workdir)) for a in case["argv"]]
    rss_file = workdir / "maxrss"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1",
               OMP_NUM_THREADS="1", UAVEST_HOSTILE_RSS=str(rss_file))
    t0 = time.monotonic()
    p = subprocess.Popen([sys.executable, "-c", _CHILD, *argv], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, env=env,
                         cwd=str(workdir), preexec_fn=_limit)
    try:
        out, err = p.communicate(timeout=timeout)
        hang = False
    except subprocess.TimeoutExpired:
        p.kill()
        out, err = p.communicate()
        hang = True
    try:
        maxrss = int(rss_file.read_text()) * 1024
        rss_file.unlink()
    except (OSError, ValueError):
        maxrss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    doc = None
    j = workdir / "out.json"
    if j.exists():
        try:
            doc = json.loads(j.read_text())
        except ValueError:
            doc = None
        j.unlink()
    return {"rc": p.returncode, "stdout": out.decode("utf-8", "replace"),
            "stderr": err.decode("utf-8", "replace"), "hang": hang,
            "maxrss": maxrss, "secs": time.monotonic() - t0, "doc": doc}


def _errors_one_line(stderr: str) -> bool:
    """One error line (argparse's own usage lines before it are allowed)."""
    lines = [ln for ln in stderr.splitlines() if ln.strip() and ": warning:" not in ln
             and not ln.startswith(("usage:", " "))]
    return len(lines) == 1 and ("error" in lines[0]) and len(lines[0]) <= 400


def _rmse(doc: dict) -> list[float] | None:
    row = (doc or {}).get("filters", {}).get("ekf")
    if not row or not row.get("n"):
        return None
    return [row[k] for k in ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg")]


def classify(case: dict, res: dict, clean: dict | None = None) -> str:
    """The outcome of a run (see the module docstring); ``clean`` is the clean base's
    result document for damaged-log cases."""
    if res["hang"]:
        return "hang"
    if "Traceback" in res["stderr"]:
        return "traceback"
    if res["maxrss"] > GB:
        return "over_1gb"
    rc, exp = res["rc"], case["expect"]
    if rc == 2:
        if not _errors_one_line(res["stderr"]):
            return "bad_message"
        return "valid_refused" if exp == "ok" else "clear_error"
    if rc != 0:
        return "bad_message"
    if exp == "error":
        return "invalid_accepted"
    if exp == "ok":
        return "ok"
    doc = res["doc"] or {}
    flagged = bool(doc.get("unreliable"))
    bad = (doc.get("bad_data") or {}).get("bad_total", 0)
    base_bad = ((clean or {}).get("bad_data") or {}).get("bad_total", 0)
    counted = bad > base_bad or bool(doc.get("repaired")) or flagged
    if case["cls"] == "truncation":  # test.BIN is itself cut: its base counts truncated 1
        counted = counted or (doc.get("bad_data") or {}).get("truncated", 0) > 0
    if flagged:
        return "recovered"
    a, b = _rmse(doc), _rmse(clean or {})
    close = a is not None and b is not None and all(
        abs(x - y) <= max(RMSE_REL * y, RMSE_ABS) for x, y in zip(a, b, strict=True))
    if case.get("light") and not close:
        return "wrong_unflagged"
    if counted:
        return "recovered"
    # nothing counted: harmless only if the result is the clean one (the damage hit
    # bytes that are not used, or a cut fell on a record boundary)
    return "unaffected" if close else "uncounted"
