"""The hostile-input sweep (issue 11): every case of ``tests/hostile/cases.py`` (>= 200:
truncations, byte flips, splices, duplicated and reordered sections, random bytes after
valid headers, one bad time stamp, special files, bad options, ``--set`` and scenario
files, for tlog, DataFlash .bin and ULog and for replay, bench and track) run as child
processes with a timeout and their peak memory measured, then the table.

    PYTHONPATH=$PWD python benchmarks/hostile_sweep.py [--quick] [--json out.json]
        [--only SUBSTRING] [--timeout 120]

Needs the shared logs at ../shared/logs. Takes about 10-20 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from hostile import cases as H  # noqa: E402

COLS = ["cases", "clear_error", "recovered", "unaffected", "ok", "traceback", "hang", "over_1gb",
        "invalid_accepted", "wrong_unflagged", "uncounted", "valid_refused", "bad_message"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer seeds per flip class")
    ap.add_argument("--json", help="write every case's outcome here")
    ap.add_argument("--only", help="only cases whose name contains this")
    ap.add_argument("--names", help="only the cases named in this file (one a line)")
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--jobs", type=int, default=2, help="cases run at once (default 2)")
    a = ap.parse_args()
    cases = H.all_cases(full=not a.quick)
    if a.only:
        cases = [c for c in cases if a.only in c["name"] or c["name"].endswith(":clean")]
    if a.names:
        want = set(Path(a.names).read_text().splitlines())
        cases = [c for c in cases if c["name"] in want or c["name"].endswith(":clean")]
    print(f"{len(cases)} cases", flush=True)
    rows = []
    clean: dict[str, dict] = {}
    t0 = time.monotonic()
    from concurrent.futures import ThreadPoolExecutor

    with tempfile.TemporaryDirectory() as tmp:
        def one(ic):
            i, c = ic
            wd = Path(tmp) / f"c{i}"
            res = H.run(c, wd, a.timeout)
            for f in wd.glob("input*"):
                f.unlink()
            return i, c, res

        def record(i, c, res):
            out = H.classify(c, res, clean.get(c.get("base", "")))
            last = [ln for ln in res["stderr"].splitlines() if ln.strip()][-1:] or [""]
            rows.append({"name": c["name"], "cls": c["cls"], "outcome": out, "rc": res["rc"],
                         "secs": round(res["secs"], 2), "maxrss_mb": res["maxrss"] >> 20,
                         "message": last[0][:300]})
            print(f"[{len(rows)}/{len(cases)}] {out:16s} rc={res['rc']} {res['secs']:5.1f}s "
                  f"{res['maxrss'] >> 20:5d}MB {c['name']}  {last[0][:110]}", flush=True)

        first = [(i, c) for i, c in enumerate(cases) if c["name"].endswith(":clean")]
        rest = [(i, c) for i, c in enumerate(cases) if not c["name"].endswith(":clean")]
        for ic in first:  # the clean bases first: the damaged logs are compared with them
            i, c, res = one(ic)
            if res["doc"]:
                clean[c["fmt"]] = res["doc"]
            record(i, c, res)
        with ThreadPoolExecutor(max(1, a.jobs)) as ex:
            for i, c, res in ex.map(one, rest):
                record(i, c, res)
    by: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for r in rows:
        by[r["cls"]][r["outcome"]] += 1
        by[r["cls"]]["cases"] += 1
        by["TOTAL"][r["outcome"]] += 1
        by["TOTAL"]["cases"] += 1
    w = max(len(k) for k in by)
    print(f"\nhostile sweep: {len(rows)} cases in {time.monotonic() - t0:.0f} s; peak child "
          f"RSS {max(r['maxrss_mb'] for r in rows)} MB")
    print(f"{'class':<{w}}  " + "  ".join(f"{c:>8.8}" for c in COLS))
    for k in sorted(by, key=lambda k: (k == "TOTAL", k)):
        print(f"{k:<{w}}  " + "  ".join(f"{by[k][c]:>8d}" for c in COLS))
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "table": by}, indent=1))
    bad = sum(by["TOTAL"][k] for k in ("traceback", "hang", "over_1gb", "invalid_accepted",
                                       "wrong_unflagged", "uncounted", "bad_message",
                                       "valid_refused"))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
