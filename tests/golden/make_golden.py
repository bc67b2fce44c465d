"""Regenerate the golden replays of ``tests/integration/test_engine_equivalence.py``.

The golden files are the attitude replay of the batch engine at commit ``05bb455``
(``uavest.pipeline.replay``, the code the streaming engine replaced) on two shared logs:
``replay_<log>.npz`` holds the step times ``t`` (s, log clock, ``t[0]`` the initial state)
and, per filter label, the state rows ``x`` (``(len(t), 7)``: quaternion w,x,y,z body FRD
-> NED, then gyro bias in rad/s), float64, every step. Each filter's random draws come from
``default_rng([0, crc32(label)])``, the old engine's seeding, which the test reproduces.
The reference's input is the old reader's with one named bug of it mended as today's reader
mends it: MAVLink's integer IMU counts (RAW_IMU, SCALED_IMU*) read as the middle of their
unit, not as the truncated value (cbff37f; docs/ingest.md).

Run from the repository root, with the shared logs present and git history containing the
reference commit (it is extracted with ``git archive`` into a temporary folder and run in a
subprocess)::

    python tests/golden/make_golden.py            # writes tests/golden/replay_*.npz

Regenerate only when the reference itself is meant to change (a named bug in the old
replay, a change of the shared logs); a change of today's engine that breaks the test is a
behaviour change to explain, not a reason to regenerate.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
REV = "05bb455"
LOGS = ("vtol.tlog", "sample.ulg")
FILTERS = ("ekf", "ukf", "hybrid")

# Run with PYTHONPATH at the extracted reference tree: the batch replay of that commit.
_SCRIPT = r"""
import sys, numpy as np
from dataclasses import replace
from uavest.ingest import read_log
from uavest.models.attitude import declination_from_params, noise_for_source
from uavest.pipeline.replay import build_steps, run_filters, velocity_acceleration
log, out, filters = sys.argv[1], sys.argv[2], tuple(sys.argv[3].split(","))
data = read_log(log)
from uavest.ingest.convert import MG_TO_MS2, MGAUSS_TO_GAUSS, MRAD_TO_RAD
_MILLI = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
def _middle(v, k):  # the count n = v / k read as n +- 0.5 (0 as 0), as today's reader
    n = np.round(v / k)
    return np.where(n > 0, n + 0.5, np.where(n < 0, n - 0.5, n)) * k
if data.imu.source in _MILLI:
    data.imu.gyro[:] = _middle(data.imu.gyro, MRAD_TO_RAD)
    data.imu.accel[:] = _middle(data.imu.accel, MG_TO_MS2)
if data.mag.source in _MILLI:
    data.mag.field[:] = _middle(data.mag.field, MGAUSS_TO_GAUSS)
noise = noise_for_source(data.imu.source)
decl = declination_from_params(data.params) or 0.0
mag = data.mag
steps = build_steps(data.imu.t, data.imu.gyro, data.imu.accel, mag.t, mag.field, None, "auto")
for name, pos in data.positions.items():
    if len(pos) >= 2 and np.isfinite(pos.vel_ned).all(axis=1).sum() >= 2:
        steps = replace(steps, accel_ned=velocity_acceleration(pos.t, pos.vel_ned, steps.t[1:]))
        break
runs, _ = run_filters(steps, filters, noise, decl, 0, False, True)
np.savez(out, t=steps.t, **{r.label: r.x for r in runs})
"""


def golden_path(log: str) -> Path:
    """The golden file of one shared log (``tests/golden/replay_<log>.npz``)."""
    return HERE / f"replay_{log.replace('.', '_')}.npz"


def _extract(rev: str, dest: Path) -> Path:
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "uavest"],
                         capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(dest, filter="data")
    return dest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rev", default=REV, help="reference commit (default %(default)s)")
    logs = os.environ.get("UAVEST_LOGS") or ROOT.parent / "shared" / "logs"
    ap.add_argument("--logs", type=Path, default=logs,
                    help="folder of the shared logs (default: $UAVEST_LOGS, else "
                    "../shared/logs of the repository)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        old = _extract(args.rev, Path(tmp) / "old")
        for log in LOGS:
            raw = Path(tmp) / f"{log}.npz"
            env = dict(os.environ, PYTHONPATH=str(old), OPENBLAS_NUM_THREADS="1")
            subprocess.run([sys.executable, "-c", _SCRIPT, str(args.logs / log), str(raw),
                            ",".join(FILTERS)], env=env, check=True, cwd=tmp)
            ref = dict(np.load(raw))
            meta = {"rev": args.rev, "log": log, "filters": list(FILTERS),
                    "seeding": "default_rng([0, crc32(label)])"}
            out = golden_path(log)
            np.savez_compressed(out, meta=np.array(json.dumps(meta)), **ref)
            print(f"{out.relative_to(ROOT)}: {len(ref['t'])} steps, "
                  f"{out.stat().st_size / 1e3:.0f} kB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
