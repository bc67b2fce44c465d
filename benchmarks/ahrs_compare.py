"""Benchmark: the ``ahrs`` package's filters (Madgwick, Mahony, EKF) against ours on the
same IMU stream of a log, scored against the same reference.

    python benchmarks/ahrs_compare.py ../shared/logs/vtol.tlog [--smooth] [--json out.json]

The ahrs filters get exactly what ours get: the chosen IMU source's gyro (rad/s), accel
and magnetometer samples, stepped with the real time between samples (``dt``), starting
from the same accel+mag initial attitude (:func:`uavest.models.attitude.initial_attitude`).
Frames: our data are body FRD -> NED. ahrs's Madgwick and Mahony take an accelerometer
that reads +g "up" and a field reference (bx, 0, bz) with z along gravity; feeding them
FRD gyro/mag with the accelerometer negated (gravity direction, "down") makes their
earth frame NED with magnetic north as x, so their quaternion is body FRD -> NED up to the
declination, which we apply (``q = qz(decl) * q_ahrs``). ahrs's EKF runs in its NED
mode with the field reference built from the first sample's dip angle and the log's
declination (no truth is used). Each ahrs filter is run with its default gains. Ours run
with the replay defaults (including the velocity-based accel compensation when the log
has velocity; ``--accel-comp none`` turns it off for an like-for-like input set).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np

from uavest.apps.replay import ReplayConfig, replay
from uavest.cli.replay import format_doc
from uavest.eval.attitude import rmse_deg, select_reference
from uavest.geometry.rotation import euler_to_quat, quat_conj, quat_mul, quat_slerp_interp
from uavest.ingest import read_log
from uavest.models.attitude import declination_from_params, initial_attitude
from uavest.sinks.jsonout import write_json


def run_ahrs(name: str, t, gyro, accel, mag, decl: float) -> np.ndarray:
    """Quaternions (N, 4), body FRD -> NED, from an ahrs filter stepped sample by sample."""
    import ahrs.filters as F

    g = -accel  # gravity direction ("down"), as ahrs's Madgwick/Mahony/EKF(NED) expect
    q0 = initial_attitude(accel[0], mag[0], decl)
    qz = euler_to_quat(0.0, 0.0, decl)
    q = quat_mul(quat_conj(qz), q0)  # ahrs works w.r.t. magnetic north
    if name == "madgwick":
        f = F.Madgwick()
        step = f.updateMARG
    elif name == "mahony":
        f = F.Mahony()
        step = f.updateMARG
    elif name == "ekf":
        m0 = mag[0] / np.linalg.norm(mag[0])
        down = g[0] / np.linalg.norm(g[0])
        dip = np.degrees(np.arcsin(np.clip(m0 @ down, -1, 1)))
        f = F.EKF(frame="NED", magnetic_ref=float(dip))
        f.mag = np.zeros((1, 3))  # ahrs's EKF fuses mag only if constructed with data
        step = f.update
    else:
        raise ValueError(name)
    out = np.empty((t.shape[0], 4))
    out[0] = q
    for k in range(1, t.shape[0]):
        dt = float(t[k] - t[k - 1])
        q = np.asarray(step(q, gyro[k], g[k], mag[k], dt=dt), float)
        if not np.isfinite(q).all():
            q = out[k - 1]
        out[k] = q
    return quat_mul(qz[None, :], out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log")
    ap.add_argument("--filters", default="ekf,ukf,hybrid")
    ap.add_argument("--smooth", action="store_true")
    ap.add_argument("--accel-comp", default="auto", choices=("auto", "none"))
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    warnings.filterwarnings("ignore")
    data = read_log(args.log)
    if data.mag is None:
        print("ahrs_compare: the log has no magnetometer", file=sys.stderr)
        return 2
    t = data.imu.t
    mag = np.stack([np.interp(t, data.mag.t, data.mag.field[:, i]) for i in range(3)], axis=1)
    decl = declination_from_params(data.params) or 0.0
    ref_name, _ = select_reference(data.references)
    ref = data.references[ref_name]
    ref_q, mask = quat_slerp_interp(ref.t, ref.q, t)
    mask[0] = False
    rows: dict = {}
    for name in ("madgwick", "mahony", "ekf"):
        c0 = time.perf_counter()
        q = run_ahrs(name, t, data.imu.gyro, data.imu.accel, mag, decl)
        sec = time.perf_counter() - c0
        row = rmse_deg(q, ref_q, mask)
        row["us_per_step"] = 1e6 * sec / max(len(t) - 1, 1)
        rows[f"ahrs.{name}"] = row
    specs = tuple(s.strip() for s in args.filters.split(",") if s.strip())
    doc = replay(args.log, ReplayConfig(filters=specs, smooth=args.smooth,
                                        accel_comp=args.accel_comp))
    doc["filters"].update(rows)
    print(f"{args.log}: IMU {data.imu.source} {data.imu_rate_hz:.1f} Hz, reference {ref_name} "
          f"({ref.kind}); accel compensation: {doc['accel_compensation']}")
    print(format_doc(doc))
    if args.json:
        write_json(args.json, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
