"""`uavest run` attached to `uavest sim`, over many simulated flights: per seed and IMU
rate, the simulator's own tlog (made as fast as it can, sending what the live job asks
for and its SPEC parameters, as it does live) and then the live job over it (`uavest run
--connect TLOG`: the estimates of a live run, docs/live.md), then per filter the mean and
worst over the seeds of the whole-run and settled RMSE and NEES in-band shares, and how
many seeds meet issue 19's targets (all of them, and those of the attitude and velocity),
and each NEES block's mean over the flights (3, its dimension, for a consistent filter).
One live session is one realisation of the flight's noise and start; this shows the
spread (docs/live.md, "Over many flights"). Beside each flight's horizontal position
error, the receiver's own: its fixes against the simulator's truth over the same part
of the flight (the simulated receiver's slowly varying error, which no filter here can
tell from the position), and where a position NEES misses its band, on which side.

    OMP_NUM_THREADS=1 python benchmarks/live_seeds.py [--seeds 0-7] [--rates 200,400]
        [--filters ekf] [--duration 32] [--settle 10] [--jobs 2] [--rows]
        [--noise KEY=VALUE ...] [--set KEY=VALUE ...] [--keep DIR]
        [--aiding-from FILE | --aiding-flight SEED] [--aiding-keys mag_inclination,...]

``--aiding-flight SEED``: every flight's live job starts with what a replay (navigation
EKF) of another flight, seed SEED, 60 s at the highest rate with the same ``--set``,
learned, as ``uavest run --aiding-from`` would take it from that replay's JSON: a
previous flight at the same site.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import tempfile  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from uavest.apps.aiding import read_aiding  # noqa: E402
from uavest.apps.live import LIVE_STREAMS, LiveConfig, run_live  # noqa: E402
from uavest.cli.replay import parse_noise  # noqa: E402
from uavest.errors import InputError  # noqa: E402
from uavest.scenarios import load_typed  # noqa: E402
from uavest.sim.mavlink import Simulator  # noqa: E402
from uavest.sim.protocol import PERIODIC  # noqa: E402

#: issue 19's targets: roll / pitch / yaw RMSE deg, velocity RMSE m/s, horizontal
#: position RMSE m, and the share of steps with each NEES block in its 95 % band
TARGETS = {"rpy": (0.26, 0.24, 0.9), "vel": 0.3, "hpos": 1.5, "in95": 0.8}
BLOCKS = ("attitude", "velocity", "position")


def session_tlog(path: str | Path, seed: int, rate: float, duration: float,
                 sets: list[str]) -> None:
    """The simulator's tlog of one flight (``seed``, IMU ``rate`` Hz, ``duration`` s,
    scenario overrides ``sets``) with the periodic messages the live job asks for at its
    rates (:data:`~uavest.apps.live.LIVE_STREAMS`) and the parameter list."""
    rates = {k: v for k, v in LIVE_STREAMS.items() if k in PERIODIC}
    sim = Simulator(load_typed("sim_default", list(sets)), seed=seed, imu_rate=rate,
                    rates=rates)
    sim.run(None, duration=duration, speed=0, tlog=path, send_params=True)


def scores(r: dict) -> dict:
    """One filter's figures from a live JSON block (``doc["attitude"][label]``): for
    ``whole`` and ``settled``, roll / pitch / yaw RMSE (deg), velocity and horizontal
    position RMSE, the three NEES blocks' in-band shares and means, and the position
    NEES's shares below and above its band."""
    def part(d: dict) -> dict:
        pos = d["nees"]["position"]
        return {"rpy": [d[k] for k in ("roll_rmse_deg", "pitch_rmse_deg", "yaw_rmse_deg")],
                "vel": d["vel_rmse_ms"], "hpos": d["hpos_rmse_m"],
                "in95": [d["nees"][b]["in_band95"] for b in BLOCKS],
                "nees": [d["nees"][b]["mean"] for b in BLOCKS],
                "pos_out": [pos["below_band95"], pos["above_band95"]]}
    return {"whole": part(r), "settled": part(r["settled"])}


def receiver_hpos(path: str | Path, settle: float) -> dict[str, float]:
    """The receiver's own horizontal position error (m, RMS): every 3-D fix of the
    simulator's tlog (GNSS samples as the live job reads them) against the simulator's
    true position (HIL_STATE_QUATERNION) interpolated to the fix's time, over the whole
    flight and from ``settle`` s after the first fix (``whole``, ``settled``)."""
    from uavest.geometry.geodesy import geodetic_to_ned
    from uavest.ingest import open_source
    from uavest.ingest.types import GnssSample, PositionSample

    fix_t, fix, ref_t, ref = [], [], [], []
    for smp in open_source(str(path)):
        if isinstance(smp, GnssSample) and smp.fix_type >= 3:
            fix_t.append(smp.t)
            fix.append(smp.lat_lon_alt)
        elif (isinstance(smp, PositionSample) and smp.source == "HIL_STATE_QUATERNION"
              and smp.lat_lon_alt is not None):
            ref_t.append(smp.t)
            ref.append(smp.lat_lon_alt)
    t, fix, rt, ref = np.array(fix_t), np.array(fix), np.array(ref_t), np.array(ref)
    truth = np.column_stack([np.interp(t, rt, ref[:, k]) for k in range(3)])
    # both in one local frame at the first true position (the flight spans a few hundred
    # metres: the frame's curvature is far below a millimetre)
    err = geodetic_to_ned(fix, ref[0])[:, :2] - geodetic_to_ned(truth, ref[0])[:, :2]
    e2 = np.sum(err**2, axis=1)
    late = t >= t[0] + settle
    return {"whole": float(np.sqrt(e2.mean())), "settled": float(np.sqrt(e2[late].mean()))}


def meets(p: dict) -> bool:
    """Every target met by one part (:func:`scores`)."""
    return (meets_attitude_velocity(p) and p["hpos"] <= TARGETS["hpos"]
            and p["in95"][2] >= TARGETS["in95"])


def meets_attitude_velocity(p: dict) -> bool:
    """The attitude's and the velocity's targets met by one part (:func:`scores`): RMSE
    and NEES."""
    rpy_ok = all(v <= t for v, t in zip(p["rpy"], TARGETS["rpy"], strict=True))
    return (rpy_ok and p["vel"] <= TARGETS["vel"]
            and min(p["in95"][:2]) >= TARGETS["in95"])


def trial(seed: int, rate: float, filters: tuple[str, ...], duration: float, settle: float,
          noise: dict, sets: list[str], keep: str | None, aiding: dict | None = None,
          aiding_why: str | None = None) -> dict[str, dict]:
    """{filter label: :func:`scores`} of the live job over one simulated flight, started
    with ``aiding`` (``--aiding-from``, :func:`~uavest.apps.aiding.read_aiding`), and
    under ``"receiver"`` the receiver's own error (:func:`receiver_hpos`)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(keep or tmp) / f"seed{seed}_{rate:g}hz.tlog"
        session_tlog(path, seed, rate, duration, sets)
        cfg = LiveConfig(connect=str(path), filters=filters, trackers=(), seed=0,
                         model="nav", settle_s=settle, noise=dict(noise),
                         aiding=dict(aiding or {}), aiding_why=aiding_why)
        doc = run_live(cfg, status=False, on_note=lambda _: None)
        rx = receiver_hpos(path, settle)
    return {**{lab: scores(r) for lab, r in doc["attitude"].items() if "settled" in r},
            "receiver": rx}


def previous_flight(seed: int, rate: float, sets: list[str]) -> tuple[dict, str]:
    """What ``uavest run --aiding-from`` takes from the JSON result of a navigation replay
    (EKF) of the simulator's 60-s flight ``seed`` at ``rate`` Hz with ``sets``."""
    from uavest.apps.replay import ReplayConfig, replay
    from uavest.sinks.jsonout import write_json

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"seed{seed}_{rate:g}hz.tlog"
        session_tlog(path, seed, rate, 60.0, sets)
        doc = replay(str(path), ReplayConfig(filters=("ekf",), model="nav"))
        got, why = read_aiding(write_json(Path(tmp) / f"seed{seed}.json", doc))
    return got, f"{why}: a replay of seed {seed}'s flight"


def seed_list(text: str) -> list[int]:
    """``0-7`` or ``0,2,5`` (or both, comma separated)."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def summary(runs: dict[int, dict[str, dict]], label: str) -> dict:
    """Mean and worst over the seeds of one filter's figures, the seeds meeting every
    target and those meeting the attitude's and velocity's (whole run, settled)."""
    per = [runs[s][label] for s in sorted(runs) if label in runs[s]]
    out = {"n": len(per)}
    for part in ("whole", "settled"):
        rpy = np.array([p[part]["rpy"] for p in per])
        in95 = np.array([p[part]["in95"] for p in per])
        out[part] = {"rpy_mean": rpy.mean(0), "rpy_max": rpy.max(0),
                     "vel_mean": float(np.mean([p[part]["vel"] for p in per])),
                     "hpos_mean": float(np.mean([p[part]["hpos"] for p in per])),
                     "hpos_max": float(np.max([p[part]["hpos"] for p in per])),
                     "in95_mean": in95.mean(0), "in95_min": in95.min(0),
                     "nees_mean": np.mean([p[part]["nees"] for p in per], axis=0),
                     "meets": sum(meets(p[part]) for p in per),
                     "meets_att_vel": sum(meets_attitude_velocity(p[part]) for p in per)}
    return out


def _seeds(text: str) -> list[int]:
    """:func:`seed_list` as an argparse type (a one-line error for bad text)."""
    try:
        return seed_list(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seeds as 0-7 or 0,3,5, not {text!r}") from None


def _rates(text: str) -> list[float]:
    """Comma-separated IMU rates (Hz, > 0) as an argparse type."""
    try:
        rates = [float(r) for r in text.split(",")]
    except ValueError:
        rates = []
    if not rates or not all(np.isfinite(r) and r > 0 for r in rates):
        raise argparse.ArgumentTypeError(f"expected rates in Hz as 200,400, not {text!r}")
    return rates


def _f(a) -> str:
    return " / ".join(f"{v:.3f}" for v in np.atleast_1d(a))


def _pos_out(p: dict) -> str:
    """Where a position NEES under its target lies: below its band (the error smaller
    than the filter says it may be) or above (larger)."""
    if p["in95"][2] >= TARGETS["in95"]:
        return ""
    below, above = p["pos_out"]
    return f" (position NEES below its band {below:.3f}, above {above:.3f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0-7", type=_seeds,
                    help="simulator seeds: 0-7 or 0,3,5")
    ap.add_argument("--rates", default="200,400", type=_rates, help="IMU rates, Hz")
    ap.add_argument("--filters", default="ekf")
    ap.add_argument("--duration", type=float, default=32.0, help="simulated s per flight")
    ap.add_argument("--settle", type=float, default=10.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rows", action="store_true", help="also print every seed's row")
    ap.add_argument("--noise", action="append", default=[], metavar="KEY=VALUE",
                    help="a navigation noise parameter, as uavest run")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scenario override, as uavest sim --set")
    ap.add_argument("--keep", help="keep the tlogs in this directory")
    ap.add_argument("--aiding-from", metavar="FILE",
                    help="start every flight's live job with what this result learned, as "
                    "uavest run --aiding-from (e.g. a replay of another flight)")
    ap.add_argument("--aiding-flight", type=int, metavar="SEED",
                    help="as --aiding-from, from a replay of this seed's 60-s flight")
    ap.add_argument("--aiding-keys", metavar="K1,K2",
                    help="take only these of it (gnss_delay, gnss_vel_window, baro_noise, "
                    "mag_inclination)")
    a = ap.parse_args()
    seeds, rates = a.seeds, a.rates
    filters = tuple(a.filters.split(","))
    try:  # uavest run's own checks of --noise (name, number, >= 0) and the scenario's
        noise = parse_noise(a.noise)
        load_typed("sim_default", list(a.set))
        aiding, aiding_why = read_aiding(a.aiding_from) if a.aiding_from else ({}, None)
        if a.aiding_flight is not None:
            aiding, aiding_why = previous_flight(a.aiding_flight, max(rates), a.set)
    except InputError as e:
        ap.error(str(e))
    if a.aiding_keys:
        keys = set(a.aiding_keys.split(","))
        if "mag_inclination" in keys:
            keys |= {"mag_site_lat", "mag_site_lon"}
        aiding = {k: v for k, v in aiding.items() if k in keys}
    if a.keep:
        Path(a.keep).mkdir(parents=True, exist_ok=True)
    jobs = [(s, r) for r in rates for s in seeds]
    with ProcessPoolExecutor(max(1, a.jobs)) as ex:
        futs = {j: ex.submit(trial, j[0], j[1], filters, a.duration, a.settle, noise,
                             a.set, a.keep, aiding, aiding_why) for j in jobs}
        res = {j: f.result() for j, f in futs.items()}
    print(f"live job over the simulator's flights: seeds {','.join(map(str, seeds))}, "
          f"{a.duration:g} s, "
          f"settled from {a.settle:g} s; noise {noise or 'the spec'}; sets {a.set or 'none'}"
          + (f"; aiding {aiding} ({aiding_why})" if aiding_why else ""))
    print("RMSE roll / pitch / yaw deg; in95 attitude / velocity / position; targets "
          f"{_f(TARGETS['rpy'])} deg, vel {TARGETS['vel']} m/s, hpos {TARGETS['hpos']} m, "
          f"in95 {TARGETS['in95']}")
    for r in rates:
        runs = {s: res[(s, r)] for s in seeds}
        for lab in filters:
            sm = summary(runs, lab)
            print(f"\n{r:g} Hz, {lab}, {sm['n']} seeds")
            for part in ("whole", "settled"):
                p = sm[part]
                print(f"  {part:7s} RMSE mean {_f(p['rpy_mean'])} max {_f(p['rpy_max'])} | "
                      f"vel {p['vel_mean']:.3f} | hpos mean {p['hpos_mean']:.3f} max "
                      f"{p['hpos_max']:.3f} | in95 mean {_f(p['in95_mean'])} min "
                      f"{_f(p['in95_min'])} | NEES mean {_f(p['nees_mean'])} | "
                      f"every target: {p['meets']} of {sm['n']}, "
                      f"attitude and velocity: {p['meets_att_vel']}")
            if a.rows:
                for s in seeds:
                    if lab in runs[s]:
                        w, st = runs[s][lab]["whole"], runs[s][lab]["settled"]
                        rx = runs[s]["receiver"]
                        print(f"    seed {s}: whole {_f(w['rpy'])}, hpos {w['hpos']:.3f} "
                              f"(receiver {rx['whole']:.3f}), in95 {_f(w['in95'])}; "
                              f"settled {_f(st['rpy'])}, hpos {st['hpos']:.3f} (receiver "
                              f"{rx['settled']:.3f}), in95 {_f(st['in95'])}"
                              + _pos_out(st))


if __name__ == "__main__":
    main()
