"""``uavest track SCENARIO``: run a radar scenario once and print the track table.

Registered by ``uavest/cli/__init__.py`` through :func:`add_track_parser`.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..sinks.jsonout import write_json
from .record import add_recording_options, finish_recording, recording_sinks

if TYPE_CHECKING:
    from ..tracking.tracker import Tracker

# The scenario schema, the radar experiments and the tracker are imported by the command,
# not by this module: ``uavest --help`` registers every parser and stays fast.


def track_table(sc, filters: list[str], seed: int, sinks=(), command: str = "") -> dict:
    """Run the scenario ``sc`` (typed, or its dict) once (run 0 of ``seed``) with every
    filter's tracker on the same detections. Returns {"scenario", "seed", "tracks": [rows],
    "summary": {filter: {...}}}.

    Row fields: filter, track id, born / confirmed / deleted scan times (s; None if never),
    length (scans alive), hits, truth (index of the truth it was assigned to most often,
    None for a false track), pos_rmse (m) against that truth over the assigned scans."""
    from ..engine.records import RunInfo, package_versions
    from ..experiments.radar import data_rng, run_trackers, tracker_errors
    from ..presets import spec_labels
    from ..scenarios import resolved, typed
    from ..tracking.scenario import generate_run

    scn = typed(sc)
    dt, ndim, c = float(scn.dt), int(scn.ndim), float(scn.metrics.gospa_c)
    run = generate_run(scn, data_rng(seed, 0))  # filter-mode scenarios: tracker too
    info = RunInfo(command, f"scenario:{scn.name}", seed,
                   filters={lab: {"spec": lab, "preset": "radar"} for lab in spec_labels(filters)},
                   config={"scenario": scn.name, "dt": dt, "gospa_c": c},
                   versions=package_versions(), scenario=resolved(scn))
    trackers: dict[str, Tracker] = run_trackers(scn, filters, run, seed, 0, sinks, info)
    rows, summary = [], {}
    for lab, tr in trackers.items():
        q, _ = tracker_errors(tr, run, ndim, c, dt)
        by_track: dict[int, list[tuple[int, int]]] = {}
        for tid, lst in q.assigned.items():
            for k0, j in lst:
                by_track.setdefault(j, []).append((k0, tid))
        for t in tr.all_tracks:
            if t.confirmed_at is None:
                continue
            pairs = by_track.get(t.id, [])
            truth = None
            rmse = None
            if pairs:
                tids = [p[1] for p in pairs]
                truth = int(max(set(tids), key=tids.count))
                post = {h[0]: h[2] for h in t.history}
                e = [
                    post[k0 + 1].x[:ndim] - run.truths[truth, k0 + 1, :ndim]
                    for k0, tid in pairs
                    if tid == truth
                ]
                rmse = float(np.sqrt(np.mean(np.sum(np.square(e), axis=1))))
            rows.append(
                {
                    "filter": lab,
                    "track": t.id,
                    "born": t.born * dt,
                    "confirmed": t.confirmed_at * dt,
                    "deleted": None if t.deleted_at is None else t.deleted_at * dt,
                    "length": len(t.history),
                    "hits": int(sum(h[3] for h in t.history)),
                    "truth": truth,
                    "pos_rmse": rmse,
                }
            )
        summary[lab] = {
            "gospa": q.gospa,
            "tracks_confirmed_total": q.confirmed_tracks,
            "false_tracks": q.false_tracks,
            "id_swaps": q.id_swaps,
            "track_breaks": q.track_breaks,
            "time_to_confirm": q.time_to_confirm,
            "tentative_tracks": len(tr.all_tracks),
            "us_per_scan": 1e6 * tr.seconds / max(tr.n_scans, 1),
        }
    return {"scenario": scn.name, "seed": seed, "tracks": rows, "summary": summary,
            "run": info.as_dict()}


def _fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def print_table(res: dict) -> None:
    print(f"scenario {res['scenario']}  seed {res['seed']}")
    hdr = (
        f"{'filter':<10}{'track':>6}{'born s':>8}{'conf s':>8}{'del s':>8}{'len':>6}"
        f"{'hits':>6}{'truth':>7}{'pos_rmse m':>12}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in res["tracks"]:
        print(
            f"{r['filter']:<10}{r['track']:>6}{_fmt(r['born'], '.0f'):>8}"
            f"{_fmt(r['confirmed'], '.0f'):>8}{_fmt(r['deleted'], '.0f'):>8}{r['length']:>6}"
            f"{r['hits']:>6}{_fmt(r['truth'], 'd'):>7}{_fmt(r['pos_rmse'], '.1f'):>12}"
        )
    print()
    hdr = (
        f"{'filter':<10}{'gospa':>9}{'conf_total':>11}{'false':>7}{'swaps':>7}{'breaks':>8}"
        f"{'t_conf s':>10}{'us/scan':>10}"
    )
    print(hdr)
    print("-" * len(hdr))
    for lab, s in res["summary"].items():
        print(
            f"{lab:<10}{s['gospa']:>9.1f}{s['tracks_confirmed_total']:>11}{s['false_tracks']:>7}"
            f"{s['id_swaps']:>7}{s['track_breaks']:>8}{_fmt(s['time_to_confirm'], '.1f'):>10}"
            f"{s['us_per_scan']:>10.0f}"
        )


def cmd_track(args: argparse.Namespace) -> int:
    from ..scenarios import load_typed

    scn = load_typed(args.scenario, args.set or [])
    if scn.kind != "radar":
        raise InputError(f"scenario {args.scenario!r} is not a radar scenario "
                         "(radar scenarios: see 'uavest list')")
    filters = args.filter_specs or list(scn.filters)
    from ..experiments.resources import check
    from .replay import reject_linear_only

    reject_linear_only(filters, "track", "the nonlinear radar measurement model")
    check(scn, filters or ["ekf", "ukf", "hybrid"], 1, scn.steps, "track")
    res = track_table(scn, filters or ["ekf", "ukf", "hybrid"], args.seed,
                      recording_sinks(args), " ".join(sys.argv))
    print_table(res)
    if args.json:
        write_json(args.json, res)
    finish_recording(args)
    return 0


def add_track_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``uavest track SCENARIO [--filters ekf,ukf,hybrid] [--seed S]
    [--set KEY=VALUE ...] [--json PATH]``."""
    p = subparsers.add_parser(
        "track",
        help="run a radar scenario once and print the track table",
        description="Run a radar tracking scenario once with each filter's tracker on the "
        "same detections and print the track table.",
    )
    p.add_argument("scenario", help="scenario name (scenarios/<name>.toml) or .toml path")
    p.add_argument("--filters", default=None, help="comma-separated filter specs")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario parameter (dotted keys), repeatable")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the table as JSON")
    add_recording_options(p, live_view=False)
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (accepted for symmetry with bench and replay)")
    p.set_defaults(func=cmd_track, filters_preset="radar")
    return p


__all__ = ["add_track_parser", "cmd_track", "track_table"]
