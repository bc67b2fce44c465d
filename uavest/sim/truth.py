"""The simulator's truth: the vehicle and target states it reports, kept for
:meth:`.mavlink.Simulator.truth_at`, and the truth CSV it writes as it runs.

NED m and m/s from the scenario origin, body FRD, radians, seconds since boot; geodetic
positions in deg, deg, m.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import IO

import numpy as np

from ..geometry.geodesy import LocalFrame
from ..geometry.rotation import euler_to_quat
from .radar import Detection, Targets
from .sensors import ImuChunk
from .vehicle import TruthChunk, VehicleModel, body_rates

Array = np.ndarray

__all__ = ["Chunk", "TRUTH_COLUMNS", "Truth", "TruthCsv", "TruthHistory", "VehicleTruth"]

#: Columns of the truth CSV (``run(truth=...)`` / ``--truth``). ``kind`` is ``vehicle``
#: (id 0), ``target`` (id = obstacle id, origin = target index) or ``det`` (a radar
#: detection: id = obstacle_id sent, origin = target index or -1 for clutter, n/e/d =
#: the FRD x/y/z sent, a/b/c = range m, azimuth rad, elevation rad). Vehicle rows: a/b/c =
#: roll, pitch, yaw rad. NED m and m/s from the origin; lat/lon deg, alt m.
TRUTH_COLUMNS = ("t", "kind", "id", "origin", "n", "e", "d", "vn", "ve", "vd", "a", "b", "c",
                 "lat", "lon", "alt")


@dataclass
class VehicleTruth:
    """Vehicle truth at one time: NED position/velocity (m, m/s) from the origin,
    attitude ``q`` (body FRD -> NED, scalar-first), ``euler`` (roll, pitch, yaw rad),
    body rates ``omega`` (rad/s, FRD), specific force ``f_body`` (m/s^2, FRD), the IMU
    biases (FRD) and the geodetic position ``lla`` (deg, deg, m)."""

    t: float
    q: Array
    euler: Array
    omega: Array
    f_body: Array
    pos_ned: Array
    vel_ned: Array
    gyro_bias: Array
    accel_bias: Array
    lla: Array


@dataclass
class Truth:
    """Truth of the whole scene at time ``t`` (s since boot): the vehicle and the targets
    (``target_pos`` / ``target_vel`` (n, 3) NED m, m/s; ``target_lla`` (n, 3) deg, deg, m;
    ``target_ids`` the obstacle ids, ``target_icao`` the ICAO addresses)."""

    t: float
    vehicle: VehicleTruth
    target_pos: Array
    target_vel: Array
    target_lla: Array
    target_ids: list[int]
    target_icao: list[int]


@dataclass
class Chunk:
    """One chunk of consecutive IMU steps from step ``k0``: times (us since boot), the
    vehicle truth, the IMU outputs, the autopilot's estimate errors (attitude rad,
    position m, velocity m/s, barometer m) and the true geodetic position."""

    k0: int
    t_us: Array
    truth: TruthChunk
    imu: ImuChunk
    att_err: Array
    nav_err: Array
    vel_err: Array
    baro_err: Array
    lla: Array = field(default=None)  # (N, 3) deg, deg, m


class TruthHistory:
    """The chunks of the last ``history_s`` s of simulated steps (None: all), and the
    truth at any time within them (:meth:`truth_at`, safe from another thread)."""

    def __init__(self, vehicle: VehicleModel, targets: Targets, frame: LocalFrame,
                 history_s: float | None) -> None:
        self.vehicle = vehicle
        self.targets = targets
        self.frame = frame
        self.history_s = history_s
        self.hist: tuple[list[Chunk], list[int]] = ([], [])

    @property
    def chunks(self) -> list[Chunk]:
        """The chunks kept, oldest first."""
        return self.hist[0]

    def push(self, ch: Chunk) -> None:
        """Keep a new chunk (and drop those older than ``history_s``)."""
        t_us = ch.t_us
        chunks = self.hist[0] + [ch]
        if self.history_s is not None:
            keep = self.history_s * 1e6
            while len(chunks) > 2 and chunks[1].t_us[0] < t_us[-1] - keep:
                chunks.pop(0)
        # new lists (not in-place edits) so that truth_at in another thread sees a
        # consistent pair
        self.hist = (chunks, [int(c.t_us[0]) for c in chunks])

    def truth_at(self, t: float, now_us: float) -> Truth:
        """Truth of the vehicle and the targets at ``t`` (s since boot). The vehicle part
        needs ``t`` within the simulated history (kept ``history_s``); position and
        velocity are linearly interpolated between IMU steps, attitude and rates are
        evaluated exactly, biases taken at the step before ``t``; ``now_us``: the time
        of the current step (the newest one that counts)."""
        t_us = t * 1e6
        chunks, starts = self.hist  # one tuple, replaced (never mutated) by push
        n = bisect.bisect_right(starts, t_us + 1e-6) - 1
        # the newest step may still be unsent: only times up to the current step count
        if n < 0 or t_us > min(chunks[-1].t_us[-1], now_us) + 1e-6:
            raise ValueError(f"t = {t} s is outside the simulated history")
        ch = chunks[n]
        i = int(np.searchsorted(ch.t_us, t_us, side="right") - 1)
        if i + 1 < ch.t_us.size:
            c2, j = ch, i + 1
        elif n + 1 < len(chunks):
            c2, j = chunks[n + 1], 0
        else:
            c2, j = ch, i
        span = c2.t_us[j] - ch.t_us[i]
        s = 0.0 if span == 0 else (t_us - ch.t_us[i]) / span
        tr, tr2 = ch.truth, c2.truth
        pos = (1 - s) * tr.pos[i] + s * tr2.pos[j]
        vel = (1 - s) * tr.vel[i] + s * tr2.vel[j]
        f_b = (1 - s) * tr.f_body[i] + s * tr2.f_body[j]
        val, rate = self.vehicle.man.eval(np.array([t]))
        e = val[0, :3].copy()
        q = euler_to_quat(e[0], e[1], e[2])
        om = body_rates(val[:, :3], rate[:, :3])[0]
        e[2] = (e[2] + np.pi) % (2 * np.pi) - np.pi
        lat, lon, h = self.frame.ned_to_geodetic(pos)
        vt = VehicleTruth(t, q, e, om, f_b, pos, vel, ch.imu.gyro_bias[i].copy(),
                          ch.imu.accel_bias[i].copy(), np.array([lat, lon, h], float))
        P, V = self.targets.state_at(t) if len(self.targets) else (np.zeros((0, 3)),) * 2
        la, lo, hh = self.frame.ned_to_geodetic(P)
        return Truth(t, vt, P, V, np.column_stack([la, lo, hh]),
                     [tg.ident for tg in self.targets.targets],
                     [tg.icao for tg in self.targets.targets])


class TruthCsv:
    """The truth CSV of a run (:data:`TRUTH_COLUMNS`): vehicle and target rows every
    ``1 / rate`` s of simulated time, one row per radar detection."""

    def __init__(self, f: IO[str], targets: Targets, frame: LocalFrame) -> None:
        self.f = f
        self.targets = targets
        self.frame = frame
        f.write(",".join(TRUTH_COLUMNS) + "\n")

    def write_state(self, ch: Chunk, i: int) -> None:
        """Vehicle and target rows at step ``i`` of ``ch`` (flushed)."""
        t = ch.t_us[i] * 1e-6
        tr = ch.truth
        p, v, e = tr.pos[i], tr.vel[i], tr.euler[i]
        la, lo, h = ch.lla[i]
        rows = [f"{t:.6f},vehicle,0,,{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},{v[0]:.4f},{v[1]:.4f},"
                f"{v[2]:.4f},{e[0]:.6f},{e[1]:.6f},{e[2]:.6f},{la:.8f},{lo:.8f},{h:.3f}"]
        if len(self.targets):
            P, V = self.targets.state_at(t)
            LA, LO, H = self.frame.ned_to_geodetic(P)
            for j, tg in enumerate(self.targets.targets):
                p, v = P[j], V[j]
                rows.append(f"{t:.6f},target,{tg.ident},{j},{p[0]:.3f},{p[1]:.3f},{p[2]:.3f},"
                            f"{v[0]:.3f},{v[1]:.3f},{v[2]:.3f},,,,{LA[j]:.8f},{LO[j]:.8f},"
                            f"{H[j]:.3f}")
        self.f.write("\n".join(rows) + "\n")
        self.f.flush()

    def write_detections(self, t: float, dets: list[Detection]) -> None:
        """One row per detection of the scan at ``t`` (s)."""
        rows = []
        for d in dets:
            r, az, el = d.rae
            rows.append(f"{t:.6f},det,{d.obstacle_id},{d.origin},{d.xyz[0]:.3f},"
                        f"{d.xyz[1]:.3f},{d.xyz[2]:.3f},,,,{r:.3f},{az:.6f},{el:.6f},,,")
        if rows:
            self.f.write("\n".join(rows) + "\n")

    def close(self) -> None:
        self.f.close()
