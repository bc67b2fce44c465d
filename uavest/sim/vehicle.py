"""Truth motion of the simulated multirotor.

Frames and units: world = local NED at the scenario origin (m, m/s), body = FRD,
attitude quaternion ``q`` scalar-first rotating body FRD into NED
(:mod:`uavest.geometry.rotation`), angles in radians, times in seconds since boot.

Motion model
------------
Attitude is prescribed: roll, pitch and yaw are sums of smooth manoeuvre segments
(:class:`Manoeuvres`) plus a small "turbulence" jitter (a few random sinusoids), all
with analytic time derivatives, so the body rates are exact:
``p = droll - dyaw sin(pitch)``, ``q = dpitch cos(roll) + dyaw sin(roll) cos(pitch)``,
``r = -dpitch sin(roll) + dyaw cos(roll) cos(pitch)`` (ZYX Euler kinematics).

Translation follows from the attitude like a multirotor's: the thrust ``T`` (per unit
mass, along body -z) is set so that the vertical speed follows the scenario's climb
command exactly (``T = (g + dclimb/dt) / (cos roll cos pitch)``), so tilting produces
horizontal acceleration ``a_h = -T R[0:2, 2] - k_drag v_h`` with linear drag. The
horizontal velocity is integrated with the trapezoidal rule (an IIR recursion run by
``scipy.signal.lfilter``), the position with the trapezoidal rule of the velocity.
Specific force (what an ideal accelerometer reads) ``f_b = R^T (a - [0, 0, g])``:
level and still gives ``(0, 0, -g)``.

Sensors: :mod:`.sensors`.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import lfilter

from ..errors import InputError
from ..geometry.rotation import G0, euler_to_quat, quat_to_dcm

Array = np.ndarray

CHANNELS = ("roll", "pitch", "yaw", "climb")


def stream_rng(seed: int, name: str) -> np.random.Generator:
    """Independent generator per named stream: ``default_rng([seed, crc32(name)])``."""
    return np.random.default_rng([int(seed), zlib.crc32(name.encode())])


# ----------------------------------------------------------------------------- manoeuvres


def _smooth(s: Array) -> tuple[Array, Array]:
    """Raised-cosine step on s in [0, 1]: value and d/ds (0 outside, 1 above)."""
    s = np.clip(s, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * s), 0.5 * np.pi * np.sin(np.pi * s)


def _window(t: Array, start: float, dur: float, ramp: float) -> tuple[Array, Array]:
    """1 on [start + ramp, start + dur - ramp], raised-cosine edges of ``ramp`` s, 0 outside."""
    if ramp <= 0:
        inside = (t >= start) & (t < start + dur)
        return inside.astype(float), np.zeros_like(t)
    up, dup = _smooth((t - start) / ramp)
    dn, ddn = _smooth((start + dur - t) / ramp)
    return up * dn, (dup * dn - up * ddn) / ramp


@dataclass
class Segment:
    """One manoeuvre segment of a channel (see ``docs/sim.md`` / the scenario TOML).

    kind: ``hold`` (value held between smooth ramps), ``sine`` (amplitude * sin(2 pi f
    (t - start)) under the same window) or ``ramp`` (channel changes by ``value`` over
    ``duration`` and keeps it; repeats accumulate, e.g. yaw turns). Values in channel
    units (rad for angles, m/s for climb)."""

    channel: str
    kind: str
    start: float
    duration: float
    value: float = 0.0
    freq: float = 0.0
    ramp: float = 0.0

    def eval(self, t: Array) -> tuple[Array, Array]:
        if self.kind == "ramp":
            s, ds = _smooth((t - self.start) / self.duration)
            return self.value * s, self.value * ds / self.duration
        w, dw = _window(t, self.start, self.duration, self.ramp)
        if self.kind == "hold":
            return self.value * w, self.value * dw
        if self.kind == "sine":
            ph = 2 * np.pi * self.freq * (t - self.start)
            s, c = np.sin(ph), np.cos(ph)
            return self.value * s * w, self.value * (2 * np.pi * self.freq * c * w + s * dw)
        raise InputError(f"manoeuvre kind {self.kind!r}: expected hold, sine or ramp")


class Manoeuvres:
    """Roll, pitch, yaw (rad) and climb rate (m/s, up) as smooth functions of time.

    Args:
      segments: list of TOML tables (``channel``, ``kind``, ``start`` s, ``duration`` s,
        ``value`` deg or m/s, ``freq_hz``, ``ramp`` s).
      period: the schedule repeats every ``period`` s (None: once). Ramps accumulate
        across repeats; holds and sines must lie within [0, period).
      yaw0: initial heading (rad). jitter: random sinusoid amplitude (rad, per axis).
      rng: generator for the jitter's frequencies and phases.
    """

    def __init__(
        self,
        segments: Sequence[Any],
        period: float | None = None,
        yaw0: float = 0.0,
        jitter: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.period = float(period) if period else None
        self.yaw0 = float(yaw0)
        self.segments: list[Segment] = []
        for d in segments:
            ch = d.channel
            if ch not in CHANNELS:
                raise InputError(f"manoeuvre channel {ch!r}: expected one of {CHANNELS}")
            k = 1.0 if ch == "climb" else np.pi / 180.0
            seg = Segment(
                ch, d.kind, float(d.start), float(d.duration),
                float(d.amplitude if d.amplitude is not None and not d.value else d.value) * k,
                float(d.freq_hz), float(d.ramp),
            )
            if seg.duration <= 0:
                raise InputError("manoeuvre duration must be > 0")
            if self.period and seg.start + seg.duration > self.period + 1e-9:
                raise InputError(f"manoeuvre at {seg.start} s runs past period {self.period} s")
            self.segments.append(seg)
        rng = rng or np.random.default_rng(0)
        # 3 sinusoids per attitude axis, 0.2-1.5 Hz, equal amplitude (sum std ~ jitter)
        self._jf = rng.uniform(0.2, 1.5, (3, 3))
        self._jp = rng.uniform(0, 2 * np.pi, (3, 3))
        self._ja = float(jitter) * np.sqrt(2.0 / 3.0)

    def eval(self, t: Array) -> tuple[Array, Array]:
        """Channel values (N, 4) = [roll, pitch, yaw, climb] and their rates (N, 4)."""
        t = np.asarray(t, float)
        val = np.zeros(t.shape + (4,))
        rate = np.zeros_like(val)
        val[..., 2] = self.yaw0
        if self.period:
            n_rep = np.floor(t / self.period)
            tau = t - n_rep * self.period
        else:
            n_rep, tau = np.zeros_like(t), t
        for seg in self.segments:
            i = CHANNELS.index(seg.channel)
            v, dv = seg.eval(tau)
            if seg.kind == "ramp":
                v = v + n_rep * seg.value
            val[..., i] += v
            rate[..., i] += dv
        if self._ja > 0:
            ph = 2 * np.pi * self._jf * t[..., None, None] + self._jp  # (..., axis, k)
            val[..., :3] += self._ja * np.sin(ph).sum(-1)
            rate[..., :3] += self._ja * (2 * np.pi * self._jf * np.cos(ph)).sum(-1)
        return val, rate


def body_rates(euler: Array, euler_rate: Array) -> Array:
    """Body FRD angular rates (N, 3) rad/s from ZYX Euler angles and their rates."""
    r, p = euler[..., 0], euler[..., 1]
    dr, dp, dy = euler_rate[..., 0], euler_rate[..., 1], euler_rate[..., 2]
    return np.stack(
        [
            dr - dy * np.sin(p),
            dp * np.cos(r) + dy * np.sin(r) * np.cos(p),
            -dp * np.sin(r) + dy * np.cos(r) * np.cos(p),
        ],
        axis=-1,
    )


# ---------------------------------------------------------------------------- truth


@dataclass
class TruthChunk:
    """Vehicle truth at consecutive IMU steps (N rows). NED / FRD, SI units."""

    t: Array  # (N,) s since boot
    q: Array  # (N, 4) body FRD -> NED
    euler: Array  # (N, 3) roll, pitch, yaw rad (yaw wrapped to [-pi, pi))
    omega: Array  # (N, 3) body rates rad/s
    pos: Array  # (N, 3) NED m
    vel: Array  # (N, 3) NED m/s
    acc: Array  # (N, 3) NED kinematic acceleration m/s^2
    f_body: Array  # (N, 3) specific force, body FRD, m/s^2
    R: Array  # (N, 3, 3) body -> NED


class VehicleModel:
    """Multirotor truth, generated chunk by chunk (see module docstring).

    Args:
      cfg: the scenario's ``[vehicle]`` table.
      rng: the ``motion`` stream (jitter phases).
    """

    def __init__(self, cfg: Any, rng: np.random.Generator) -> None:
        self.man = Manoeuvres(
            cfg.manoeuvres,
            cfg.period_s,
            np.deg2rad(float(cfg.yaw_deg)),
            np.deg2rad(float(cfg.jitter_deg)),
            rng,
        )
        self.k_drag = float(cfg.drag_per_s)
        self.pos = np.asarray(cfg.position_ned, float).copy()
        self._vh = np.asarray(cfg.velocity_ne, float).copy()
        self._uh: Array | None = None  # horizontal thrust accel at the previous step
        self._vz: float | None = None

    def chunk(self, t: Array) -> TruthChunk:
        """Truth at the equally spaced times ``t`` (s), continuing the previous chunk."""
        dt = float(t[1] - t[0]) if t.size > 1 else 0.0
        val, rate = self.man.eval(t)
        euler = val[:, :3]
        q = euler_to_quat(euler[:, 0], euler[:, 1], euler[:, 2])
        R = quat_to_dcm(q)
        omega = body_rates(euler, rate[:, :3])
        vz = -val[:, 3]
        az = -rate[:, 3]
        thrust = (G0 - az) / R[:, 2, 2]
        u = -thrust[:, None] * R[:, 0:2, 2]
        if self._uh is None:  # first sample: the initial state
            self._uh, self._vz = u[0], vz[0]
            vh = np.empty_like(u)
            vh[0] = self._vh
            first = 1
        else:
            first = 0
            vh = np.empty_like(u)
        h = 0.5 * self.k_drag * dt
        c1, c2 = (1 - h) / (1 + h), 0.5 * dt / (1 + h)
        if t.size > first:
            x = u[first:]
            zi = c1 * self._vh + c2 * self._uh
            y, _ = lfilter([c2, c2], [1.0, -c1], x, axis=0, zi=zi[None, :])
            vh[first:] = y
        vel = np.column_stack([vh, vz])
        prev_v = np.concatenate([[np.r_[self._vh, self._vz]], vel[:-1]])
        steps = 0.5 * dt * (prev_v + vel)
        if first:
            steps[0] = 0.0
        pos = self.pos + np.cumsum(steps, axis=0)
        acc = np.column_stack([u - self.k_drag * vh, az])
        g = np.array([0.0, 0.0, G0])
        f_body = np.einsum("nji,nj->ni", R, acc - g)
        self.pos, self._vh, self._uh, self._vz = pos[-1].copy(), vh[-1].copy(), u[-1], vz[-1]
        e = euler.copy()
        e[:, 2] = (e[:, 2] + np.pi) % (2 * np.pi) - np.pi
        return TruthChunk(t, q, e, omega, pos, vel, acc, f_body, R)
