"""From stored results to the report: per-input rows, aggregate tables, wins, CSV.

Pure functions of the plan and the stored result documents, so a resumed run gives the
same report as an uninterrupted one. Logs: per filter, the mean, median and worst (max)
over logs of roll/pitch/yaw RMSE, ``att_rmse_deg`` = sqrt(mean of the three squared) and
NEES; a filter *wins* a log when its ``att_rmse_deg`` is the lowest of the filters run.
Monte Carlo: :func:`uavest.experiments.montecarlo.aggregate` over every trial row of
every shard (the same table as ``uavest bench`` with those trials), plus the worst trial
RMSE and the wins per trial (lowest RMSE).
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np

__all__ = ["LOG_METRICS", "group_summary", "log_row", "rows_csv", "aggregate_csv"]

LOG_METRICS = ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "att_rmse_deg", "nees_mean",
               "vel_rmse_ms", "hpos_rmse_m")


def _num(v):
    return v if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) \
        else None


def _att(r: dict):
    axes = [_num(r.get(k)) for k in ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg")]
    if any(a is None for a in axes):
        return None
    return math.sqrt(sum(a * a for a in axes) / 3.0)


def log_row(inp, doc: dict | None, labels: list[str]) -> dict:
    """One log's row from its stored document (or its failure)."""
    row = {"input": inp.name, "kind": "log", "key": inp.key, "status": "failed",
           "reason": None, "filters": {}, "winner": None, "duplicate_of": inp.duplicate_of}
    if doc is None:
        row["reason"] = inp.error or "not evaluated"
        return row
    row["status"] = doc["status"]
    row["reason"] = _strip_path(doc.get("reason"), inp)
    row["attempts"] = doc.get("attempts")
    if doc["status"] != "ok":
        return row
    r = doc["result"]
    bad = r.get("bad_data") or {}
    row.update({
        "format": r.get("format"), "duration_s": r.get("duration_s"),
        "imu_source": r.get("imu_source"), "imu_rate_hz": r.get("imu_rate_hz"),
        "reference": r.get("reference"), "reference_kind": r.get("reference_kind"),
        "steps": r.get("steps"), "bad_total": bad.get("bad_total"),
        "bad_data": {k: v for k, v in bad.items() if isinstance(v, int) and v},
        "realtime_factor": r.get("realtime_factor"), "wall_s": r.get("wall_s"),
        "model": (r.get("model") or {}).get("value"),
    })
    for lab in labels:
        f = (r.get("filters") or {}).get(lab)
        if f is None:
            continue
        row["filters"][lab] = {
            "roll_rmse_deg": _num(f.get("roll_rmse_deg")),
            "pitch_rmse_deg": _num(f.get("pitch_rmse_deg")),
            "yaw_rmse_deg": _num(f.get("yaw_rmse_deg")),
            "att_rmse_deg": _att(f), "nees_mean": _num(f.get("nees_mean")),
            # navigation model only (None for attitude-only logs)
            "vel_rmse_ms": _num(f.get("vel_rmse_ms")), "hpos_rmse_m": _num(f.get("hpos_rmse_m")),
            "resets": f.get("resets"), "us_per_step": _num(f.get("us_per_step")),
        }
    scored = [(v["att_rmse_deg"], lab) for lab, v in row["filters"].items()
              if v["att_rmse_deg"] is not None]
    if scored:
        row["winner"] = min(scored, key=lambda s: s[0])[1]  # ties: first listed
    return row


def _strip_path(reason: str | None, inp) -> str | None:
    """An input error without the file name it starts with (the row names the input)."""
    if not reason:
        return reason
    import os

    for p in (inp.name, inp.task.path if inp.task else None):
        if p:
            for q in {p, os.path.abspath(p)}:
                if reason.startswith(q + ": "):
                    return reason[len(q) + 2:]
    return reason


def _stats(vals: list) -> dict:
    v = [x for x in vals if x is not None]
    if not v:
        return {"mean": None, "median": None, "worst": None}
    return {"mean": float(np.mean(v)), "median": float(np.median(v)), "worst": float(max(v))}


def _log_aggregate(rows: list[dict], labels: list[str]) -> dict:
    out = {}
    # identical copies were evaluated once and count once
    ok = [r for r in rows if r["status"] == "ok" and not r.get("duplicate_of")]
    for lab in labels:
        fr = [r["filters"][lab] for r in ok if lab in r["filters"]]
        a: dict = {"logs": len(fr), "scored": sum(f["att_rmse_deg"] is not None for f in fr)}
        for m in LOG_METRICS:
            for k, v in _stats([f[m] for f in fr]).items():
                a[f"{m.removesuffix('_deg')}_{k}"] = v
        a["resets"] = int(sum(f["resets"] or 0 for f in fr))
        a["us_per_step_mean"] = _stats([f["us_per_step"] for f in fr])["mean"]
        a["wins"] = sum(r["winner"] == lab for r in ok)
        out[lab] = a
    return out


def _shard_row(inp, doc: dict | None) -> dict:
    from ..experiments.montecarlo import aggregate

    row = {"input": inp.name, "kind": "shard", "key": inp.key, "status": "failed",
           "reason": None, "filters": {}, "trials": None}
    if doc is None:
        row["reason"] = inp.error or "not evaluated"
        return row
    row["status"], row["reason"] = doc["status"], doc.get("reason")
    row["attempts"] = doc.get("attempts")
    if doc["status"] != "ok":
        return row
    r = doc["result"]
    row["trials"] = r["trials"]
    agg = aggregate(r["rows"], int(r["dim"]))
    row["filters"] = {lab: {k: a[k] for k in ("rmse_mean", "rmse_median", "nees_mean",
                                              "diverged_fraction", "resets", "us_per_step")}
                      for lab, a in agg.items()}
    return row


def _mc_aggregate(docs: list[dict]) -> tuple[dict, int]:
    from ..experiments.montecarlo import aggregate

    docs = sorted(docs, key=lambda d: d["result"]["trials"][0])
    rows = [row for d in docs for row in d["result"]["rows"]]
    if not rows:
        return {}, 0
    out = aggregate(rows, int(docs[0]["result"]["dim"]))
    labels = list(out)
    wins = dict.fromkeys(labels, 0)
    for row in rows:
        wins[min(labels, key=lambda lab: row[lab]["rmse"])] += 1
    for lab in labels:
        out[lab]["rmse_worst"] = float(max(row[lab]["rmse"] for row in rows))
        out[lab]["trials"] = len(rows)
        out[lab]["wins"] = wins[lab]
    return out, len(rows)


def group_summary(group: str, inputs: list, docs: dict[str, dict | None], config: dict,
                  config_hash: str) -> dict:
    """The summary of one group ("logs" or "mc:<scenario>"): config, rows, aggregate."""
    labels = [f["label"] for f in config["filters"]]
    if group == "logs":
        rows = [log_row(i, docs.get(i.key) if i.key else None, labels) for i in inputs]
        agg = _log_aggregate(rows, labels)
        extra = {"wins_metric": "att_rmse_deg (lowest of the filters run)"}
    else:
        rows = [_shard_row(i, docs.get(i.key) if i.key else None) for i in inputs]
        ok = [docs[i.key] for i in inputs if i.key and docs.get(i.key)
              and docs[i.key]["status"] == "ok"]
        agg, n = _mc_aggregate(ok)
        extra = {"wins_metric": "rmse per trial (lowest of the filters run)",
                 "trials_evaluated": n, "trials_requested": config.get("trials")}
    return {"config": config, "config_hash": config_hash, "filters": labels,
            "aggregate": agg, "rows": rows,
            "ok": sum(r["status"] == "ok" for r in rows),
            "duplicates": sum(bool(r.get("duplicate_of")) for r in rows),
            "failed": sum(r["status"] != "ok" for r in rows), **extra}


ROW_FIELDS = ("group", "input", "status", "reason", "duplicate_of", "format", "duration_s",
              "imu_source", "imu_rate_hz", "reference", "reference_kind", "bad_total",
              "realtime_factor",
              "trials", "filter", "roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg",
              "att_rmse_deg", "nees_mean", "rmse_mean", "rmse_median", "diverged_fraction",
              "resets", "us_per_step", "winner")


def _cell(v):
    if isinstance(v, list):
        return ":".join(str(x) for x in v)
    return "" if v is None else v


def rows_csv(groups: dict[str, dict]) -> str:
    """One line per (input, filter); a failed input has one line with its reason."""
    s = io.StringIO()
    w = csv.DictWriter(s, ROW_FIELDS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for g, gs in groups.items():
        for r in gs["rows"]:
            base = {k: _cell(r.get(k)) for k in ROW_FIELDS} | {"group": g}
            if not r["filters"]:
                w.writerow(base)
            for lab, f in r["filters"].items():
                w.writerow(base | {"filter": lab} | {k: _cell(v) for k, v in f.items()})
    return s.getvalue()


def aggregate_csv(groups: dict[str, dict]) -> str:
    """One line per (group, filter) with every aggregate column of that group."""
    cols: list[str] = []
    for gs in groups.values():
        for a in gs["aggregate"].values():
            cols += [k for k in a if k not in cols]
    s = io.StringIO()
    w = csv.DictWriter(s, ["group", "filter"] + cols, lineterminator="\n")
    w.writeheader()
    for g, gs in groups.items():
        for lab, a in gs["aggregate"].items():
            w.writerow({"group": g, "filter": lab} | {k: _cell(v) for k, v in a.items()})
    return s.getvalue()
