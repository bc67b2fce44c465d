"""``uavest run --connect CONN``: the live estimator, and ``uavest demo``: the built-in
simulator and the live estimator over loopback UDP."""

from __future__ import annotations

import argparse
import math
import signal
import socket
import sys
import threading

from ..apps.aiding import MAG_SITE_KM, aiding_hint, read_aiding
from ..apps.live import TRACKER_DIM, LiveConfig, run_live
from ..apps.replay import learnt_lines, resets_line
from ..errors import InputError
from ..ingest.adsb_radar import RadarConfig
from ..sinks.jsonout import write_json
from ..sinks.table import table
from .record import add_recording_options, finish_recording, recording_sinks
from .replay import (
    NAV_COLS,
    add_declination_option,
    add_geodesy_option,
    decision_lines,
    declination_rad,
    flat_row,
    parse_noise,
)

__all__ = ["add_demo_parser", "add_run_parser", "format_live"]


def _radar(args) -> RadarConfig:
    for name in ("sigma_range", "sigma_az_deg", "sigma_el_deg", "clutter_rate"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"--{name.replace('_', '-')} must be a finite number >= 0, got {v}")
    if not 0.0 <= args.pd <= 1.0:
        raise InputError(f"--pd must be in [0, 1], got {args.pd}")
    return RadarConfig(sigma_r=args.sigma_range, sigma_az=math.radians(args.sigma_az_deg),
                       sigma_el=math.radians(args.sigma_el_deg), pd=args.pd,
                       clutter_rate=args.clutter_rate, max_range=args.max_range)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--filters", default="ekf,ukf,hybrid",
                   help="attitude filters (attitude preset), default ekf,ukf,hybrid")
    p.add_argument("--trackers", default="ekf,ukf,hybrid",
                   help="tracker filters (radar preset), default ekf,ukf,hybrid; 'none' for "
                   "no tracking")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    p.add_argument("--json", help="write the results as JSON to this path")
    p.add_argument("--tlog", help="record the incoming stream to this tlog")
    p.add_argument("--radar-source", default="adsb", choices=("adsb", "obstacle"),
                   help="scans from the virtual radar over ADS-B traffic (default) or from "
                   "the vehicle's OBSTACLE_DISTANCE_3D detections")
    p.add_argument("--sigma-range", type=float, default=10.0, help="virtual radar range "
                   "noise std, m (default 10); also the trackers' model")
    p.add_argument("--sigma-az-deg", type=float, default=1.0, help="azimuth std, deg")
    p.add_argument("--sigma-el-deg", type=float, default=1.0, help="elevation std, deg")
    p.add_argument("--pd", type=float, default=0.9, help="virtual radar detection probability")
    p.add_argument("--clutter-rate", type=float, default=1.0,
                   help="virtual radar false detections per scan (Poisson mean)")
    p.add_argument("--max-range", type=float, default=5000.0, help="radar range, m")
    p.add_argument("--rate", type=float, default=None,
                   help="max attitude filter rate, Hz (default 25; 0 = every IMU sample)")
    p.add_argument("--update-rate", type=float, default=None, metavar="HZ",
                   help="above 25 Hz: accelerometer/magnetometer updates at most this often "
                   "(default 25; 0 = every step, weighted)")
    p.add_argument("--reorder-window", type=float, default=LiveConfig.reorder_window,
                   help="s of vehicle time the link holds messages to order them; "
                   f"{LiveConfig.reorder_window:g} (default): on arrival, each estimate made "
                   "as soon as its last sample arrives, a late sample applied at its time "
                   "within --history")
    p.add_argument("--history", type=float, default=LiveConfig.history_s, metavar="S",
                   help="on arrival: s of vehicle time kept to apply late samples at their "
                   "time (re-stepping the filters from before them; older ones are counted "
                   f"late and skipped; default {LiveConfig.history_s:g})")
    p.add_argument("--settle", type=float, default=LiveConfig.settle_s, metavar="S",
                   help="score each filter again from S s after its first estimate (the "
                   "'settled' table and JSON block: a start in flight converges first); 0 "
                   f"for none (default {LiveConfig.settle_s:g})")
    p.add_argument("--no-status", action="store_true", help="no live status line")
    p.add_argument("--model", default="attitude", choices=("attitude", "nav"),
                   help="attitude: attitude + gyro bias (default); nav: the GNSS-aided "
                   "navigation model (attitude, velocity, position, gyro and accelerometer "
                   "biases) from the raw GNSS stream (docs/navigation.md)")
    p.add_argument("--gnss-delay", type=float, default=None, metavar="S",
                   help="with --model nav: the GNSS measurement delay, s (default: the "
                   "vehicle's sensor spec, SPEC_GPS_DLY, if it states one; else estimated "
                   "during the run from 60 s after its first step, the model's 0 until then)")
    add_declination_option(p, "the vehicle's COMPASS_DEC / EKF2_MAG_DECL / ATT_MAG_DECL, "
                              "else the World Magnetic Model at the first fix, replaced by "
                              "the vehicle's own when it comes")
    p.add_argument("--mag-delay", type=float, default=None, metavar="S",
                   help="with --model nav: the magnetometer sample's age, s, compensated "
                   "with the gyro (default 0: not learnt live, for the age a replay "
                   "estimates costs yaw RMSE on the ArduCopter SITL; docs/live.md)")
    p.add_argument("--aiding-from", metavar="FILE",
                   help="with --model nav: start with what a previous run or replay of this "
                   "vehicle learned (its --json result): the GNSS delay and velocity window, "
                   "the baro and magnetometer noise, and the magnetic field's inclination if "
                   "this run starts "
                   f"within {MAG_SITE_KM:g} km of where it was learned; the run still learns "
                   "its own and takes them when it has them, and options given here win "
                   "(docs/live.md)")
    p.add_argument("--noise", action="append", default=[], metavar="KEY=VALUE",
                   help="override a noise parameter of the model (repeatable), e.g. --noise "
                   "mag_noise=0.01 (names and units: docs/navigation.md, docs/attitude.md); "
                   "with --model nav it wins over the vehicle's sensor spec (its SPEC_* "
                   "parameters, which uavest sim states); a navigation run gives its "
                   "filters an inclination state of 0.25 deg unless told mag_ref_inc or "
                   "mag_ref_dec (mag_ref_inc=0: none)")
    add_geodesy_option(p)


def add_run_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "run", help="the live estimator: attach to a vehicle or SITL over MAVLink",
        description="Attach to a vehicle (autopilot, ArduPilot/PX4 SITL, 'uavest sim') over "
        "MAVLink, ask for the streams it needs, and run attitude filters and trackers side "
        "by side in real time. Estimates are published only on --publish, a separate "
        "ground-station-side link, under the estimator's own system id (docs/live.md).")
    p.add_argument("--connect", required=True, help="pymavlink connection string: "
                   "udpin:127.0.0.1:14550, tcp:127.0.0.1:5760 (ArduPilot SITL), "
                   "/dev/ttyACM0,115200; or the tlog of a session (--tlog) to run the "
                   "same job over it again (the live run's estimates)")
    p.add_argument("--publish", help="ground-station-side link for the estimates, e.g. "
                   "udpout:127.0.0.1:14551 (never the vehicle's link)")
    p.add_argument("--publish-sysid", type=int, default=250,
                   help="our MAVLink system id on --publish (default 250)")
    p.add_argument("--sysid", type=int, help="listen to this vehicle only")
    p.add_argument("--signing-key", help="MAVLink 2 signing passphrase (sha256, the MAVProxy "
                   "convention) or a 32-byte key file; unsigned packets are then rejected")
    p.add_argument("--heartbeat-timeout", type=float, default=30.0,
                   help="s to wait for the vehicle's heartbeat (default 30)")
    _common(p)
    add_recording_options(p, report=False)
    p.set_defaults(func=cmd_run, filters_preset="attitude")
    return p


def _cfg(args, connect: str) -> LiveConfig:
    trackers = () if args.trackers.strip() in ("", "none") else tuple(
        s for s in args.trackers.split(","))
    from ..core.spec import split_filter_list
    from ..presets import resolve_list

    if args.gnss_delay is not None and not (math.isfinite(args.gnss_delay)
                                             and args.gnss_delay >= 0):
        raise InputError(f"--gnss-delay must be a finite number of seconds >= 0, got "
                         f"{args.gnss_delay}")
    dec = declination_rad(args)
    md = getattr(args, "mag_delay", None)
    if md is not None and not (math.isfinite(md) and 0 <= md <= 10.0):
        raise InputError(f"--mag-delay must be a finite number of seconds in [0, 10], got {md}")
    if md is not None and args.model != "nav":
        raise InputError("--mag-delay needs --model nav (the attitude model's live "
                         "magnetometer is taken at age 0)")
    aiding, aiding_why = {}, None
    if getattr(args, "aiding_from", None):
        if args.model != "nav":
            raise InputError("--aiding-from needs --model nav (it carries the navigation "
                             "model's aiding)")
        aiding, aiding_why = read_aiding(args.aiding_from)
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration must be > 0 s, got {args.duration}")
    for name, v in (("rate", args.rate), ("update-rate", getattr(args, "update_rate", None))):
        if v is not None and not (v >= 0 and math.isfinite(v)):
            raise InputError(f"--{name} must be >= 0 Hz (0 = every step), got {v}")
    return LiveConfig(
        connect=connect, filters=tuple(args.filter_specs or split_filter_list(args.filters)),
        trackers=tuple(resolve_list(",".join(trackers), "radar", TRACKER_DIM)) if trackers else (),
        seed=args.seed, sysid=getattr(args, "sysid", None),
        signing_key=getattr(args, "signing_key", None), tlog=args.tlog,
        heartbeat_timeout=getattr(args, "heartbeat_timeout", 30.0),
        reorder_window=args.reorder_window, history_s=args.history, settle_s=args.settle,
        duration=args.duration, rate_hz=args.rate,
        update_hz=getattr(args, "update_rate", None),
        radar_source=args.radar_source, radar=_radar(args), model=args.model,
        gnss_delay=args.gnss_delay, mag_delay=md,
        declination=dec, geodesy=args.geodesy,
        noise=parse_noise(args.noise),
        aiding=aiding, aiding_why=aiding_why)


def format_live(doc: dict) -> str:
    """The side-by-side tables of a live run."""
    ref, kind = doc["reference"], doc["reference_kind"]
    what = "none" if ref is None else (f"{ref} (truth)" if kind == "truth"
                                       else f"{ref} ({kind} estimate, not truth)")
    lines = decision_lines(doc)
    cols = ["roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg", "nees_mean", "resets",
            "us_per_step"]
    title = f"attitude against {what}; RMSE in degrees"
    rows = doc["attitude"]
    if doc.get("model") == "nav":
        # "rejected": the aiding updates the filter's gates dropped (JSON ``gates``)
        cols[4:4] = ["vel_rmse_ms", "hpos_rmse_m", "vpos_rmse_m", "rejected"]
        rows = {k: flat_row(r) for k, r in rows.items()}
        pref = next((r["position_reference"] for r in doc["attitude"].values()
                     if r.get("position_reference")), None)
        title = (f"navigation model; attitude against {what}, RMSE in degrees; velocity "
                 f"(m/s) and position (m) against {pref or 'no position reference'}")
    nz = doc.get("noise") or {}
    if nz.get("overrides"):
        lines.append("noise: " + ", ".join(f"{k} {v:.4g}" for k, v in nz["overrides"].items())
                     + f" ({nz['why']})")
    lines += [title, table(rows, cols)]
    lines += _settled_lines(doc)
    reset = resets_line({k: r.get("resets", 0) for k, r in doc["attitude"].items()},
                        {k: r["resets_why"] for k, r in doc["attitude"].items()
                         if r.get("resets_why")})
    if reset:
        lines.append(reset)
    lines += learnt_lines(doc["attitude"], doc)
    live = doc.get("gnss_delay_live")
    tries = (live or {}).get("tries") or []
    if live and live.get("given") is None and live["delay"] is None:
        last = tries[-1]["why"] if tries else "the run ended before the first try"
        lines.append(f"GNSS delay: not estimated live ({last}); --gnss-delay S to set it")
    elif live and live.get("given") is not None and live.get("window") is None:
        last = (tries[-1].get("window_why") or tries[-1]["why"] if tries
                else "the run ended before the first try")
        lines.append(f"GNSS velocity window: not estimated live at the given delay ({last})")
    if doc["tracks"]:
        lines += ["", f"tracks against ADS-B truth ({doc['targets_seen']} aircraft seen, "
                  f"{doc['scans']} scans); GOSPA and position RMSE in m",
                  table(doc["tracks"], ["pos_rmse", "gospa", "nees_mean", "track_breaks",
                                        "id_swaps", "false_tracks", "us_per_scan"])]
    attitude_filters = [k for k in doc["run"]["filters"] if not k.startswith("track:")]
    if attitude_filters and not doc.get("attitude_steps", 1):
        lines.append("attitude: no estimates (" + (
            "no IMU sample received)" if not doc.get("imu_samples") else
            f"{doc['imu_samples']} IMU samples but no alignment)"))
    link = doc.get("link", {})
    if link:
        bad = link["bad_data"]
        lines.append(f"\nlink: vehicle {link['vehicle_sysid']}, declination "
                     f"{math.degrees(link['declination_rad'] or 0.0):.2f} deg "
                     f"({link['declination_source']}), gaps {len(link['gaps'])}, bad data "
                     f"{bad['bad_total']}")
        miss = link.get("missing_streams") or []
        if miss:
            lines.append(f"streams missing (none received): {', '.join(miss)}")
    if doc.get("latency_ms"):
        lat = doc["latency_ms"]
        lines.append(f"latency sample -> estimate: p50 {lat['p50']:.2f} ms, "
                     f"p99 {lat['p99']:.2f} ms")
    hist = doc.get("history") or {}
    if hist.get("on_arrival"):
        lanes = hist.get("lanes", {}).values()
        lines.append(f"samples on arrival: {sum(v['rewinds'] for v in lanes)} late ones "
                     f"applied at their time (history {hist['history_s']:g} s), "
                     f"{sum(v['late'] for v in lanes)} older skipped (counted late)")
    return "\n".join(lines)


def _settled_lines(doc: dict) -> list[str]:
    """The ``settled`` table: each filter's scores from ``after_s`` after its first
    estimate (RMSE, and the share of steps with the NEES in its 95 % band per block)."""
    rows = {k: flat_row(r["settled"]) for k, r in doc["attitude"].items()
            if isinstance(r.get("settled"), dict)}
    if not rows:
        return []
    after = next(iter(rows.values())).get("after_s")
    cols = ["roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg"] + (
        NAV_COLS if doc.get("model") == "nav" else ["nees_mean"])
    return [f"settled (from {after:g} s after each filter's first estimate; --settle):",
            table(rows, cols)]


def _wait(msg: str) -> None:
    print(f"uavest: {msg}", file=sys.stderr)


def _stop_on_signals() -> threading.Event:
    """SIGINT / SIGTERM end the run cleanly (results printed, every file complete)."""
    stop = threading.Event()

    def handler(signum, frame) -> None:
        if stop.is_set():  # a second signal: stop now
            raise KeyboardInterrupt
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
    return stop


def _finish(args, doc: dict, failures: list) -> int:
    """Tables, ``--json``, the recording's line; then a sink that failed during the run
    ends the command as its error would have: an ``OSError`` (a full disk, a path that
    cannot be written) as bad input (one line, exit 2), anything else as an internal
    error (exit 1, the traceback with ``-v``). The estimates were made either way."""
    print(format_live(doc))
    if args.json:
        write_json(args.json, doc)
        print(f"wrote {args.json}")
        hint = aiding_hint(args.json, "run")
        if hint:
            print(hint)
    if failures:
        raise failures[0].error
    finish_recording(args)
    return 0


def cmd_run(args) -> int:
    cfg = _cfg(args, args.connect)
    failures: list = []
    doc = run_live(cfg, command=" ".join(sys.argv), status=False if args.no_status else None,
                   on_wait=_wait, publish=args.publish, publish_sysid=args.publish_sysid,
                   stop=_stop_on_signals(), sinks=recording_sinks(args), on_note=_wait,
                   failures=failures)
    return _finish(args, doc, failures)


# ----------------------------------------------------------------------------- demo


def add_demo_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo", help="the built-in simulator and the live estimator over loopback UDP",
        description="Start the built-in MAVLink vehicle-and-radar simulator and the live "
        "estimator, talking over real UDP on 127.0.0.1, for --duration seconds (default "
        "30), then print attitude and track errors of every filter against the "
        "simulator's truth. No hardware, no SITL, no network beyond loopback.")
    p.add_argument("scenario", nargs="?", default="sim_default", help="sim scenario")
    p.add_argument("--speed", type=float, default=1.0,
                   help="simulated seconds per wall second (default 1: real time)")
    p.add_argument("--imu-rate", type=float, default=200.0, help="simulated IMU rate, Hz")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario value, as uavest sim --set (repeatable), e.g. "
                   "--set imu.gyro_drift=1e-4 for a gyro bias that ramps")
    _common(p)
    add_recording_options(p, mcap_default="uavest-demo.mcap")
    p.add_argument("--no-record", action="store_true", help="do not write the recording")
    p.set_defaults(func=cmd_demo, filters_preset="attitude", duration=30.0)
    return p


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def demo(args) -> dict:
    """Run the simulator and the live estimator side by side; returns the result doc."""
    from ..scenarios import load_typed
    from ..sim import Simulator

    if not args.speed > 0:
        raise InputError(f"--speed must be > 0 for a live demo, got {args.speed}")
    port = _free_udp_port()
    sc = load_typed(args.scenario, list(args.sets))
    sim = Simulator(sc, seed=args.seed, imu_rate=args.imu_rate)
    stop = threading.Event()
    errors: list = []

    def sim_main() -> None:
        try:
            sim.run(f"udpout:127.0.0.1:{port}", duration=None, speed=args.speed,
                    stop_event=stop, wait_gcs=True)
        except Exception as e:  # noqa: BLE001 - reported after the run
            errors.append(e)

    th = threading.Thread(target=sim_main, name="uavest-sim", daemon=True)
    th.start()
    cfg = _cfg(args, f"udpin:127.0.0.1:{port}")
    cfg.heartbeat_timeout = 15.0
    # the simulator states its sensors' datasheet as SPEC_* parameters, which the live
    # run takes where the options leave a value open (uavest.apps.sensor_spec)
    # uavest's simulator sends SIMSTATE, not ArduPilot SITL's SIM_STATE (whose presence
    # would put the navigation frame on ArduPilot's sphere): not asked, not "missing"
    cfg.streams = {k: v for k, v in cfg.streams.items() if k != "SIM_STATE"}
    print(f"uavest demo: simulator '{args.scenario}' -> udp 127.0.0.1:{port} -> live "
          f"estimator, {args.duration:g} s", file=sys.stderr)
    try:
        if args.no_record:
            args.mcap = args.mcap_default = None
        doc = run_live(cfg, command=" ".join(sys.argv),
                       status=False if args.no_status else None, on_wait=_wait,
                       stop=_stop_on_signals(), sinks=recording_sinks(args), on_note=_wait,
                       failures=getattr(args, "failures", None))
    finally:
        stop.set()
        th.join(timeout=10)
    if errors:  # bad input or a link failure: one line; anything else is a bug of ours
        if isinstance(errors[0], InputError | OSError):
            raise InputError(f"simulator failed: {errors[0]}") from errors[0]
        raise errors[0]
    doc["simulator"] = {"scenario": args.scenario, "speed": args.speed, "port": port,
                        "seed": args.seed, "imu_rate_hz": args.imu_rate,
                        "sets": list(args.sets)}
    return doc


def cmd_demo(args) -> int:
    args.failures = []
    doc = demo(args)
    return _finish(args, doc, args.failures)
