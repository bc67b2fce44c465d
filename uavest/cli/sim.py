"""``uavest sim``: the built-in vehicle-and-radar simulator on a MAVLink 2 link.

Usage: ``uavest sim [SCENARIO] --out CONN [--imu-rate HZ] [--duration S] [--speed X]
[--seed S] [--sysid N] [--tlog PATH] [--rate NAME=HZ ...] [--set KEY=VALUE ...]``.
See ``docs/sim.md``. Exit status: 0 when the duration is reached *or* the run is stopped
by SIGINT / SIGTERM (the tlog is then closed after a whole record); 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading


def _parse_rates(items: list[str]) -> dict[str, float]:
    out = {}
    for it in items or ():
        if "=" not in it:
            raise argparse.ArgumentTypeError(f"--rate {it!r}: expected NAME=HZ")
        k, v = it.split("=", 1)
        try:
            out[k.strip().upper()] = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--rate {it!r}: {v.strip()!r} is not a number "
                                             "of Hz") from None
    return out


def add_sim_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``sim`` sub-command to an argparse ``subparsers`` object (sets ``func``)."""
    p = subparsers.add_parser(
        "sim",
        help="simulated ArduPilot-like vehicle + radar speaking MAVLink 2 (no SITL needed)",
        description="Simulate a quadrotor (IMU, magnetometer, GPS, autopilot attitude, truth "
        "as SIMSTATE) and a radar seeing the scenario's aircraft (OBSTACLE_DISTANCE_3D, "
        "ADSB_VEHICLE), sent over MAVLink 2. Like an ArduPilot SITL it sends only HEARTBEAT "
        "until asked (SET_MESSAGE_INTERVAL / REQUEST_DATA_STREAM) unless --rate is given.",
    )
    _fill(p)
    return p


def _fill(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", default="sim_default",
                   help="scenario name or .toml path (default sim_default)")
    p.add_argument("--out", default="udpout:127.0.0.1:14550",
                   help="pymavlink connection string (default udpout:127.0.0.1:14550; "
                   "tcpin:127.0.0.1:5760 behaves like a SITL's TCP port; 'none' = no link)")
    p.add_argument("--imu-rate", type=float, help="IMU sample / simulation step rate, Hz "
                   "(default the scenario's imu.rate_hz, 400)")
    p.add_argument("--duration", type=float,
                   help="simulated seconds to run (default: until SIGINT/SIGTERM; "
                   "required with --out none)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="simulated seconds per wall second (1 = real time, 0 = as fast as "
                   "possible; default 1)")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--tlog", help="also write everything sent to this .tlog")
    p.add_argument("--truth", help="also write a truth CSV (vehicle, targets, detection "
                   "origins; columns in docs/sim.md) as the run goes")
    p.add_argument("--truth-rate", type=float, default=10.0,
                   help="rows per second for vehicle/targets in --truth (default 10)")
    p.add_argument("--rate", action="append", default=[], metavar="NAME=HZ",
                   help="start a message (RAW_IMU, HIGHRES_IMU, SIMSTATE, ...) or a data "
                   "stream (RAW_SENSORS, EXTENDED_STATUS, POSITION, EXTRA1..3, ALL; capped "
                   "at 50 Hz) as if requested; repeatable")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario value, e.g. --set radar.pd=0.8")
    p.add_argument("--wait", action="store_true",
                   help="hold the simulated clock at 0 until a peer connects / sends")
    p.add_argument("--params", action="store_true",
                   help="send the parameter list (PARAM_VALUE, e.g. COMPASS_DEC) once at start")
    p.add_argument("--no-spec", action="store_true",
                   help="do not state the sensors' datasheet (the SPEC_* parameters), as "
                   "an autopilot does not: an estimator then uses its IMU source's "
                   "default noise profile")
    p.add_argument("--quiet", action="store_true", help="no summary on stderr")
    p.set_defaults(func=cmd_sim)


def cmd_sim(args) -> int:
    """Run the simulator from parsed arguments; returns the exit status."""
    from ..errors import InputError
    from ..scenarios import ScenarioError, load_typed
    from ..sim import Simulator

    try:
        scn = load_typed(args.scenario, args.sets)
        if scn.kind != "sim":
            raise ScenarioError(f"scenario {scn.name!r} is kind {scn.kind!r}, "
                                "expected 'sim'")
        rates = _parse_rates(args.rate)
        sim = Simulator(scn, seed=args.seed, imu_rate=args.imu_rate, sysid=args.sysid,
                        rates=rates, state_spec=not args.no_spec)
    # bad values are InputErrors; a KeyError is a required key missing from a scenario
    # table (e.g. a target without position_ned)
    except (InputError, argparse.ArgumentTypeError, KeyError) as e:
        print(f"uavest sim: {e}", file=sys.stderr)
        return 2
    if args.speed < 0 or (args.duration is not None and args.duration < 0):
        print("uavest sim: --speed and --duration must be >= 0", file=sys.stderr)
        return 2
    out = None if str(args.out).lower() == "none" else args.out
    if out is None and args.duration is None:
        print("uavest sim: --out none needs --duration", file=sys.stderr)
        return 2
    stop = threading.Event()

    def _on_signal(signum, frame):  # noqa: ARG001
        stop.set()

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        if not args.quiet:
            print(f"uavest sim: {scn.name} -> {out or 'no link'}"
                  f"{' + ' + args.tlog if args.tlog else ''}, IMU {sim.imu_rate:g} Hz, "
                  f"speed {args.speed:g}, seed {args.seed}", file=sys.stderr, flush=True)
        summary = sim.run(out, duration=args.duration, speed=args.speed, stop_event=stop,
                          tlog=args.tlog, wait_gcs=args.wait,
                          send_params=args.params, truth=args.truth,
                          truth_rate=args.truth_rate)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if not args.quiet:
        print(f"uavest sim: {summary}", file=sys.stderr, flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m uavest.cli.sim ...`` (same options as ``uavest sim``)."""
    p = argparse.ArgumentParser(prog="uavest sim", description="uavest built-in simulator")
    _fill(p)
    args = p.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
