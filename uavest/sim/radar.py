"""Simulated aircraft around the vehicle, the vehicle's radar and ADS-B reports.

World frame: local NED at the scenario origin (m, m/s). Target motion is piecewise
constant velocity / coordinated turn in the horizontal plane (turn rate ``omega`` about
NED down: positive = clockwise seen from above = a right turn) with constant vertical
speed; positions are closed-form at any time (:meth:`Targets.state_at`).

Radar: body-fixed, axes = vehicle body FRD, at the vehicle's position. A target at
line of sight ``d = R^T (p_target - p_vehicle)`` (FRD) is seen at
``range = |d|``, ``azimuth = atan2(d_y, d_x)`` (from the nose, positive to the right),
``elevation = atan2(-d_z, hypot(d_x, d_y))`` (positive up); noise is added to range,
azimuth and elevation (Gaussian, std ``sigma_range``, ``sigma_az_deg``,
``sigma_el_deg``) and the noisy spherical measurement is sent back as Cartesian FRD
``x = r cos(el) cos(az)``, ``y = r cos(el) sin(az)``, ``z = -r sin(el)``. Each target inside
the field of view and ``[r_min, r_max]`` is detected with probability ``pd`` per scan;
clutter: Poisson(``clutter_rate``) false detections per scan, uniform in (range,
azimuth, elevation) over the field of view (the same uniform-in-measurement-space model
as :func:`uavest.tracking.scenario.clutter_box`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InputError

Array = np.ndarray

CLUTTER_ID = 65535  # OBSTACLE_DISTANCE_3D obstacle_id of clutter (MAVLink: "unknown")

EMITTERS = {  # ADSB_EMITTER_TYPE
    "no_info": 0, "light": 1, "small": 2, "large": 3, "high_vortex_large": 4, "heavy": 5,
    "highly_manuv": 6, "rotocraft": 7, "rotorcraft": 7, "glider": 9, "lighter_air": 10,
    "parachute": 11, "ultra_light": 12, "uav": 14, "space": 15,
}


@dataclass
class Target:
    """One aircraft: initial NED state at t = 0 and horizontal turn segments
    ``[[t_start, t_end, deg_per_s], ...]`` (s since boot; end may be ``inf``); with
    ``period`` the whole trajectory restarts every ``period`` s (time taken modulo it)."""

    name: str
    ident: int  # OBSTACLE_DISTANCE_3D obstacle_id
    icao: int
    emitter: int
    adsb: bool
    p0: Array
    v0: Array
    turns: list
    period: float | None = None  # s: the trajectory restarts every period (a new pass)


def _ct(p: Array, v: Array, w: float, tau: Array) -> tuple[Array, Array]:
    """Horizontal coordinated-turn propagation by ``tau`` (s), vectorised over tau."""
    tau = np.asarray(tau, float)
    if abs(w) < 1e-12:
        return p[:2] + np.outer(tau, v[:2]), np.tile(v[:2], (tau.size, 1))
    s, c = np.sin(w * tau), np.cos(w * tau)
    a, b = s / w, (1 - c) / w
    vn, ve = v[0], v[1]
    pos = p[:2] + np.column_stack([a * vn - b * ve, b * vn + a * ve])
    vel = np.column_stack([c * vn - s * ve, s * vn + c * ve])
    return pos, vel


def _position(p: Sequence[float], i: int) -> Array:
    """A target's initial NED position (m); a missing one is a one-line input error."""
    if len(p) != 3:
        raise InputError(f"targets[{i}].position_ned: needs [north, east, down] (m)")
    return np.asarray(p, float)


class Targets:
    """The scenario's ``[[targets]]`` (typed ``SimTarget`` tables of
    :mod:`uavest.scenarios.schema`, which declare the keys' units)."""

    def __init__(self, tables: Sequence[Any]) -> None:
        self.targets: list[Target] = []
        for i, d in enumerate(tables):
            em = d.emitter
            self.targets.append(Target(
                name=str(d.name if d.name is not None else f"TGT{i + 1}")[:8],
                ident=int(d.id if d.id is not None else i + 1),
                icao=int(d.icao if d.icao is not None else 0xA00000 + i + 1) & 0xFFFFFF,
                emitter=EMITTERS[em] if isinstance(em, str) else int(em),
                adsb=bool(d.adsb),
                p0=_position(d.position_ned, i),
                v0=np.asarray(d.velocity_ned, float),
                turns=sorted([float(a), float(b), np.deg2rad(float(w))]
                             for a, b, w in d.turns),
                period=float(d.period_s) if d.period_s else None,
            ))
            if self.targets[-1].ident == CLUTTER_ID:
                raise InputError(f"target id {CLUTTER_ID} is reserved for clutter")

    def __len__(self) -> int:
        return len(self.targets)

    @staticmethod
    def _segments(turns: list) -> list[tuple[float, float, float]]:
        """(t0, t1, omega) pieces covering [0, inf)."""
        segs, t = [], 0.0
        for a, b, w in turns:
            a = max(a, t)
            if b <= a:
                continue
            if a > t:
                segs.append((t, a, 0.0))
            segs.append((a, b, w))
            t = b
        if np.isfinite(t):
            segs.append((t, np.inf, 0.0))
        return segs

    def _one(self, tg: Target, t: Array) -> tuple[Array, Array]:
        t = np.atleast_1d(np.asarray(t, float))
        if tg.period:
            t = np.mod(t, tg.period)
        pos = np.empty((t.size, 3))
        vel = np.empty((t.size, 3))
        pos[:, 2] = tg.p0[2] + tg.v0[2] * t
        vel[:, 2] = tg.v0[2]
        p, v = tg.p0.copy(), tg.v0.copy()
        for j, (t0, t1, w) in enumerate(self._segments(tg.turns)):
            m = t < t1 if j == 0 else (t >= t0) & (t < t1)
            if m.any():
                pos[m, :2], vel[m, :2] = _ct(p, v, w, t[m] - t0)
            if np.isfinite(t1):
                pe, ve = _ct(p, v, w, np.array([t1 - t0]))
                p[:2], v[:2] = pe[0], ve[0]
        return pos, vel

    def state_at(self, t: float | Array) -> tuple[Array, Array]:
        """True positions and velocities (n_targets, 3) NED at time ``t`` (s), or
        (n_targets, len(t), 3) for an array of times."""
        scalar = np.ndim(t) == 0
        out = [self._one(tg, t) for tg in self.targets]
        P = np.array([o[0] for o in out]).reshape(len(out), -1, 3)
        V = np.array([o[1] for o in out]).reshape(len(out), -1, 3)
        return (P[:, 0], V[:, 0]) if scalar else (P, V)


@dataclass
class Detection:
    """One radar detection: FRD Cartesian (m), the noisy spherical measurement
    (range m, azimuth rad, elevation rad), the obstacle_id sent, and its origin
    (target index, -1 for clutter)."""

    xyz: Array
    rae: Array
    obstacle_id: int
    origin: int


class Radar:
    """Body-fixed radar (``[radar]`` table; see module docstring).

    Args:
      cfg: ``enabled``, ``rate_hz``, ``r_min``, ``r_max`` (m), ``fov_az_deg`` (full
        width, 360 = all round), ``fov_el_deg`` (full width), ``pd``, ``clutter_rate``
        (per scan), ``sigma_range`` (m), ``sigma_az_deg``, ``sigma_el_deg``,
        ``report_ids`` (false: every detection gets obstacle_id 65535).
      rng: the ``radar`` stream.
    """

    def __init__(self, cfg: Any, rng: np.random.Generator) -> None:
        self.enabled = bool(cfg.enabled)
        self.rate = float(cfg.rate_hz)
        self.r_min = float(cfg.r_min)
        self.r_max = float(cfg.r_max)
        self.half_az = np.deg2rad(float(cfg.fov_az_deg)) / 2
        self.half_el = np.deg2rad(float(cfg.fov_el_deg)) / 2
        self.pd = float(cfg.pd)
        self.clutter_rate = float(cfg.clutter_rate)
        self.sigma = np.array([
            float(cfg.sigma_range),
            np.deg2rad(float(cfg.sigma_az_deg)),
            np.deg2rad(float(cfg.sigma_el_deg)),
        ])
        self.report_ids = bool(cfg.report_ids)
        self.rng = rng

    @staticmethod
    def to_spherical(d: Array) -> Array:
        """(range, azimuth, elevation) (..., 3) of FRD vectors (..., 3)."""
        r = np.linalg.norm(d, axis=-1)
        az = np.arctan2(d[..., 1], d[..., 0])
        el = np.arctan2(-d[..., 2], np.hypot(d[..., 0], d[..., 1]))
        return np.stack([r, az, el], axis=-1)

    @staticmethod
    def to_cartesian(rae: Array) -> Array:
        """FRD vectors (..., 3) of (range, azimuth, elevation) (..., 3)."""
        r, az, el = rae[..., 0], rae[..., 1], rae[..., 2]
        return np.stack(
            [r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), -r * np.sin(el)],
            axis=-1,
        )

    def in_view(self, rae: Array) -> Array:
        ok = (rae[..., 0] >= self.r_min) & (rae[..., 0] <= self.r_max)
        if self.half_az < np.pi:
            ok &= np.abs(rae[..., 1]) <= self.half_az
        return ok & (np.abs(rae[..., 2]) <= self.half_el)

    def scan(self, R_nb: Array, p_vehicle: Array, p_targets: Array,
             ids: list[int]) -> list[Detection]:
        """Detections of one scan (shuffled): vehicle attitude ``R_nb`` (3, 3) body->NED,
        position (3,) NED, target positions (n, 3) NED and their obstacle ids."""
        rng = self.rng
        n = p_targets.shape[0]
        d = (p_targets - p_vehicle) @ R_nb  # rows R^T (p - p_v)
        rae = self.to_spherical(d)
        hit = self.in_view(rae) & (rng.random(n) < self.pd)
        noise = rng.standard_normal((n, 3)) * self.sigma
        meas = rae + noise
        out = []
        for i in np.flatnonzero(hit):
            m = meas[i].copy()
            m[1] = (m[1] + np.pi) % (2 * np.pi) - np.pi
            oid = ids[i] if self.report_ids else CLUTTER_ID
            out.append(Detection(self.to_cartesian(m), m, oid, int(i)))
        nc = rng.poisson(self.clutter_rate)
        if nc:
            lo = np.array([self.r_min, -min(self.half_az, np.pi), -self.half_el])
            hi = np.array([self.r_max, min(self.half_az, np.pi), self.half_el])
            c = rng.uniform(lo, hi, (nc, 3))
            out.extend(Detection(self.to_cartesian(m), m, CLUTTER_ID, -1) for m in c)
        order = rng.permutation(len(out))
        return [out[i] for i in order]
