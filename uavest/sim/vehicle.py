"""Truth motion of the simulated multirotor and its onboard sensors.

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

Sensors (:class:`ImuModel`): gyro = body rate + bias + white noise + vibration; accel =
specific force + bias + white noise + vibration; biases do a random walk. Noise is given
as continuous densities and discretised at the IMU rate the usual way
(``sigma_d = N sqrt(rate)`` for white noise, ``sigma_d = K / sqrt(rate)`` per step for
the bias random walk); see O. J. Woodman, "An introduction to inertial navigation"
(Cambridge UCAM-CL-TR-696, 2007) and IEEE Std 952-1997 (Allan variance terms N, K).
Vibration: motor-frequency sinusoids (fundamental + 2nd harmonic) that alias at the
IMU sample rate as on a real airframe.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

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
        segments: list[dict],
        period: float | None = None,
        yaw0: float = 0.0,
        jitter: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.period = float(period) if period else None
        self.yaw0 = float(yaw0)
        self.segments: list[Segment] = []
        for d in segments:
            ch = d.get("channel")
            if ch not in CHANNELS:
                raise InputError(f"manoeuvre channel {ch!r}: expected one of {CHANNELS}")
            k = 1.0 if ch == "climb" else np.pi / 180.0
            seg = Segment(
                ch, d.get("kind", "hold"), float(d["start"]), float(d["duration"]),
                float(d.get("value", d.get("amplitude", 0.0))) * k,
                float(d.get("freq_hz", 0.0)), float(d.get("ramp", 0.0)),
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

    def __init__(self, cfg: dict, rng: np.random.Generator) -> None:
        self.man = Manoeuvres(
            cfg.get("manoeuvres", []),
            cfg.get("period_s"),
            np.deg2rad(float(cfg.get("yaw_deg", 0.0))),
            np.deg2rad(float(cfg.get("jitter_deg", 0.0))),
            rng,
        )
        self.k_drag = float(cfg.get("drag_per_s", 0.3))
        self.pos = np.asarray(cfg.get("position_ned", [0.0, 0.0, 0.0]), float).copy()
        self._vh = np.asarray(cfg.get("velocity_ne", [0.0, 0.0]), float).copy()
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


# ---------------------------------------------------------------------------- sensors


@dataclass
class ImuChunk:
    """Sensor outputs at the IMU steps of a :class:`TruthChunk` (body FRD, SI)."""

    gyro: Array  # (N, 3) rad/s
    accel: Array  # (N, 3) m/s^2 specific force
    gyro_bias: Array  # (N, 3) rad/s, the true bias in ``gyro``
    accel_bias: Array  # (N, 3) m/s^2
    mag: Array  # (N, 3) gauss, held between magnetometer updates
    mag_new: Array  # (N,) bool, a new magnetometer sample at this step


def _vec3(v, default) -> Array:
    a = np.asarray(default if v is None else v, float)
    return np.broadcast_to(a, (3,)).astype(float)


def earth_field_ned(decl: float, incl: float, intensity: float) -> Array:
    """Earth magnetic field in NED (gauss) from declination, inclination (rad, positive
    east / down) and total intensity (gauss)."""
    return intensity * np.array(
        [np.cos(incl) * np.cos(decl), np.cos(incl) * np.sin(decl), np.sin(incl)]
    )


class ImuModel:
    """Gyro, accelerometer and magnetometer (see module docstring).

    Args:
      cfg: the scenario's ``[imu]`` table (noise densities etc.).
      mag_cfg: the ``[mag]`` table (declination_deg, inclination_deg, intensity_gauss,
        noise_gauss, rate_hz, offsets_gauss).
      rate: IMU sample rate (Hz).
      seed: master seed (streams ``imu.gyro``, ``imu.accel``, ``imu.bias``, ``imu.vib``,
        ``mag``).
    """

    def __init__(self, cfg: dict, mag_cfg: dict, rate: float, seed: int) -> None:
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        r_bias = stream_rng(seed, "imu.bias")
        self.rg, self.ra = stream_rng(seed, "imu.gyro"), stream_rng(seed, "imu.accel")
        self.rbw = stream_rng(seed, "imu.bias_walk")
        self.rmag = stream_rng(seed, "mag")
        self.gyro_nd = float(cfg.get("gyro_noise_density", 1.5e-4))
        self.accel_nd = float(cfg.get("accel_noise_density", 2.0e-3))
        self.gyro_rw = float(cfg.get("gyro_bias_walk", 2.0e-5))
        self.accel_rw = float(cfg.get("accel_bias_walk", 1.0e-4))
        bg, ba = cfg.get("gyro_bias"), cfg.get("accel_bias")
        self.bg = (_vec3(bg, 0.0) if bg is not None else
                   r_bias.normal(0, float(cfg.get("gyro_bias_std", 0.01)), 3))
        self.ba = (_vec3(ba, 0.0) if ba is not None else
                   r_bias.normal(0, float(cfg.get("accel_bias_std", 0.05)), 3))
        rv = stream_rng(seed, "imu.vib")
        self.vib_f = float(cfg.get("vibration_hz", 137.0))
        self.vib_a = _vec3(cfg.get("vibration_accel"), [0.6, 0.6, 1.5])
        self.vib_g = _vec3(cfg.get("vibration_gyro"), [0.01, 0.01, 0.005])
        self.vib_ph = rv.uniform(0, 2 * np.pi, (4, 3))
        decl = np.deg2rad(float(mag_cfg.get("declination_deg", 0.0)))
        incl = np.deg2rad(float(mag_cfg.get("inclination_deg", 60.0)))
        self.declination = decl
        self.b_ned = earth_field_ned(decl, incl, float(mag_cfg.get("intensity_gauss", 0.5)))
        self.mag_off = _vec3(mag_cfg.get("offsets_gauss"), 0.0)
        self.mag_noise = float(mag_cfg.get("noise_gauss", 0.003))
        self.mag_rate = float(mag_cfg.get("rate_hz", 50.0))
        self._mag_last = None
        self._mag_k = -1

    def chunk(self, tr: TruthChunk) -> ImuChunk:
        n = tr.t.size
        sq = np.sqrt(self.dt)
        wg = self.rg.standard_normal((n, 3)) * (self.gyro_nd / sq)
        wa = self.ra.standard_normal((n, 3)) * (self.accel_nd / sq)
        walk = self.rbw.standard_normal((n, 6)) * sq
        bg = self.bg + np.cumsum(walk[:, :3] * self.gyro_rw, axis=0)
        ba = self.ba + np.cumsum(walk[:, 3:] * self.accel_rw, axis=0)
        self.bg, self.ba = bg[-1].copy(), ba[-1].copy()
        ph = 2 * np.pi * self.vib_f * tr.t[:, None]
        vib1 = np.sin(ph + self.vib_ph[0]) + 0.4 * np.sin(2 * ph + self.vib_ph[1])
        vib2 = np.sin(ph + self.vib_ph[2]) + 0.4 * np.sin(2 * ph + self.vib_ph[3])
        gyro = tr.omega + bg + wg + self.vib_g * vib1
        accel = tr.f_body + ba + wa + self.vib_a * vib2
        # magnetometer: new sample when floor(t * rate) advances, held in between
        b_body = np.einsum("nji,j->ni", tr.R, self.b_ned) + self.mag_off
        noise = self.rmag.standard_normal((n, 3)) * self.mag_noise
        k = np.floor(tr.t * self.mag_rate + 1e-9).astype(np.int64)
        new = np.r_[k[0] != self._mag_k, k[1:] != k[:-1]]
        fresh = b_body + noise
        idx = np.maximum.accumulate(np.where(new, np.arange(n), -1))
        mag = np.where((idx >= 0)[:, None], fresh[np.maximum(idx, 0)],
                       self._mag_last if self._mag_last is not None else fresh[0])
        self._mag_last, self._mag_k = mag[-1].copy(), k[-1]
        return ImuChunk(gyro, accel, bg, ba, mag, new)


class GaussMarkov:
    """First-order Gauss-Markov process per component: stationary std ``sigma``, time
    constant ``tau`` (s), sampled every ``dt`` s (exact discretisation)."""

    def __init__(self, sigma, tau: float, dt: float, rng: np.random.Generator) -> None:
        self.sigma = np.atleast_1d(np.asarray(sigma, float))
        self.phi = float(np.exp(-dt / tau))
        self.rng = rng
        self.x = self.sigma * rng.standard_normal(self.sigma.size)

    def run(self, n: int) -> Array:
        """The next ``n`` samples (n, k)."""
        w = self.rng.standard_normal((n, self.sigma.size)) * self.sigma * np.sqrt(1 - self.phi**2)
        y, _ = lfilter([1.0], [1.0, -self.phi], w, axis=0, zi=(self.phi * self.x)[None, :])
        self.x = y[-1].copy()
        return y

    def step(self) -> Array:
        return self.run(1)[0]
