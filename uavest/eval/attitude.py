"""Scoring attitude estimates against a reference: Euler-angle RMSE and NEES.

Errors are taken between ZYX Euler angles (roll, pitch, yaw; see
:mod:`uavest.geometry.rotation`) as wrapped differences in degrees (yaw modulo 360, so 359
vs 1 is a 2 degree error). The reference is interpolated (slerp) at the estimate's times;
estimate times outside the reference's span are not scored.

NEES is computed on the attitude part only (3 degrees of freedom, the reference has no
gyro bias): ``e = Log(q_est^-1 q_ref)`` (body-frame error, the filter's tangent
convention) and ``nees = e^T P[:3, :3]^-1 e``; a consistent filter averages 3.
"""

from __future__ import annotations

import numpy as np

from ..geometry.rotation import (
    quat_conj,
    quat_log,
    quat_mul,
    quat_to_euler,
    wrap_pi,
)

Array = np.ndarray

__all__ = [
    "AUTOPILOT_SOURCES",
    "euler_errors_deg",
    "nees_attitude",
    "rmse_deg",
    "select_reference",
]

#: Preference order among autopilot estimates (first present wins).
AUTOPILOT_SOURCES = ("ATTITUDE_QUATERNION", "ATTITUDE", "ATT", "vehicle_attitude")
TRUTH_SOURCES = ("SIMSTATE", "SIM")


def select_reference(refs: dict) -> tuple[str | None, str | None]:
    """(reference source, autopilot source) from ``LogData.references``.

    The reference is truth when the log has it (``kind == "truth"``), else the
    autopilot's estimate, else AHRS2; the autopilot source is the preferred autopilot
    estimate (None if absent). Either may be None.
    """
    truth = [k for k in TRUTH_SOURCES if k in refs and refs[k].kind == "truth"]
    truth += [k for k, v in refs.items() if v.kind == "truth" and k not in truth]
    auto = [k for k in AUTOPILOT_SOURCES if k in refs]
    auto += [k for k, v in refs.items() if v.kind == "autopilot" and k not in auto]
    other = [k for k, v in refs.items() if v.kind == "ahrs2"]
    ap = auto[0] if auto else None
    for cand in (truth, auto, other):
        usable = [k for k in cand if len(refs[k]) > 0]
        if usable:
            return usable[0], ap
    return None, ap



def euler_errors_deg(q_est: Array, q_ref: Array) -> Array:
    """(N, 3) wrapped (estimate - reference) roll, pitch, yaw errors in degrees."""
    d = wrap_pi(quat_to_euler(q_est) - quat_to_euler(q_ref))
    return np.rad2deg(d)


def rmse_deg(q_est: Array, q_ref: Array, mask: Array | None = None) -> dict[str, float]:
    """Roll, pitch, yaw RMSE (degrees) of ``q_est`` against ``q_ref`` over ``mask``."""
    e = euler_errors_deg(q_est, q_ref)
    if mask is not None:
        e = e[mask]
    if e.shape[0] == 0:
        nan = float("nan")
        return {"roll_rmse_deg": nan, "pitch_rmse_deg": nan, "yaw_rmse_deg": nan, "n": 0}
    r = np.sqrt(np.mean(e * e, axis=0))
    return {
        "roll_rmse_deg": float(r[0]),
        "pitch_rmse_deg": float(r[1]),
        "yaw_rmse_deg": float(r[2]),
        "n": int(e.shape[0]),
    }


def nees_attitude(q_est: Array, P: Array, q_true: Array) -> Array:
    """Per-step attitude NEES (3 dof): ``e^T P[:3,:3]^-1 e``, e = Log(q_est^-1 q_true)."""
    e = quat_log(quat_mul(quat_conj(q_est), q_true))
    Pa = P[:, :3, :3]
    sol = np.linalg.solve(Pa, e[..., None])[..., 0]
    return np.einsum("ij,ij->i", e, sol)
