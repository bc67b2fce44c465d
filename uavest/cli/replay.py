"""``uavest replay LOG``: attitude filters side by side over a flight log."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
from pathlib import Path

from ..apps.aiding import aiding_hint
from ..apps.replay import (
    DEFAULT_FILTERS,
    ReplayConfig,
    learnt_lines,
    replay,
)
from ..core.spec import FilterSpec
from ..engine.attitude import DEFAULT_MAX_RATE_HZ
from ..errors import InputError
from ..models.attitude import AttitudeNoise
from ..models.navigation import NavNoise
from ..sinks.base import ResetLog, Sink
from ..sinks.jsonout import write_json
from ..sinks.table import table
from .progress import progress
from .record import add_recording_options, finish_recording, recording_sinks

__all__ = ["NAV_COLS", "add_replay_parser", "cmd_replay", "flat_row", "format_doc"]


#: Filters that need linear models (the attitude and radar models are nonlinear).
LINEAR_ONLY = ("kf",)


def reject_linear_only(specs, command: str, models: str) -> None:
    """One-line ValueError for a filter that cannot run on ``command``'s models."""
    for sp in specs or ():
        name = sp.name if isinstance(sp, FilterSpec) else str(sp).split("(")[0].strip().lower()
        sp = sp.label if isinstance(sp, FilterSpec) else sp
        if name in LINEAR_ONLY:
            raise InputError(
                f"--filters {sp}: the linear Kalman filter needs linear models; {command} "
                f"uses {models} (use ekf, ukf, srukf, enkf, hybrid, pf...)")


def add_geodesy_option(p: argparse.ArgumentParser) -> None:
    """``--geodesy``: the navigation model's local frame (``NavOptions.geodesy``)."""
    p.add_argument("--geodesy", choices=("auto", "wgs84", "sphere"), default="auto",
                   help="navigation model: how GNSS lat/lon become local NED metres: wgs84 "
                   "(a receiver's), sphere (ArduPilot's flat-Earth scaling, with which an "
                   "ArduPilot SITL makes its lat/lon), or auto (default: sphere when the "
                   "stream is an ArduPilot SITL's - SIM_STATE, or SIM_* parameters - else "
                   "wgs84)")


def add_declination_option(p: argparse.ArgumentParser, default: str) -> None:
    """``--declination DEG`` (east positive), its default said by ``default``."""
    p.add_argument("--declination", type=float, default=None, metavar="DEG",
                   help=f"magnetic declination in degrees, east positive (default: {default})")


def declination_rad(args: argparse.Namespace) -> float | None:
    """``--declination`` in radians (None: not given); one line for a bad value."""
    d = getattr(args, "declination", None)
    if d is None:
        return None
    if not (math.isfinite(d) and -180.0 <= d <= 180.0):
        raise InputError(f"--declination must be a number of degrees from -180 to 180, got {d}")
    return math.radians(d)


def parse_noise(items: list[str]) -> dict:
    """``--noise KEY=VALUE`` items as {name: value}; a clear error for an unknown name,
    a non-number or a negative value."""
    # the attitude and the navigation model's parameters (each model checks its own)
    known = set(AttitudeNoise.__dataclass_fields__) | set(NavNoise.__dataclass_fields__)
    out = {}
    for it in items:
        if "=" not in it:
            raise InputError(f"--noise expects KEY=VALUE, got {it!r}")
        k, v = (x.strip() for x in it.split("=", 1))
        if k not in known:
            raise InputError(f"--noise: unknown parameter {k!r}; known: {', '.join(sorted(known))}")
        try:
            f = float(v)
        except ValueError:
            raise InputError(f"--noise {k}: {v!r} is not a number") from None
        if not math.isfinite(f) or f < 0:
            raise InputError(f"--noise {k}: must be a finite number >= 0, got {v}")
        out[k] = f
    return out


class _Progress(Sink):
    """Progress while the log is read and replayed: bytes of the file for MAVLink logs
    (their reader streams), steps for ULog (read whole first); only on a terminal."""

    def __init__(self, enabled: bool | None, path: str | None = None) -> None:
        self.enabled, self.path = enabled, path
        self.bar = progress(None, "replay", enabled)
        self.k = 0
        self.src = None

    def source(self, src) -> None:
        if hasattr(src, "bytes_read") and self.path:
            import os

            with contextlib.suppress(OSError):
                size = os.path.getsize(self.path)
                self.bar.close()
                self.bar = progress(size, f"reading {Path(self.path).name}", self.enabled)
                self.bar.unit, self.bar.unit_scale = "B", True
                self.src = src

    def record(self, rec) -> None:
        if rec.k != self.k:
            self.k = rec.k
            if self.src is None:
                self.bar.update(1)
            elif rec.k % 20 == 0:
                self.bar.update(self.src.bytes_read - self.bar.n)

    def close(self) -> None:
        self.bar.close()


def decision_lines(doc: dict) -> list[str]:
    """One ``decision:`` line per entry of ``doc["decisions"]`` (what, value, the vehicle
    time it took effect, s, and how far into the IMU data, why)."""
    t0, lines = doc.get("t_first"), []
    for d in doc.get("decisions") or []:
        rel = f", {d['t'] - t0:+.1f} s into the IMU data" if t0 is not None else ""
        when = "at" if d["what"].endswith("alignment") or d["what"] == "restart" else "from"
        lines.append(f"decision: {d['what']}: {d['value']} {when} t={d['t']:.1f} s{rel} "
                     f"({d['why']})")
    return lines


#: Navigation columns of the replay table (``flat_row`` of a filter's row).
NAV_COLS = ["vel_rmse_ms", "hpos_rmse_m", "vpos_rmse_m", "nees_att_in95", "nees_vel_in95",
            "nees_pos_in95"]


def flat_row(row: dict) -> dict:
    """A result row with its NEES blocks as columns (share of steps in the 95 % band) and
    the aiding updates every gate rejected."""
    out = dict(row)
    for blk, short in (("attitude", "att"), ("velocity", "vel"), ("position", "pos")):
        b = (row.get("nees") or {}).get(blk) or {}
        out[f"nees_{short}_in95"] = b.get("in_band95")
    gates = row.get("gates")
    if gates is not None:
        out["rejected"] = sum(g.get("rejected", 0) for g in gates.values())
    return out


def model_lines(doc: dict) -> list[str]:
    """The model decision (navigation or attitude-only, and why) and, for navigation,
    the GNSS / baro sources and the position reference."""
    m = doc.get("model")
    if not m:
        return []
    name = {"nav": "navigation (attitude, velocity, position, gyro and accel biases)",
            "attitude": "attitude-only (attitude, gyro bias)"}[m["value"]]
    when = f" from t={m['t']:.1f} s" if m.get("t") is not None else ""
    lines = [f"decision: model: {name}{when} ({m['why']})"]
    if m["value"] == "nav":
        aid = doc.get("aiding") or {}
        cnt = "; ".join(f"{k}: " + ", ".join(f"{a} {n}" for a, n in sorted(v.items()))
                        for k, v in sorted(aid.items()))
        lines.append(f"aiding: GNSS {doc.get('gnss_source')} (delay "
                     f"{doc.get('gnss_delay_s') or 0:g} s), baro {doc.get('baro_source')}, "
                     f"magnetometer {doc.get('mag_source')}" + (f"; {cnt}" if cnt else ""))
    drift = (doc.get("gnss_delay_estimate") or {}).get("gnss_drift") or {}
    if drift.get("text"):
        lines.append(f"GNSS drift: {drift['text']}")
    if doc.get("position_reference"):
        lines.append(f"position reference: {doc['position_reference']} "
                     f"({doc.get('position_reference_kind')}); velocity RMSE m/s, position "
                     "RMSE m, NEES: share of steps in the 95 % chi-square band")
    return lines


def format_doc(doc: dict) -> str:
    """The human-readable result of a replay: what was read, the table, bad data."""
    return "\n".join(_source_lines(doc) + model_lines(doc) + decision_lines(doc)
                     + _imu_interval_lines(doc) + _table_lines(doc) + _bad_data_lines(doc)
                     + [_speed_line(doc)])


def _source_lines(doc: dict) -> list[str]:
    """The log, its IMU and filter rates, the integration, the reference, the declination."""
    then = "".join(f" then {w['to']} from t={w['t']:.1f} s" for w in doc.get("imu_switches") or [])
    lines = [
        f"{doc['log']}: {doc['format']}, IMU {doc['imu_source']}{then} at "
        f"{doc['imu_rate_hz']:.1f} Hz,"
        f" {doc['duration_s']:.1f} s, {doc['steps']} filter steps at "
        f"{doc['filter_rate_hz']:.1f} Hz ({doc['integration']})",
        f"integration: {doc['integration']} ({doc.get('integration_why') or 'option'})",
    ]
    ref, kind = doc["reference"], doc["reference_kind"]
    rejected = doc.get("references_rejected") or {}
    if ref is None:
        lines.append("reference: none usable in this log (RMSE not available)")
    else:
        what = "truth" if kind == "truth" else f"{kind} estimate, not truth"
        lines.append(f"reference: {ref} ({what}); RMSE in degrees, Euler ZYX, wrapped")
    for name, why in rejected.items():
        lines.append(f"  not used as reference: {name}: {why}")
    if doc.get("declination_source"):
        lines.append(f"declination: {math.degrees(doc['declination_rad'] or 0.0):.2f} deg "
                     f"({doc['declination_source']})")
    return lines


def _imu_interval_lines(doc: dict) -> list[str]:
    """IMU gaps (not integrated across) and long intervals (predicted in sub-steps)."""
    lines = []
    if doc.get("imu_gaps"):
        (g0, _), = [max(doc["imu_gap_list"], key=lambda g: g[1] - g[0])]
        lines.append(f"IMU gaps: {doc['imu_gaps']} longer than "
                     f"{doc['imu_gap_threshold_s']:.2f} s (max(0.5 s, 20 median intervals)), "
                     f"longest {doc['imu_gap_longest_s']:.1f} s from t={g0:.1f} s; not "
                     "integrated across, the filters re-aligned after each")
    if doc.get("imu_split_intervals"):
        lines.append(f"long IMU intervals: {doc['imu_split_intervals']} longer than "
                     f"{doc['max_step_s']:.2f} s (below the gap threshold), longest "
                     f"{doc['imu_split_longest_s']:.2f} s; each predicted in sub-steps, the "
                     "aiding inside it at its own time")
    return lines


def _table_lines(doc: dict) -> list[str]:
    """The filters' table (smoothed rows indented; navigation columns for the nav model)
    and, when the log says when the vehicle was airborne, the airborne table (smoothed
    rows too)."""
    rows = {}
    for name, row in doc["filters"].items():
        rows[name] = row
        if "smoothed" in row:
            rows[f"  {name} smoothed"] = row["smoothed"]
    cols = ["roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "nees_mean", "resets",
            "us_per_step"]
    nav = (doc.get("model") or {}).get("value") == "nav"
    if nav:
        rows = {k: flat_row(r) for k, r in rows.items()}
        cols = cols[:4] + NAV_COLS + ["rejected"] + cols[4:]
    lines = [table(rows, cols)]
    air = {}
    for k, r in doc["filters"].items():
        if r.get("airborne"):
            air[k] = flat_row(r["airborne"])
        if (r.get("smoothed") or {}).get("airborne"):
            air[f"  {k} smoothed"] = flat_row(r["smoothed"]["airborne"])
    if air:
        a0 = next(iter(doc["filters"].values())).get("airborne") or {}
        t = a0.get("t") or [math.nan, math.nan]
        lines.append(f"airborne (t={t[0]:.1f}-{t[1]:.1f} s, {doc.get('position_reference')} "
                     f"more than {a0.get('height_above_lowest_m', 2.0):g} m above its "
                     "lowest):")
        acols = ["roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg"]
        lines.append(table(air, acols + (NAV_COLS if nav else ["nees_att_in95"])))
    lines += learnt_lines(doc["filters"], doc)
    return lines


def _bad_data_lines(doc: dict) -> list[str]:
    """Bad data by kind, then what was skipped, absent, without a fix, retimed or repaired
    (none of them bad data), and the reasons the run is unreliable."""
    bad = doc["bad_data"]
    parts = [f"{k} {bad[k]}" for k in bad
             if isinstance(bad[k], int) and bad[k]
             and k not in ("bad_total", "absent_sensor", "unusable_sensor", "non_mavlink",
                           "no_fix", "retimed")]
    lines = [f"bad data: {bad['bad_total']}" + (f" ({', '.join(parts)})" if parts else "")]
    skipped = bad.get("skipped") or {}
    if skipped:
        lines.append("skipped between records: " + ", ".join(
            f"{k.replace('_', ' ')} {n}" for k, n in skipped.items())
            + " (text: not bad data)" * bool(skipped.get("text_bytes")))
    for key, what in (("absent", "absent sensors (all-zero records"),
                      ("unusable", "unusable sensors (every reading out of range: a wrong "
                       "unit")):
        per = bad.get(key) or {}
        if per:
            lines.append(f"{what}, not bad data, ignored): " + ", ".join(
                f"{k.split(':', 1)[-1]} x{n}" for k, n in per.items()))
    if bad.get("no_fix"):
        lines.append(f"no GNSS fix: {bad['no_fix']} position records with lat/lon 0 skipped "
                     "(not bad data)")
    if bad.get("retimed"):
        lines.append(f"retimed: {bad['retimed']} GNSS records stamped with UNIX time mapped "
                     "onto the vehicle clock (not bad data)")
    rep = doc.get("repaired") or {}
    if rep.get("time_outlier"):
        lines.append(f"repaired: {rep['time_outlier']} time stamps that were outliers against "
                     "their neighbours (kept with a time from their neighbours)")
    return lines + [f"UNRELIABLE: {why}" for why in doc.get("unreliable") or []]


def _speed_line(doc: dict) -> str:
    """The replay speed: log duration over the filter loop's wall time, all filters (the
    compiled kernels' first load in this process said apart: numba's cache load, or its
    compilation for this machine on the first run)."""
    rt = doc["realtime_factor"]
    if not rt:
        return "replay speed: -"
    load = doc.get("kernel_load_s") or 0.0
    tail = (f"; the compiled kernels' first load in this process, {load:.1f} s, not "
            "counted" if load >= 0.05 else "")
    return (f"replay speed: {rt:.1f}x real time ({len(doc['guard_resets'])} filters "
            f"together, {doc['wall_s']:.2f} s{tail})")


def cmd_replay(args: argparse.Namespace) -> int:
    """Entry point of ``uavest replay`` (errors reach ``uavest.cli.main``: exit 2)."""
    from ..ingest import detect_format

    if not os.path.lexists(args.log):
        raise InputError(f"no such log file: {args.log}")
    detect_format(Path(args.log))  # one-line IngestError for missing/special/unknown files
    declination = declination_rad(args)
    for name in ("start", "end"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            raise InputError(f"--{name} must be a finite time in s, got {v}")
    if args.start is not None and args.end is not None and args.end <= args.start:
        raise InputError(f"--end ({args.end}) must be after --start ({args.start})")
    if args.gnss_delay is not None and not (math.isfinite(args.gnss_delay)
                                            and 0.0 <= args.gnss_delay <= 2.0):
        raise InputError(f"--gnss-delay must be from 0 to 2 s, got {args.gnss_delay}")
    if args.baro_delay is not None and not (math.isfinite(args.baro_delay)
                                            and 0.0 <= args.baro_delay <= 2.0):
        raise InputError(f"--baro-delay must be from 0 to 2 s, got {args.baro_delay}")
    if args.mag_delay is not None and args.mag_delay > 10.0:
        raise InputError(f"--mag-delay must be at most 10 s, got {args.mag_delay}")
    if args.mag_delay is not None and (args.mag_delay < 0 or not math.isfinite(args.mag_delay)):
        raise InputError(
            f"--mag-delay must be a finite number of seconds >= 0, got {args.mag_delay}")
    if args.rate is not None and (args.rate < 0 or not math.isfinite(args.rate)):
        raise InputError(f"--rate must be >= 0 Hz (0 = every IMU sample), got {args.rate}")
    if args.update_rate is not None and (args.update_rate < 0
                                         or not math.isfinite(args.update_rate)):
        raise InputError(f"--update-rate must be >= 0 Hz (0 = every step), got "
                         f"{args.update_rate}")
    reject_linear_only(args.filter_specs, "replay", "nonlinear attitude models")
    model, model_why = args.model, None
    cfg = ReplayConfig(
        filters=tuple(args.filter_specs), start=args.start, end=args.end, smooth=args.smooth,
        seed=args.seed, rate_hz=args.rate, update_hz=args.update_rate,
        integration=args.integration,
        declination=declination,
        noise=parse_noise(args.noise), imu=args.imu, use_mag=not args.no_mag,
        accel_comp=args.accel_comp, mag_mode=args.mag_mode, mag_delay=args.mag_delay,
        model=model, gnss_delay=args.gnss_delay, model_why=model_why,
        baro_delay=args.baro_delay, geodesy=args.geodesy,
    )
    bar = _Progress(False if args.no_progress else None, args.log)
    sinks = [bar, ResetLog(), *recording_sinks(args)]
    doc = replay(args.log, cfg, sinks=sinks, command=" ".join(sys.argv), on_source=bar.source)
    print(format_doc(doc))
    if args.json:
        write_json(args.json, doc)
        print(f"wrote {args.json}")
        hint = aiding_hint(args.json, "replay")
        if hint:
            print(hint)
    finish_recording(args)
    if doc["reference"] is None:
        why = "; ".join(f"{k}: {v}" for k, v in doc["references_rejected"].items())
        print(f"uavest replay: error: {args.log}: nothing to score against: "
              + (f"no usable attitude reference ({why})" if why else
                 "the log has no attitude reference (truth, autopilot or AHRS2)"),
              file=sys.stderr)
        return 2
    return 0


def add_replay_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``replay`` on an argparse sub-parsers object (sets ``func``)."""
    p = subparsers.add_parser(
        "replay",
        help="replay a flight log through attitude filters and score them",
        description="Run attitude filters side by side over a log (tlog, DataFlash .BIN, "
        "ULog) and report roll/pitch/yaw RMSE against the log's truth (SITL) or, without "
        "truth, against the autopilot's own estimate. 'hybrid' means the attitude preset "
        "(see 'uavest list').",
    )
    p.add_argument("log", help="log file (.tlog, .bin, .ulg)")
    p.add_argument("--filters", default=",".join(DEFAULT_FILTERS),
                   help="comma-separated filter specs (default: ekf,ukf,hybrid), e.g. "
                   "'ekf,ukf,hybrid(n_cloud=32)'")
    p.add_argument("--json", help="write the results as JSON to this path")
    p.add_argument("--start", type=float, help="start time (s, vehicle clock)")
    p.add_argument("--end", type=float, help="end time (s, vehicle clock)")
    p.add_argument("--smooth", action="store_true",
                   help="also run the forward-backward (RTS) smoother and score it")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--rate", type=float, default=None,
                   help=f"max filter rate in Hz (default {DEFAULT_MAX_RATE_HZ:g}; gyro is "
                   "pre-integrated exactly between steps); 0 = every IMU sample")
    p.add_argument("--update-rate", type=float, default=None, metavar="HZ",
                   help=f"above {DEFAULT_MAX_RATE_HZ:g} Hz filter rate: accelerometer and "
                   f"magnetometer updates at most this often, on the mean specific force "
                   f"since the last one (default {DEFAULT_MAX_RATE_HZ:g}); 0 = every step, "
                   "each weighted by its share of a reference step")
    p.add_argument("--integration", default="auto", choices=("auto", "hold", "trapezoid"),
                   help="gyro sample interpretation (default auto: by what the IMU message "
                   "is, docs/ingest.md 'IMU message semantics'; an unknown one: trapezoid "
                   "below 20 Hz)")
    add_declination_option(p, "the log's COMPASS_DEC / EKF2_MAG_DECL / ATT_MAG_DECL, else "
                              "the World Magnetic Model at its first fix, else 0")
    p.add_argument("--noise", action="append", default=[], metavar="KEY=VALUE",
                   help="override a noise parameter (repeatable), e.g. --noise mag_noise=0.1; "
                   "the navigation model's win over the sensor spec a log may carry (its "
                   "SPEC_* parameters: a uavest sim recording)")
    p.add_argument("--imu", help="IMU source name (default: the stream's choice)")
    p.add_argument("--accel-comp", default="auto", choices=("auto", "none"),
                   help="remove the vehicle's own acceleration (causal difference of the "
                   "log's velocity) from the accelerometer before using it as gravity "
                   "(default auto: when the log has velocity)")
    p.add_argument("--mag-mode", default="field", choices=("field", "heading"),
                   help="magnetometer as 3-D field direction (default) or heading only")
    p.add_argument("--mag-delay", type=float, default=None,
                   help="magnetometer sample age in s, compensated with the gyro (default: "
                   "0 for the attitude model; estimated from the log for the navigation "
                   "model)")
    p.add_argument("--no-mag", action="store_true", help="do not use the magnetometer")
    p.add_argument("--model", default="auto", choices=("auto", "nav", "attitude"),
                   help="estimation model (default auto: navigation - attitude, velocity, "
                   "position, IMU biases, aided by raw GNSS, baro and magnetometer - when "
                   "the log carries a GNSS fix stream, attitude-only otherwise; "
                   "docs/navigation.md)")
    p.add_argument("--gnss-delay", type=float, default=None, metavar="S",
                   help="navigation model: GNSS measurement delay in s (default: the log's "
                   "sensor spec, SPEC_GPS_DLY, if it carries one; else estimated from the "
                   "log, the lag of the GNSS velocity behind the IMU; 0 when the log has too "
                   "little manoeuvring)")
    p.add_argument("--baro-delay", type=float, default=None, metavar="S",
                   help="navigation model: barometer measurement delay in s, a reading "
                   "stamped t applied to the height at t - S (default: estimated from the "
                   "log against the GNSS height; 0 when the log has too little climbing)")
    add_geodesy_option(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_recording_options(p)
    p.add_argument("--speed", type=float, default=1.0,
                   help="with --foxglove: replay paced at this many times real time "
                   "(default 1)")
    p.set_defaults(func=cmd_replay, filters_preset="attitude", paced=True)
    return p
