"""What a slow IMU stream loses between two samples: each interval of the log's IMU
started at the simulator's truth (interpolated on the rotation group), propagated with the
interval's two gyro samples (trapezoid, body FRD) and compared with the truth at its end.
The RMS of that one-interval error (deg, body x / y / z) is attitude a filter has to
recover from its other sensors at every step. On ``vtol.tlog`` (RAW_IMU at 3.8 Hz) it is
several degrees, against the navigation filter's 0.26 deg roll target, which the
autopilot's own filter meets on its 400 Hz IMU.

The samples come from the project's reader (vehicle clock); the truth is the log's
``truth`` attitude reference (SIMSTATE / SIM_STATE), itself at 4.3 Hz in vtol.tlog, so
the interpolated truth adds its own error: an indicator, not a bound. Airborne:
GLOBAL_POSITION_INT's height more than 2 m above its lowest (as the replay's span).

    python benchmarks/interval_loss.py [--log PATH] [--imu SOURCE]  # ../shared/logs/vtol.tlog
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from _shared_logs import SHARED_LOGS
from scipy.spatial.transform import Rotation, Slerp

from uavest.errors import InputError
from uavest.ingest.api import open_source
from uavest.ingest.types import AttitudeRef, ImuSample, PositionSample

AIRBORNE_M = 2.0  # m above the lowest reference height


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", default=str(SHARED_LOGS / "vtol.tlog"))
    ap.add_argument("--imu", default="RAW_IMU", help="IMU source (default RAW_IMU)")
    a = ap.parse_args()
    imu, truth, height = [], [], []
    try:
        for s in open_source(a.log, imu=a.imu):
            if isinstance(s, ImuSample):
                imu.append((s.t, *s.gyro))
            elif isinstance(s, AttitudeRef) and s.kind == "truth":
                truth.append((s.t, *s.q))
            elif isinstance(s, PositionSample) and s.source == "GLOBAL_POSITION_INT":
                up = s.lat_lon_alt[2] if s.lat_lon_alt is not None else (
                    -s.ned[2] if s.ned is not None else np.nan)
                if np.isfinite(up):
                    height.append((s.t, up))
    except (InputError, OSError) as e:
        print(f"interval_loss: {e}", file=sys.stderr)
        return 2
    if len(imu) < 2 or len(truth) < 2 or not height:
        print(f"interval_loss: {a.log} needs {a.imu}, a truth attitude and "
              "GLOBAL_POSITION_INT", file=sys.stderr)
        return 2
    g, q, h = np.array(imu), np.array(truth), np.array(height)
    q = q[np.unique(q[:, 0], return_index=True)[1]]
    slerp = Slerp(q[:, 0], Rotation.from_quat(q[:, [2, 3, 4, 1]]))  # scipy: [x, y, z, w]
    t0, t1 = g[:-1, 0], g[1:, 0]
    dt = t1 - t0
    keep = (t0 > q[0, 0]) & (t1 < q[-1, 0]) & (dt > 0) & (dt < 1.0)
    up = np.interp(t0, h[:, 0], h[:, 1]) > h[:, 1].min() + AIRBORNE_M
    w = 0.5 * (g[:-1, 1:] + g[1:, 1:])
    pred = slerp(t0[keep]) * Rotation.from_rotvec(w[keep] * dt[keep, None])
    err = np.degrees((slerp(t1[keep]).inv() * pred).as_rotvec())
    print(f"{a.log}: {a.imu} at {(len(g) - 1) / (g[-1, 0] - g[0, 0]):.1f} Hz, truth at "
          f"{(len(q) - 1) / (q[-1, 0] - q[0, 0]):.1f} Hz")
    print("one interval started at the truth: attitude error, deg RMS body x / y / z; length")
    for name, sel in (("whole log", np.ones(int(keep.sum()), bool)), ("airborne", up[keep])):
        e = err[sel]
        rms = np.sqrt((e ** 2).mean(axis=0))
        print(f"  {name:9s} {int(sel.sum()):5d} intervals, median "
              f"{np.median(dt[keep][sel]):.3f} s: {rms[0]:.3f} / {rms[1]:.3f} / "
              f"{rms[2]:.3f}; {np.sqrt((e ** 2).sum(axis=1).mean()):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
