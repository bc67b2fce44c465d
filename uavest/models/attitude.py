"""Attitude models on the rotation manifold: gyro-driven process, accelerometer gravity
direction and magnetometer heading, for every filter of :mod:`uavest.core`.

State (see :class:`~uavest.geometry.rotation.AttitudeSpace`): ``x = [q, b]``, ``q`` the
unit quaternion body FRD -> NED (scalar-first, Hamilton), ``b`` the gyro bias (rad/s,
body FRD). Tangent error ``[dtheta, db]`` with ``q_true = q * Exp(dtheta)`` (body-frame,
right-multiplicative error), so the EKF on this space is the multiplicative EKF.

Process (:class:`GyroTransition`), exact for a rate constant over the step:
    q_k = q_{k-1} * Exp((omega - b) dt),   b_k = b_{k-1}
    Q = diag(sg^2 dt + sa^2 dt^3 / 3, sb^2 dt)   per axis
``sg`` gyro angle random walk (rad/s/sqrt(Hz)), ``sb`` bias random walk (rad/s^2/sqrt(Hz)),
``sa`` (rad/s^1.5) the unknown change of the true rate within a step, which dominates when
the gyro is sampled slowly (instantaneous rates streamed at a few Hz).

Accelerometer (:class:`GravityDirection`): z = -a / |a| (unit, body FRD), the direction of
gravity ("down") in the body frame; h(x) = R(q)^T e_down. Noise std
``accel_noise / g`` per axis, inflated by ``(| |a| - g | / g) * accel_deweight`` and the
update skipped (gated) when ``| |a| - g | > accel_gate`` (m/s^2).

Magnetometer (:class:`MagHeading`): h(x) = heading (rad, from north, clockwise) of the
body-measured field rotated into NED by the state, ``atan2(m_E, m_N)``; z = declination
(rad, east positive), residual wrapped to +-pi. Declination from the log's
``COMPASS_DEC`` (ArduPilot, rad) or ``ATT_MAG_DECL`` (PX4, deg) unless given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..core.interfaces import Measurement, Transition
from ..errors import InputError
from ..geometry.rotation import (
    G0,
    MANIFOLD_KERNELS,
    AttitudeSpace,
    dcm_to_quat,
    euler_to_quat,
    gyro_propagate,
    qexp_f,
    qmul_f,
    quat_exp,
    quat_mul,
    quat_rotate,
    quat_rotate_inv,
    quat_to_dcm,
    skew,
    wrap_pi,
)

Array = np.ndarray

__all__ = [
    "G0",
    "SENSOR_DEFAULTS",
    "AttitudeNoise",
    "GravityDirection",
    "GyroTransition",
    "MagField",
    "MagHeading",
    "Stacked",
    "inclination_from_samples",
    "inclination_from_params",
    "mag_reference",
    "reference_inclination",
    "declination_from_params",
    "initial_attitude",
    "noise_for_source",
    "sensor_family",
]

SPACE = AttitudeSpace()


@dataclass(frozen=True)
class AttitudeNoise:
    """Noise parameters of the attitude models (all overridable).

    gyro_noise: gyro angle random walk, rad/s/sqrt(Hz).
    gyro_bias_walk: gyro bias random walk, rad/s^2/sqrt(Hz).
    rate_walk: unmodelled change of the true rate within a step, rad/s^1.5 (adds
        rate_walk^2 dt^3 / 3 to the attitude variance).
    accel_noise: accelerometer direction noise expressed as m/s^2 std per axis.
    accel_deweight: factor on | |a| - g | / g added (in quadrature) to the accel std.
    accel_gate: skip the accel update when | |a| - g | exceeds this (m/s^2).
    mag_noise: heading noise std (rad).
    init_tilt: prior std of roll/pitch (rad); init_yaw: prior std of yaw (rad);
    init_bias: prior std of each gyro bias (rad/s).
    """

    gyro_noise: float = 0.003
    gyro_bias_walk: float = 1e-4
    rate_walk: float = 0.05
    accel_noise: float = 0.5
    accel_deweight: float = 1.0
    accel_gate: float = 3.0
    mag_noise: float = 0.05
    init_tilt: float = np.deg2rad(5.0)
    init_yaw: float = np.deg2rad(15.0)
    init_bias: float = np.deg2rad(0.5)

    def with_(self, **kw: float) -> AttitudeNoise:
        """Copy with fields replaced (unknown names raise TypeError)."""
        return replace(self, **kw)


#: Defaults by IMU source (``LogData.imu.source``). Streamed MAVLink IMU messages are
#: instantaneous samples at a few Hz: a large ``rate_walk`` covers the coarse
#: integration. DataFlash ``IMU`` (filtered snapshots) and PX4 ``sensor_combined`` (interval
#: averages) are full-rate (uavest/ingest/semantics.py).
SENSOR_DEFAULTS: dict[str, AttitudeNoise] = {
    "mavlink_stream": AttitudeNoise(
        gyro_noise=0.01, gyro_bias_walk=1e-4, rate_walk=0.25, accel_noise=0.6,
        accel_deweight=1.0, accel_gate=8.0, mag_noise=0.12,
    ),
    "dataflash": AttitudeNoise(
        gyro_noise=0.003, gyro_bias_walk=5e-5, rate_walk=0.02, accel_noise=0.8,
        accel_deweight=2.0, accel_gate=3.0, mag_noise=0.08,
    ),
    "px4": AttitudeNoise(
        gyro_noise=0.004, gyro_bias_walk=5e-5, rate_walk=0.02, accel_noise=0.8,
        accel_deweight=2.0, accel_gate=3.0, mag_noise=0.08,
    ),
}


def sensor_family(source: str) -> str | None:
    """The :data:`SENSOR_DEFAULTS` key for an IMU source name, or None when unknown.

    MAVLink IMU messages (``RAW_IMU``, ``SCALED_IMU*``, ``HIGHRES_IMU``) are
    ``mavlink_stream``, DataFlash ``IMU``/``IMT`` ``dataflash``, ULog ``sensor_*`` ``px4``.
    """
    s = source.upper()
    if s.startswith(("RAW_IMU", "SCALED_IMU", "HIGHRES_IMU")):
        return "mavlink_stream"
    if s.startswith("IMU"):
        return "dataflash"
    if "SENSOR" in s:
        return "px4"
    return None


def noise_for_source(source: str) -> AttitudeNoise:
    """Default :class:`AttitudeNoise` for an IMU source name (see :data:`SENSOR_DEFAULTS`)."""
    family = sensor_family(source)
    return SENSOR_DEFAULTS[family] if family else AttitudeNoise()


def declination_from_params(params: dict[str, float]) -> float | None:
    """Magnetic declination (rad, east positive) from the log, or None if unknown
    (:func:`declination_and_source` without the source)."""
    return declination_and_source(params)[0]


def _on(params: dict, name: str, default: bool) -> bool:
    v = params.get(name)
    return default if v is None else bool(int(v) & 1)


def declination_and_source(params: dict) -> tuple[float | None, str]:
    """Magnetic declination (rad, east positive) and where it came from, or (None, why).

    In order: ArduPilot ``COMPASS_DEC`` (rad); PX4 ``EKF2_MAG_DECL`` (degrees; modern
    EKF2) then ``ATT_MAG_DECL`` (degrees; old attitude estimator). A 0 with the
    autopilot's automatic declination on (ArduPilot ``COMPASS_AUTODEC``, default on;
    PX4 ``EKF2_DECL_TYPE`` bit 0, ``ATT_MAG_DECL_A``) is the value *before* the GPS lock
    (DataFlash PARM records keep that boot value), so unknown: then the World Magnetic
    Model at the log's first GPS fix and its date (``params.geo``, set by the sources on
    a :class:`~uavest.ingest.types.LogParams`: GNSS UTC time or GPS week/time of week);
    a fix without a GNSS date (``params.fix``): at the log's own date (``params.date``,
    e.g. a tlog's receive times), else at the model's epoch, said in the source; no fix
    at all: None (the caller uses 0).
    """
    unknown = []
    for name, unit, auto, default in (
        ("COMPASS_DEC", "rad", "COMPASS_AUTODEC", True),
        ("EKF2_MAG_DECL", "deg", "EKF2_DECL_TYPE", True),
        ("ATT_MAG_DECL", "deg", "ATT_MAG_DECL_A", True),
    ):
        if name not in params:
            continue
        v = float(params[name])
        if not np.isfinite(v):
            continue
        if v == 0.0 and _on(params, auto, default):
            unknown.append(f"{name} = 0 with {auto} on")
            continue
        rad = v if unit == "rad" else float(np.deg2rad(v))
        if abs(rad) > np.pi:
            unknown.append(f"{name} = {v:g} {unit} out of range")
            continue
        return rad, f"log parameter {name} ({v:.4g} {unit})"
    tail = f"; {', '.join(unknown)}" if unknown else ""
    geo = getattr(params, "geo", None)
    if geo:
        try:
            d, what = wmm_declination(geo["lat"], geo["lon"], geo.get("alt", 0.0), geo["utc"])
            return d, what + tail
        except ValueError as e:
            unknown.append(str(e))
    fix = getattr(params, "fix", None)
    if fix:  # a fix without a GNSS date: the log's own date, else the model's epoch
        date = getattr(params, "date", None)
        try:
            if date:
                d, what = wmm_declination(fix["lat"], fix["lon"], fix.get("alt", 0.0),
                                          date["utc"])
                return d, f"{what} (no GNSS date: the date of the {date['what']}){tail}"
            d, what = wmm_declination(fix["lat"], fix["lon"], fix.get("alt", 0.0), None)
            return d, f"{what} (no date in the log: the model's epoch){tail}"
        except ValueError as e:
            unknown.append(str(e))
    why = "; ".join(unknown) if unknown else "no declination parameter or GPS fix in the log"
    return None, f"none (0): {why}"


_WMM_EPOCHS = (2010, 2015, 2020, 2025)


def wmm_declination(lat: float, lon: float, alt: float, utc_s: float | None
                    ) -> tuple[float, str]:
    """World Magnetic Model declination (rad) at a position (deg, deg, m AMSL) and UNIX
    time ``utc_s``, with a description. The WMM epoch of the date is used (2010, 2015,
    2020, 2025, each valid 5 years); dates outside 2010-2030 use the nearest epoch's end
    and say so; ``utc_s`` None (no date known): the newest model at its epoch. For
    2025-2030 this is :func:`uavest.geometry.magnetic.declination`."""
    return _wmm_angle("d", lat, lon, alt, utc_s)


def wmm_inclination(lat: float, lon: float, alt: float, utc_s: float | None
                    ) -> tuple[float, str]:
    """World Magnetic Model inclination (rad, positive down) as :func:`wmm_declination`."""
    return _wmm_angle("i", lat, lon, alt, utc_s)


def _wmm_angle(key: str, lat: float, lon: float, alt: float, utc_s: float | None
               ) -> tuple[float, str]:
    from datetime import UTC, datetime

    from ..geometry.magnetic import decimal_year

    if not all(np.isfinite([lat, lon, alt])) or abs(lat) > 90 or abs(lon) > 360:
        raise InputError(f"no usable GPS position for the magnetic model ({lat}, {lon})")
    if utc_s is None:
        epoch = _WMM_EPOCHS[-1]
        r = _geomag(epoch).calculate(glat=float(lat), glon=float(lon),
                                     alt=float(alt) / 1000.0, time=float(epoch))
        d = float(np.deg2rad(getattr(r, key)))
        return d, (f"World Magnetic Model WMM{epoch} at {lat:.4f}, {lon:.4f} at its epoch "
                   f"{epoch}.0: {np.rad2deg(d):.2f} deg")
    if not np.isfinite(utc_s):
        raise InputError(f"no usable date for the magnetic model ({utc_s})")
    when = datetime.fromtimestamp(float(utc_s), tz=UTC)
    year = decimal_year(when)
    note = ""
    y = min(max(year, 2010.0), 2029.999)
    if y != year:
        note = f", the log's date {year:.1f} clamped to the model's span"
    epoch = max(e for e in _WMM_EPOCHS if e <= y)
    r = _geomag(epoch).calculate(glat=float(lat), glon=float(lon), alt=float(alt) / 1000.0,
                                 time=y)
    d = float(np.deg2rad(getattr(r, key)))
    return d, (f"World Magnetic Model WMM{epoch} at {lat:.4f}, {lon:.4f} on "
               f"{when:%Y-%m-%d}{note}: {np.rad2deg(d):.2f} deg")


def inclination_from_params(params: dict) -> tuple[float | None, str]:
    """Magnetic inclination (rad, positive down) of the World Magnetic Model at the log's
    first GPS fix and its date (``params.geo``), else at a fix without a GNSS date
    (``params.fix``) on the log's own date (``params.date``) or the model's epoch (the
    inclination changes by about 0.1 deg a year), with where it came from; (None, why)
    without a fix or when the model cannot be evaluated."""
    geo = getattr(params, "geo", None)
    fix = geo or getattr(params, "fix", None)
    if not fix:
        return None, "no GPS fix in the log yet"
    date = getattr(params, "date", None)
    utc = geo["utc"] if geo else (date["utc"] if date else None)
    try:
        inc, what = wmm_inclination(fix["lat"], fix["lon"], fix.get("alt", 0.0), utc)
    except (ValueError, ImportError) as e:
        return None, str(e)
    if not geo:
        what += (f" (no GNSS date: the date of the {date['what']})" if date
                 else " (no date in the log: the model's epoch)")
    return inc, what


_GEOMAG: dict = {}


def _geomag(epoch: int):
    if epoch not in _GEOMAG:
        import os

        import pygeomag
        from pygeomag import GeoMag

        name = "WMM_2015v2.COF" if epoch == 2015 else f"WMM_{epoch}.COF"
        path = os.path.join(os.path.dirname(pygeomag.__file__), "wmm", name)
        _GEOMAG[epoch] = GeoMag(coefficients_file=path) if os.path.exists(path) else GeoMag(
            base_year=epoch)
    return _GEOMAG[epoch]


def _weighted(R: Array, weight: float) -> Array:
    """R / weight for an update standing for ``weight`` (0, 1] of a reference step
    (:meth:`GravityDirection.from_accel`); weight 1 returns R itself."""
    if weight == 1.0:
        return R
    if not 0.0 < weight <= 1.0:
        raise ValueError(f"update weight must be in (0, 1], got {weight}")
    return R / weight


_DOWN = np.array([0.0, 0.0, 1.0])


class GyroTransition(Transition):
    """q <- q * Exp((u - b) dt), b <- b. ``u`` gyro rate (rad/s, body FRD, bias not
    removed). Analytic tangent Jacobian for the right error:
    F = [[Exp(-phi), -J_r(phi) dt], [0, I]], phi = (u - b) dt."""

    space = SPACE

    def __init__(self, noise: AttitudeNoise | None = None) -> None:
        self.noise = noise or AttitudeNoise()
        self._q_cache: tuple | None = None  # (dt, Q) of the last call

    def f(self, X: Array, t: float, dt: float, u: Array | None = None) -> Array:
        w = np.zeros(3) if u is None else np.asarray(u, float)
        if X.ndim == 2 and X.shape[0] == 1:  # one state (the EKF): on Python floats
            return _propagate_one(X[0].tolist(), w.tolist(), dt)[None, :]
        if X.ndim == 2:
            return gyro_propagate(X, w, dt)  # fused kernel, same numbers
        phi = (w - X[..., 4:]) * dt
        q = quat_mul(X[..., :4], quat_exp(phi))
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        return np.concatenate([q, X[..., 4:]], axis=-1)

    def Q(self, t: float, dt: float, u: Array | None = None) -> Array:
        dt = abs(dt)
        c = self._q_cache
        if c is not None and c[0] == dt:  # full-rate steps repeat dt: one diag per dt
            return c[1]
        n = self.noise
        qa = n.gyro_noise**2 * dt + n.rate_walk**2 * dt**3 / 3.0 + 1e-14
        qb = n.gyro_bias_walk**2 * dt + 1e-16
        Q = np.diag([qa, qa, qa, qb, qb, qb])
        Q.flags.writeable = False
        self._q_cache = (dt, Q)
        return Q

    def F(self, x: Array, t: float, dt: float, u: Array | None = None) -> Array:
        """The tangent Jacobian, on Python floats (one 6x6 array built at the end):
        Exp(-phi) as a DCM and the SO(3) right Jacobian J_r(phi) = I - (1 - cos th)/th^2
        [phi]x + (th - sin th)/th^3 [phi]x^2 (Taylor below th^2 = 1e-10), the formulas of
        :func:`~uavest.geometry.rotation.quat_to_dcm` / ``quat_exp`` and
        :func:`~uavest.geometry.rotation.right_jacobian`."""
        w = (0.0, 0.0, 0.0) if u is None else np.asarray(u, float).tolist()
        b = x[4:].tolist()
        px, py, pz = (w[0] - b[0]) * dt, (w[1] - b[1]) * dt, (w[2] - b[2]) * dt
        th2 = px * px + py * py + pz * pz
        th = math.sqrt(th2)
        # quat_exp(-phi) -> DCM
        h = 0.5 * th
        s = 0.5 - th * th / 48.0 if th < 1e-5 else math.sin(h) / th
        qw, qx, qy, qz = math.cos(h), -s * px, -s * py, -s * pz
        # J_r(phi) = I - a K + c K^2, K = [phi]x, K^2 = phi phi^T - th^2 I
        if th2 < 1e-10:
            a, c = 0.5, 1.0 / 6.0
        else:
            a, c = (1 - math.cos(th)) / th2, (th - math.sin(th)) / (th2 * th)
        kxx, kyy, kzz = px * px - th2, py * py - th2, pz * pz - th2
        kxy, kxz, kyz = px * py, px * pz, py * pz
        m = -dt
        return np.array([
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy),
             m * (1 + c * kxx), m * (a * pz + c * kxy), m * (-a * py + c * kxz)],
            [2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx),
             m * (-a * pz + c * kxy), m * (1 + c * kyy), m * (a * px + c * kyz)],
            [2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy),
             m * (a * py + c * kxz), m * (-a * px + c * kyz), m * (1 + c * kzz)],
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        ])


def _propagate_one(x: list, w: list, dt: float) -> Array:
    """q <- q * Exp((w - b) dt), normalised; b <- b: one state on Python floats (``qexp_f``,
    ``qmul_f``: the formulas of ``quat_exp`` / ``quat_mul``)."""
    qw, qx, qy, qz, bx, by, bz = x
    rw, rx, ry, rz = qmul_f((qw, qx, qy, qz),
                            qexp_f(((w[0] - bx) * dt, (w[1] - by) * dt, (w[2] - bz) * dt)))
    n = math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    return np.array([rw / n, rx / n, ry / n, rz / n, bx, by, bz])


class GravityDirection(Measurement):
    """Accelerometer as the gravity direction in body FRD (unit vector, 3 components).

    h(x) = R(q)^T r with r the unit "apparent down" in NED: (0, 0, 1), or
    (g_ned - a_ned)/|.| when the vehicle's acceleration a_ned is supplied.

    ``accel`` the specific force (m/s^2, body FRD); ``z = -accel/|accel|``. R is isotropic,
    std = sqrt(accel_noise^2 + (accel_deweight * | |a| - g |)^2) / g. Use
    :meth:`from_accel`, which returns None when the sample is gated out.
    """

    space = SPACE

    def __init__(self, R: Array, ref: Array | None = None) -> None:
        self.R = R
        self.ref = None if ref is None else np.asarray(ref, float)
        if self.ref is not None:  # np.allclose(ref, [0, 0, 1]) without its call cost
            r0, r1, r2 = self.ref.tolist()
            if abs(r0) <= 1e-8 and abs(r1) <= 1e-8 and abs(r2 - 1.0) <= 1e-8 + 1e-5:
                self.ref = None

    @staticmethod
    def from_accel(
        accel: Array, noise: AttitudeNoise, g: float = G0, accel_ned: Array | None = None,
        weight: float = 1.0,
    ) -> tuple[Array, GravityDirection] | None:
        """(z, model) for one accel sample, or None if gated / degenerate.

        ``accel_ned`` (m/s^2, NED), the vehicle's own acceleration if known (e.g. from
        differentiated GPS/EKF velocity): the reference direction becomes the apparent
        gravity ``g_ned - accel_ned`` and the gate / de-weighting use its norm.

        ``weight`` (0, 1]: the share of a reference step this update stands for, R is
        divided by it. ``accel_noise`` / ``accel_deweight`` describe the accelerometer
        averaged over a reference step (the default 25 Hz filter rate); its errors
        (vibration, unmodelled dynamics) are correlated over such a step, so k times more
        updates per second must each carry 1/k of the information: a step builder running
        at k times the reference rate passes ``weight = 1 / k`` (1: the reference rate,
        R unchanged bit for bit).
        """
        a = np.asarray(accel, float)
        na = float(np.linalg.norm(a))
        ref = np.array([0.0, 0.0, g])
        if accel_ned is not None and np.isfinite(accel_ned).all():
            ref = ref - np.asarray(accel_ned, float)
        nr = float(np.linalg.norm(ref))
        dev = abs(na - nr)
        if not np.isfinite(na) or na < 1e-6 or nr < 1e-6 or dev > noise.accel_gate:
            return None
        sd = np.hypot(noise.accel_noise, noise.accel_deweight * dev) / nr
        return -a / na, GravityDirection(_weighted(np.eye(3) * sd * sd, weight), ref / nr)

    def h(self, X: Array) -> Array:
        if self.ref is not None:
            return quat_rotate_inv(X[..., :4], self.ref)
        if X.ndim == 2 and MANIFOLD_KERNELS.get():  # R^T (0, 0, 1), compiled: the same sums
            return quat_rotate_inv(X[:, :4], _DOWN)
        w, x, y, z = X[..., 0], X[..., 1], X[..., 2], X[..., 3]
        return np.stack(
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1
        )

    def H(self, x: Array) -> Array:
        gb = self.h(x[None, :])[0]
        H = np.zeros((3, 6))
        H[:, :3] = skew(gb)
        return H


class MagHeading(Measurement):
    """Magnetometer heading: h(x) = atan2(m_E, m_N) of ``R(q) field`` (rad); z is the
    declination (rad, east positive); residual wrapped to [-pi, pi).

    Only the horizontal projection of the field enters, so its strength and inclination
    do not matter. Use :meth:`from_field` (None if the horizontal field is degenerate).
    """

    space = SPACE

    def __init__(self, field: Array, R: Array) -> None:
        self.field = np.asarray(field, float)
        self.R = R

    @staticmethod
    def from_field(
        field: Array, noise: AttitudeNoise, declination: float = 0.0, weight: float = 1.0
    ) -> tuple[Array, MagHeading] | None:
        """(z, model) for one magnetometer sample (gauss, body FRD), or None. ``weight``
        as :meth:`GravityDirection.from_accel` (R / weight; 1: unchanged)."""
        f = np.asarray(field, float)
        if not np.isfinite(f).all() or np.linalg.norm(f) < 1e-6:
            return None
        R = _weighted(np.array([[noise.mag_noise**2]]), weight)
        return np.array([declination]), MagHeading(f, R)

    def h(self, X: Array) -> Array:
        m = quat_rotate(X[..., :4], self.field)
        return np.arctan2(m[..., 1], m[..., 0])[..., None]

    def H(self, x: Array) -> Array:
        Rq = quat_to_dcm(x[:4])
        m = Rq @ self.field
        hn2 = m[0] ** 2 + m[1] ** 2
        if hn2 < 1e-12:
            return np.zeros((1, 6))
        dpsi_dm = np.array([-m[1], m[0], 0.0]) / hn2
        H = np.zeros((1, 6))
        H[0, :3] = dpsi_dm @ (-Rq @ skew(self.field))
        return H

    def residual(self, a: Array, b: Array) -> Array:
        return wrap_pi(a - b)

    def mean(self, Y: Array, w: Array) -> Array:
        ref = Y[0]
        return wrap_pi(ref + w @ wrap_pi(Y - ref))

    def arithmetic(self) -> str | None:
        return "angle"


class MagField(Measurement):
    """Magnetometer as a 3-D field direction: z = field/|field| (unit, body FRD),
    h(x) = R(q)^T m_ref with m_ref the unit Earth field in NED (declination east
    positive, inclination positive down, see :func:`mag_reference`). Unlike the heading,
    this also constrains tilt (strongly where the field is steep), which helps when the
    accelerometer is corrupted by manoeuvres. Std ``mag_noise`` (rad) per axis."""

    space = SPACE

    def __init__(self, ref: Array, R: Array) -> None:
        self.ref = np.asarray(ref, float)
        self.R = R

    @staticmethod
    def from_field(
        field: Array, noise: AttitudeNoise, ref: Array, weight: float = 1.0
    ) -> tuple[Array, MagField] | None:
        """(z, model) for one magnetometer sample (gauss, body FRD), or None. ``weight``
        as :meth:`GravityDirection.from_accel` (R / weight; 1: unchanged)."""
        f = np.asarray(field, float)
        nf = float(np.linalg.norm(f))
        if not np.isfinite(nf) or nf < 1e-6:
            return None
        return f / nf, MagField(ref, _weighted(np.eye(3) * noise.mag_noise**2, weight))

    def h(self, X: Array) -> Array:
        return quat_rotate_inv(X[..., :4], self.ref)

    def H(self, x: Array) -> Array:
        H = np.zeros((3, 6))
        H[:, :3] = skew(self.h(x[None, :])[0])
        return H


class Stacked(Measurement):
    """Several measurements of the same instant fused in one update (z and h
    concatenated, R block diagonal, residual/mean per block). Exactly equivalent to
    sequential updates for a linear-Gaussian model; one update instead of several keeps
    the per-step overhead down (used for accel + magnetometer)."""

    space = SPACE

    def __init__(self, models: list[Measurement]) -> None:
        self.models = models
        dims = [m.R.shape[0] for m in models]
        self._cuts = np.cumsum([0] + dims)
        n = int(self._cuts[-1])
        self.R = np.zeros((n, n))
        for m, a, b in zip(models, self._cuts[:-1], self._cuts[1:], strict=True):
            self.R[a:b, a:b] = m.R
        self._plain = all(type(m).residual is Measurement.residual for m in models)

    @staticmethod
    def of(pairs: list[tuple[Array, Measurement]]) -> tuple[Array, Measurement]:
        """(z, model) from several (z_i, model_i); a single pair is returned unchanged."""
        if len(pairs) == 1:
            return pairs[0]
        return np.concatenate([z for z, _ in pairs]), Stacked([m for _, m in pairs])

    def h(self, X: Array) -> Array:
        return np.concatenate([m.h(X) for m in self.models], axis=-1)

    def H(self, x: Array) -> Array:
        return np.vstack([m.H(x) for m in self.models])

    def residual(self, a: Array, b: Array) -> Array:
        if self._plain:
            return a - b
        a, b = np.broadcast_arrays(a, b)
        c = self._cuts
        return np.concatenate(
            [m.residual(a[..., c[i]:c[i + 1]], b[..., c[i]:c[i + 1]])
             for i, m in enumerate(self.models)], axis=-1)

    def mean(self, Y: Array, w: Array) -> Array:
        if self._plain:
            return w @ Y
        c = self._cuts
        return np.concatenate(
            [m.mean(Y[:, c[i]:c[i + 1]], w) for i, m in enumerate(self.models)])


def mag_reference(declination: float | Array, inclination: float | Array) -> Array:
    """Unit Earth field in NED from declination (rad, east positive) and inclination
    (rad, positive when the field points down: northern hemisphere): (3,), or (..., 3) for
    arrays of angles."""
    ci = np.cos(inclination)
    return np.stack([ci * np.cos(declination), ci * np.sin(declination), np.sin(inclination)],
                    axis=-1)


def reference_inclination(mref: Array) -> float:
    """The inclination (rad, positive down) of a unit NED field ``mref``
    (:func:`mag_reference`'s inverse for it)."""
    return float(np.arcsin(np.clip(mref[2], -1.0, 1.0)))


def reference_declination(mref: Array) -> float:
    """The declination (rad, east positive) of a NED field ``mref`` (:func:`mag_reference`'s
    inverse for it)."""
    return float(np.arctan2(mref[1], mref[0]))


def inclination_from_samples(accel: Array, field: Array) -> float:
    """Magnetic inclination (rad, positive down) from accel (m/s^2) and field samples
    (N, 3) taken together, via the mean angle between the field and gravity."""
    a = -np.atleast_2d(accel)
    f = np.atleast_2d(field)
    ok = np.isfinite(a).all(axis=1) & np.isfinite(f).all(axis=1)
    a = a[ok] / np.linalg.norm(a[ok], axis=1, keepdims=True)
    f = f[ok] / np.linalg.norm(f[ok], axis=1, keepdims=True)
    if a.shape[0] == 0:
        return 0.0
    return float(np.arcsin(np.clip(np.median(np.sum(a * f, axis=1)), -1.0, 1.0)))


def triad_attitude(f_body: Array, f_ned: Array, m_body: Array, m_ned: Array) -> Array:
    """Quaternion (body FRD -> NED) from two vector pairs by TRIAD (Black, "A passive
    system for determining the attitude of a satellite"): the specific force in body
    (m/s^2, accelerometer) and in NED (vehicle acceleration minus gravity: exact in a
    turn, where the accelerometer alone levels the wrong way), then the magnetic field in
    body and its NED direction (only its plane with the first pair is used)."""
    def unit(v):
        v = np.asarray(v, float)
        return v / np.linalg.norm(v)

    fb, fn = unit(f_body), unit(f_ned)
    t2b, t2n = unit(np.cross(fb, m_body)), unit(np.cross(fn, m_ned))
    Mb = np.column_stack([fb, t2b, np.cross(fb, t2b)])
    Mn = np.column_stack([fn, t2n, np.cross(fn, t2n)])
    return dcm_to_quat(Mn @ Mb.T)


def initial_attitude(accel: Array, field: Array | None, declination: float = 0.0) -> Array:
    """Quaternion (body FRD -> NED) from one accel sample (m/s^2) and, if given, one
    magnetometer sample: roll/pitch from gravity, yaw from the tilt-compensated field."""
    a = -np.asarray(accel, float)  # gravity direction in body, "down"
    roll = float(np.arctan2(a[1], a[2]))
    pitch = float(np.arctan2(-a[0], np.hypot(a[1], a[2])))
    yaw = 0.0
    if field is not None and np.isfinite(field).all():
        q0 = euler_to_quat(roll, pitch, 0.0)
        m = quat_rotate(q0, np.asarray(field, float))
        yaw = float(wrap_pi(declination - np.arctan2(m[1], m[0])))
    return euler_to_quat(roll, pitch, yaw)
