"""A self-contained HTML report of an evaluation (one file, inline SVG figures).

Figures need matplotlib (drawn with the Agg backend as SVG text); without it the report
has the tables only. Every input has a row in the inputs table, linked to its section
(per-filter numbers, bad data, its stored result file) and, when a recording report
exists for a log (``<log>.report/index.html``, ``<log stem>_report/index.html`` beside
the log, or ``OUT/reports/<log stem>/index.html``), a link to it.
"""

from __future__ import annotations

import html
import io
import math
import os
from pathlib import Path

__all__ = ["recording_report", "render_html"]

_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222;max-width:80em}
table{border-collapse:collapse;margin:.5em 0 1.2em}td,th{border:1px solid #ccc;
padding:.2em .5em;text-align:right}th{background:#f3f3f3}td:first-child,th:first-child
{text-align:left}.failed{color:#b00}.ok{color:#070}details{margin:.3em 0}
figure{display:inline-block;margin:.5em 1em .5em 0}figcaption{font-size:.9em;color:#555}
code{background:#f6f6f6;padding:0 .2em}
"""


def _e(v) -> str:
    return html.escape("" if v is None else str(v))


def _f(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool) or isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "-"
        return f"{v:.3g}" if abs(v) >= 1e5 or (v != 0 and abs(v) < 1e-3) else f"{v:.3f}"
    if isinstance(v, list):
        return "[" + ", ".join(_f(x) for x in v) + "]"
    return _e(v)


def _table(rows: dict[str, dict], cols: list[str], first: str = "filter") -> str:
    h = "".join(f"<th>{_e(c)}</th>" for c in [first] + cols)
    body = "".join(
        f"<tr><td>{_e(k)}</td>" + "".join(f"<td>{_f(r.get(c))}</td>" for c in cols) + "</tr>"
        for k, r in rows.items())
    return f"<table><tr>{h}</tr>{body}</table>"


def _svg(fig) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    s = buf.getvalue()
    return s[s.find("<svg"):]


def _figures(group: str, s: dict) -> list[tuple[str, str]]:
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
    except Exception:  # noqa: BLE001 - figures are optional
        return []
    labels = s["filters"]
    metric = "att_rmse_deg" if group == "logs" else "rmse_mean"
    data = [[r["filters"][lab][metric] for r in s["rows"]
             if r["status"] == "ok" and lab in r["filters"]
             and r["filters"][lab].get(metric) is not None] for lab in labels]
    out = []
    if any(data):
        fig, ax = plt.subplots(figsize=(1.2 + 0.9 * len(labels), 3.2))
        keep = [(lab, d) for lab, d in zip(labels, data, strict=True) if d]
        ax.boxplot([d for _, d in keep], showmeans=True)
        ax.set_xticks(range(1, len(keep) + 1), [lab for lab, _ in keep], rotation=30)
        ax.set_ylabel("attitude RMSE (deg) per log" if group == "logs"
                      else "RMSE, mean of each shard")
        ax.grid(alpha=0.3)
        out.append((_svg(fig), "RMSE distribution per filter (box: quartiles, "
                    "triangle: mean)"))
    wins = {lab: a.get("wins", 0) for lab, a in s["aggregate"].items()}
    if any(wins.values()):
        fig, ax = plt.subplots(figsize=(1.2 + 0.9 * len(wins), 3.2))
        ax.bar(list(wins), list(wins.values()), color="#4a7ab5")
        ax.set_ylabel("wins (" + ("logs" if group == "logs" else "trials") + ")")
        ax.tick_params(axis="x", rotation=30)
        ax.grid(alpha=0.3, axis="y")
        out.append((_svg(fig), f"which filter wins how often: {s['wins_metric']}"))
    return out


def recording_report(log: str, out: Path) -> str | None:
    """Relative link to a recording report of ``log`` if one exists (see module doc)."""
    p = Path(log)
    for c in (Path(str(p) + ".report") / "index.html",
              p.parent / f"{p.stem}_report" / "index.html",
              out / "reports" / p.stem / "index.html"):
        if c.is_file():
            return os.path.relpath(c, out)
    return None


_LOG_AGG = ["logs", "scored", "att_rmse_mean", "att_rmse_median", "att_rmse_worst",
            "roll_rmse_mean", "roll_rmse_median", "roll_rmse_worst", "pitch_rmse_mean",
            "pitch_rmse_median", "pitch_rmse_worst", "yaw_rmse_mean", "yaw_rmse_median",
            "yaw_rmse_worst", "nees_mean_mean", "nees_mean_median", "nees_mean_worst",
            "vel_rmse_ms_mean", "vel_rmse_ms_worst", "hpos_rmse_m_mean", "hpos_rmse_m_worst",
            "resets", "us_per_step_mean", "wins"]
_MC_AGG = ["trials", "rmse_mean", "rmse_median", "rmse_worst", "approx_error", "est_error",
           "nees_mean", "nees_median", "nees_band", "diverged_fraction", "resets",
           "us_per_step", "wins"]
_LOG_FILTER = ["roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "att_rmse_deg",
               "nees_mean", "vel_rmse_ms", "hpos_rmse_m", "resets", "us_per_step"]
_MC_FILTER = ["rmse_mean", "rmse_median", "nees_mean", "diverged_fraction", "resets",
              "us_per_step"]


def _inputs_section(gi: int, group: str, s: dict, out: Path) -> str:
    logs = group == "logs"
    head = (["#", "input", "status", "duration s", "IMU", "rate Hz", "reference", "bad data",
             "RT factor", "winner", "files"] if logs else
            ["#", "shard", "status", "trials", "files"])
    parts = ["<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"]
    details = []
    for k, r in enumerate(s["rows"]):
        anchor = f"g{gi}-i{k}"
        ok = r["status"] == "ok"
        status = ("<span class=ok>ok</span>" if ok else
                  f"<span class=failed>failed: {_e(r['reason'])}</span>")
        links = []
        if r.get("key"):
            rp = out / "results" / f"{r['key']}.json"
            if rp.is_file():
                links.append(f"<a href='{_e(os.path.relpath(rp, out))}'>result</a>")
        if logs:
            rec = recording_report(r["input"], out)
            if rec:
                links.append(f"<a href='{_e(rec)}'>recording report</a>")
        name = f"<a href='#{anchor}'>{_e(r['input'])}</a>" if ok else _e(r["input"])
        if logs:
            cells = [str(k + 1), name, status, _f(r.get("duration_s")), _e(r.get("imu_source")),
                     _f(r.get("imu_rate_hz")),
                     _e(r.get("reference")) + (f" ({_e(r.get('reference_kind'))})"
                                               if r.get("reference") else ""),
                     _f(r.get("bad_total")), _f(r.get("realtime_factor")),
                     _e(r.get("winner")), " ".join(links)]
        else:
            cells = [str(k + 1), name, status, _f(r.get("trials")), " ".join(links)]
        parts.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
        if ok:
            bad = ", ".join(f"{_e(a)} {b}" for a, b in (r.get("bad_data") or {}).items()
                            if a != "bad_total")
            extra = f"<p>bad data: {_f(r.get('bad_total'))} {('(' + bad + ')') if bad else ''}" \
                    f"</p>" if logs else ""
            details.append(
                f"<details id='{anchor}'><summary>{_e(r['input'])}</summary>"
                + _table(r["filters"], _LOG_FILTER if logs else _MC_FILTER) + extra
                + "</details>")
    parts.append("</table>")
    return "".join(parts) + "<h3>Per input</h3>" + "".join(details)


def render_html(summary: dict, out: str | Path) -> str:
    """The report as one HTML document (``out``: where it will be written, for links)."""
    out = Path(out)
    run, c = summary["run"], summary["counts"]
    body = [f"<h1>uavest evaluate</h1><p>{c['inputs']} input(s), {c['ok']} ok, "
            f"{c['failed']} failed"
            + (f"; {c['computed']} computed this run, {c['reused']} reused" if "computed" in c
               else "")
            + f". uavest {_e(run.get('version'))}, {_e(run.get('backend'))}, finished "
            f"{_e(run.get('finished_at'))}. Files: <a href='summary.json'>summary.json</a>, "
            "<a href='rows.csv'>rows.csv</a>, <a href='aggregate.csv'>aggregate.csv</a>.</p>"]
    if summary["failures"]:
        body.append("<h2>Failed inputs</h2><ul>" + "".join(
            f"<li><code>{_e(f['input'])}</code>: {_e(f['reason'])}</li>"
            for f in summary["failures"]) + "</ul>")
    for gi, (g, s) in enumerate(summary["groups"].items()):
        logs = g == "logs"
        title = "Flight logs" if logs else f"Monte Carlo: {g[3:]}"
        body.append(f"<h2>{_e(title)}</h2>")
        specs = ", ".join(f"<code>{_e(f['label'])}</code>" for f in s["config"]["filters"])
        body.append(f"<p>filters: {specs}; configuration hash <code>"
                    f"{_e(s['config_hash'][:16])}</code>; wins: {_e(s['wins_metric'])}.</p>")
        if not logs:
            body.append(f"<p>{s['trials_evaluated']} of {s['trials_requested']} trials, "
                        f"seed {s['config'].get('seed')}.</p>")
        body.append(_table(s["aggregate"], _LOG_AGG if logs else _MC_AGG))
        for svg, cap in _figures(g, s):
            body.append(f"<figure>{svg}<figcaption>{_e(cap)}</figcaption></figure>")
        body.append("<h3>Inputs</h3>" + _inputs_section(gi, g, s, out))
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>uavest evaluate"
            f"</title><style>{_CSS}</style></head><body>" + "".join(body) + "</body></html>\n")
