"""The simulated vehicle's sensors: IMU and magnetometer, GPS, the autopilot's estimate
errors and the ADS-B reports of the targets.

Frames and units as :mod:`.vehicle`: NED (m, m/s), body FRD, radians, seconds since boot.

Sensors (:class:`ImuModel`): gyro = body rate + bias + white noise + vibration; accel =
specific force + bias + white noise + vibration; biases do a random walk (the gyro's
plus a steady ramp, ``gyro_drift``: an ArduPilot SITL's ``SIM_DRIFT_SPEED`` without its
turn back after ``SIM_DRIFT_TIME``). Noise is given
as continuous densities and discretised at the IMU rate the usual way
(``sigma_d = N sqrt(rate)`` for white noise, ``sigma_d = K / sqrt(rate)`` per step for
the bias random walk); see O. J. Woodman, "An introduction to inertial navigation"
(Cambridge UCAM-CL-TR-696, 2007) and IEEE Std 952-1997 (Allan variance terms N, K).
Vibration: motor-frequency sinusoids (fundamental + 2nd harmonic) that alias at the
IMU sample rate as on a real airframe.

The autopilot's own estimates (ATTITUDE, GLOBAL_POSITION_INT, LOCAL_POSITION_NED), the
GPS fix error and the barometer error are first-order Gauss-Markov processes
(:class:`GaussMarkov`) on the truth; GPS velocity and ADS-B reports carry white noise.
Every process draws from its own named stream (:func:`.vehicle.stream_rng`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import lfilter

from ..geometry.geodesy import LocalFrame
from .vehicle import TruthChunk, stream_rng

Array = np.ndarray

__all__ = ["AdsbReports", "GaussMarkov", "ImuChunk", "ImuModel", "NavSensors",
           "earth_field_ned"]

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

    def __init__(self, cfg: Any, mag_cfg: Any, rate: float, seed: int) -> None:
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        r_bias = stream_rng(seed, "imu.bias")
        self.rg, self.ra = stream_rng(seed, "imu.gyro"), stream_rng(seed, "imu.accel")
        self.rbw = stream_rng(seed, "imu.bias_walk")
        self.rmag = stream_rng(seed, "mag")
        self.gyro_nd = float(cfg.gyro_noise_density)
        self.accel_nd = float(cfg.accel_noise_density)
        self.gyro_rw = float(cfg.gyro_bias_walk)
        self.accel_rw = float(cfg.accel_bias_walk)
        self.gyro_drift = float(cfg.gyro_drift)  # rad/s^2, every axis
        bg, ba = cfg.gyro_bias, cfg.accel_bias
        self.bg = (_vec3(bg, 0.0) if bg is not None else
                   r_bias.normal(0, float(cfg.gyro_bias_std), 3))
        self.ba = (_vec3(ba, 0.0) if ba is not None else
                   r_bias.normal(0, float(cfg.accel_bias_std), 3))
        rv = stream_rng(seed, "imu.vib")
        self.vib_f = float(cfg.vibration_hz)
        self.vib_a = _vec3(cfg.vibration_accel, [0.6, 0.6, 1.5])
        self.vib_g = _vec3(cfg.vibration_gyro, [0.01, 0.01, 0.005])
        self.vib_ph = rv.uniform(0, 2 * np.pi, (4, 3))
        decl = np.deg2rad(float(mag_cfg.declination_deg))
        incl = np.deg2rad(float(mag_cfg.inclination_deg))
        self.declination = decl
        self.b_ned = earth_field_ned(decl, incl, float(mag_cfg.intensity_gauss))
        self.mag_off = _vec3(mag_cfg.offsets_gauss, 0.0)
        self.mag_noise = float(mag_cfg.noise_gauss)
        self.mag_rate = float(mag_cfg.rate_hz)
        self._mag_last = None
        self._mag_k = -1

    def chunk(self, tr: TruthChunk) -> ImuChunk:
        n = tr.t.size
        sq = np.sqrt(self.dt)
        wg = self.rg.standard_normal((n, 3)) * (self.gyro_nd / sq)
        wa = self.ra.standard_normal((n, 3)) * (self.accel_nd / sq)
        walk = self.rbw.standard_normal((n, 6)) * sq
        bg = self.bg + np.cumsum(walk[:, :3] * self.gyro_rw + self.gyro_drift * self.dt,
                                 axis=0)
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


#: The simulator's GNSS delay, s: its receiver stamps each fix (GPS_RAW_INT) with the time
#: it measures, and its velocity is the velocity at that time (``uavest demo`` gives it
#: to its estimator as ``--gnss-delay``, as a user would from a receiver's datasheet).
GNSS_DELAY_S = 0.0


def spec_noise(scenario: Any) -> dict[str, float]:
    """The navigation model's noise parameters (:class:`~uavest.models.navigation.NavNoise`
    names) that a ``kind = "sim"`` scenario specifies its sensors with, as a user would
    take them from a datasheet (``uavest demo`` hands them to its estimator):
    ``gyro_noise`` the ``[imu]`` gyro noise density (rad/s/sqrt(Hz)) and ``mag_noise``
    the ``[mag]`` per-sample noise over the field's intensity (rad: the direction noise
    of one reading); ``gnss_bias_h`` / ``gnss_bias_v`` / ``gnss_bias_tau`` the ``[gps]``
    receiver's Gauss-Markov position error (``sigma_h``, ``sigma_v`` m, ``tau_s`` s).
    The accelerometer's is not among them: at the IMU rates the demo streams, the
    airframe's vibration (``vibration_accel``) is most of it."""
    imu, mag, gps = scenario.imu, scenario.mag, scenario.gps
    out = {"gyro_noise": float(imu.gyro_noise_density)}
    if float(mag.intensity_gauss) > 0:
        out["mag_noise"] = float(mag.noise_gauss) / float(mag.intensity_gauss)
    if float(gps.sigma_h) > 0 or float(gps.sigma_v) > 0:
        out.update(gnss_bias_h=float(gps.sigma_h), gnss_bias_v=float(gps.sigma_v),
                   gnss_bias_tau=float(gps.tau_s))
    return out


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


class NavSensors:
    """The GPS receiver and the autopilot's estimate errors, from a ``kind = "sim"``
    scenario's ``[gps]``, ``[ahrs]`` and ``[baro]`` tables.

    Per IMU chunk, :meth:`errors` gives the attitude (rad), position (m), velocity (m/s)
    and barometer (m) errors of the autopilot's estimates at each step; at the GPS rate,
    :meth:`gps_update` makes a fix (:attr:`fix`: ``t_us``, ``lat``/``lon`` deg, ``alt``
    m, ``vel`` NED m/s, ``acc`` the reported accuracies: horizontal, vertical m and
    speed m/s) from the truth.
    """

    def __init__(self, scenario: Any, imu_rate: float, seed: int, frame: LocalFrame) -> None:
        self.frame = frame
        g = scenario.gps
        self.gps_rate = float(g.rate_hz)
        dt_gps = 1.0 / self.gps_rate
        self.gps_err = GaussMarkov([g.sigma_h] * 2 + [g.sigma_v],
                                   float(g.tau_s), dt_gps, stream_rng(seed, "gps"))
        self.gps_vel_sigma = float(g.sigma_vel)
        #: what the receiver reports as its accuracy (GPS_RAW_INT h_acc / v_acc / vel_acc,
        #: m and m/s): its position error's std, and ``speed_acc_scale`` times its
        #: velocity noise's (a receiver's own speed accuracy is conservative)
        self.gps_acc = (float(g.sigma_h), float(g.sigma_v),
                        float(g.speed_acc_scale) * float(g.sigma_vel))
        self.gps_rng = stream_rng(seed, "gps.vel")
        ah = scenario.ahrs
        dt = 1.0 / imu_rate
        self.att_err = GaussMarkov(
            np.deg2rad([ah.roll_err_deg, ah.pitch_err_deg, ah.yaw_err_deg]),
            float(ah.tau_s), dt, stream_rng(seed, "ahrs"))
        self.nav_err = GaussMarkov([ah.pos_err_m] * 3, float(ah.tau_s),
                                   dt, stream_rng(seed, "nav"))
        self.vel_err = GaussMarkov([ah.vel_err] * 3, 2.0, dt,
                                   stream_rng(seed, "nav.vel"))
        self.baro_err = GaussMarkov([scenario.baro.sigma_m], 20.0, dt,
                                    stream_rng(seed, "baro"))
        self.fix: dict | None = None

    def errors(self, n: int) -> tuple[Array, Array, Array, Array]:
        """The next ``n`` steps' errors: attitude (n, 3) rad, position (n, 3) m, velocity
        (n, 3) m/s, barometer (n,) m."""
        return (self.att_err.run(n), self.nav_err.run(n), self.vel_err.run(n),
                self.baro_err.run(n)[:, 0])

    def gps_update(self, t_us: int, pos: Array, vel: Array) -> None:
        """A new fix at ``t_us`` (us since boot) of the true NED position / velocity."""
        err = self.gps_err.step()
        p = pos + err
        la, lo, hh = self.frame.ned_to_geodetic(p)
        v = vel + self.gps_rng.standard_normal(3) * self.gps_vel_sigma
        self.fix = {"t_us": int(t_us), "lat": float(la), "lon": float(lo),
                    "alt": float(hh), "vel": v, "acc": self.gps_acc}


class AdsbReports:
    """ADS-B reports of the targets (the scenario's ``[adsb]`` table): white noise on the
    true NED position (``sigma_h``, ``sigma_v`` m) and velocity (``sigma_vel`` m/s), one
    report per target every ``1 / rate_hz`` s."""

    def __init__(self, cfg: Any, n_targets: int, seed: int) -> None:
        self.enabled = bool(cfg.enabled) and n_targets > 0
        self.interval_us = int(1e6 / float(cfg.rate_hz))
        self.sigma = (float(cfg.sigma_h), float(cfg.sigma_v),
                      float(cfg.sigma_vel))
        self.rng = stream_rng(seed, "adsb")

    def report(self, pos: Array, vel: Array) -> tuple[Array, Array]:
        """A noisy (position NED m, velocity NED m/s) of one target."""
        sh, sv, svel = self.sigma
        r = self.rng
        p = pos + r.standard_normal(3) * np.array([sh, sh, sv])
        v = vel + r.standard_normal(3) * svel
        return p, v
