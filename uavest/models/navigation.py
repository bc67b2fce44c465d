"""GNSS-aided inertial navigation models on :class:`~uavest.geometry.navigation.NavSpace`.

State ``x = [q, v, p, bg, ba]`` (see the space's docstring: q body FRD -> NED, v NED m/s,
p NED m from a LocalFrame origin, bg rad/s, ba m/s^2, both body FRD).

Mechanisation (:class:`ImuTransition`), input ``u = [gyro (3, rad/s), specific force
(3, m/s^2)]`` in body FRD, step ``dt`` (s), first order::

    w   = u_g - bg [- R^T w_ie]           (Earth rate only when ``earth_rate=True``)
    a_n = R(q) (u_a - ba) + (0, 0, g(lat, h))
    q  <- q * Exp(w dt)                   (a_n with the mid-step attitude q * Exp(w dt / 2))
    v  <- v + a_n dt
    p  <- p + v dt + a_n dt^2 / 2
    bg, ba <- bg, ba                       (random walks, in Q)

g from :func:`~uavest.geometry.geodesy.gravity` (Somigliana) at the reference latitude and
height given to the transition. Transport rate and Coriolis are omitted (local, short
flights); the antenna lever arm is omitted.

Aiding: :class:`GnssPosition` (NED m), :class:`GnssVelocity` (NED m/s),
:class:`BaroHeight` (height up, m, with an offset estimated at start-up and held fixed,
not a state), and :class:`OnNav` which moves an attitude measurement (MagHeading,
MagField, GravityDirection) onto the navigation state.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from uavest.compiled import read_only, register
from uavest.core.interfaces import Measurement, Transition
from uavest.geometry.geodesy import EARTH_RATE, gravity
from uavest.geometry.navigation import NavSpace
from uavest.geometry.rotation import (
    dcm_f,
    quat_exp,
    quat_rotate,
    quat_rotate_inv,
    quat_to_dcm,
    right_jacobian,
    skew,
)
from uavest.models.attitude import (
    GyroTransition,
    MagField,
    MagHeading,
    mag_reference,
    reference_declination,
    reference_inclination,
    sensor_family,
)

Array = np.ndarray

SPACE = NavSpace()
#: the space with the GNSS receiver bias states (NavNoise.gnss_bias)
SPACE_GNSS_BIAS = NavSpace(extra=3)


def names_gnss_bias(overrides: dict[str, float]) -> bool:
    """True when ``--noise`` overrides name any of the GNSS bias states' parameters (they
    are then the user's, not estimated)."""
    return any(k.startswith("gnss_bias_") for k in overrides)


def nav_dim(overrides: dict[str, float]) -> int:
    """The navigation state's tangent dimension (15, or 18 with the GNSS bias states)
    for ``--noise`` overrides (the IMU profiles leave the bias states off, so the
    overrides decide; filters are built for this dimension)."""
    return nav_space(NavNoise().with_(**overrides)).dim


def nav_space(noise: NavNoise) -> NavSpace:
    """The state space for ``noise``: :data:`SPACE_GNSS_BIAS` when it has GNSS bias
    states, else :data:`SPACE`; with the gyro drift states (:attr:`NavNoise.gyro_drift`)
    three more components after those, and with the magnetic reference states
    (:attr:`NavNoise.mag_ref`) two more after all of them."""
    if noise.mag_ref or noise.gyro_drift:
        return NavSpace(extra=3 if noise.gnss_bias else 0, mag=2 if noise.mag_ref else 0,
                        drift=3 if noise.gyro_drift else 0)
    return SPACE_GNSS_BIAS if noise.gnss_bias else SPACE


@dataclass(frozen=True)
class NavNoise:
    """Every noise parameter of the navigation model, per sensor, in one place.

    gyro_noise: gyro angle random walk, rad/s/sqrt(Hz).
    accel_noise: accelerometer velocity random walk, m/s^2/sqrt(Hz).
    gyro_bias_walk: gyro bias random walk, rad/s^2/sqrt(Hz) (rad/s per sqrt(s)).
    accel_bias_walk: accelerometer bias random walk, m/s^3/sqrt(Hz).
    rate_walk: unmodelled change of the true rate within a step, rad/s^1.5 (adds
        rate_walk^2 dt^3 / 3 to the attitude variance: a coarsely sampled IMU, as the
        attitude model's parameter of the same name).
    accel_walk: unmodelled change of the true specific force within a step, m/s^2.5
        (adds accel_walk^2 dt^3 / 3 to the velocity variance).
    accel_rough: the share of the accelerometer density that follows how rough the flight
        is, sqrt(s): a navigation stream's step takes ``sqrt(accel_noise^2 + (accel_rough *
        r)^2)`` with ``r`` the specific force's RMS change between consecutive 40-ms
        means over the last seconds, m/s^2 (:mod:`uavest.engine.nav_rough`); 0: a fixed
        density.
    gnss_pos_floor: lower bound on the GNSS horizontal position std, m (also used
        when the receiver reports no accuracy); gnss_vpos_floor: vertical, m.
    gnss_vel_floor: lower bound on the GNSS velocity std per axis, m/s.
    gnss_delay: GNSS measurement delay, s (the fix is applied to the state that far
        back; 0: none).
    gnss_vel_window: the GNSS velocity is the mean velocity over this long a window, s,
        centred ``gnss_delay`` before the fix's stamp (0: the velocity at that time).
        An ArduPilot SITL's GPS_RAW_INT velocity is such a mean over about 0.35 s
        (docs/navigation.md).
    baro_noise: barometric height std, m.
    mag_noise: the magnetic field's direction std per axis, rad (with a heading
        measurement, the heading's std is this over cos(inclination)).
    gate_chi2: innovation gate, chi-square value per measurement dimension group
        (applied as the 99.9 % quantile for the dimension when None).
    init_tilt, init_yaw: prior std of roll/pitch and yaw, rad (yaw from the
        magnetometer); init_yaw_course: prior std of a yaw taken from the GNSS course
        once moving (no magnetometer), rad: the crab/sideslip it leaves.
    init_vel: m/s; init_pos: m; init_gyro_bias: rad/s; init_accel_bias: m/s^2.
    nofix_pos_noise: before the first GNSS fix, the std (m, each NED axis) of the
        constant-position measurement that holds the unaided mechanisation near where
        it started (ArduPilot EKF3's EK3_NOAID_M_NSE default, 10 m).
    gnss_bias_h, gnss_bias_v, gnss_bias_tau: the receiver's slowly varying position
        error as first-order Gauss-Markov states ``bp`` (NED, m) with steady std
        ``gnss_bias_h`` (north, east) and ``gnss_bias_v`` (down), m, and correlation time
        ``gnss_bias_tau``, s: a fix measures ``p + bp``; its white part is what the
        receiver's accuracy leaves beyond them (``sqrt(h_acc^2 - gnss_bias_h^2)``, at least
        the floors). ``gnss_bias_tau`` 0 (default): no such states (15, not 18), the fixes'
        errors independent.
    mag_ref_inc, mag_ref_dec, mag_ref_walk: the magnetic reference's errors as two
        states (rad, after the GNSS bias states when there are): the field the 3-D
        magnetometer update expects has the inclination and declination it was given
        (the magnetic model's, the log's COMPASS_DEC...) plus these. ``mag_ref_inc`` and
        ``mag_ref_dec`` are their prior stds (rad; both 0, the default: no such states,
        the reference taken as exact), ``mag_ref_walk`` their random walk, rad/sqrt(s) (a
        local anomaly changes as the vehicle moves). A site's field is often a degree or
        more off the model, and a magnetometer trusted to its white noise otherwise puts
        that error into the tilt (docs/navigation.md, "The magnetic reference states").
    gyro_drift_walk, init_gyro_drift: the gyro bias's rate of change as three states
        ``dbg/dt`` (rad/s^2, body FRD; after the GNSS bias states, before the magnetic
        reference's): the bias then moves as ``bg += dbg/dt * dt``, and its rate as a
        random walk of ``gyro_drift_walk`` rad/s^2/sqrt(s), from 0 +- ``init_gyro_drift``
        rad/s^2. For a bias that ramps (a warming MEMS gyro; an ArduPilot SITL's
        ``SIM_DRIFT_SPEED``, 0.05 deg/s per minute = 1.45e-5 rad/s^2), which a random walk
        follows with a lag. ``gyro_drift_walk`` 0 (default): no such states
        (docs/navigation.md, "The gyro drift states").
    """

    gyro_noise: float = 0.003
    accel_noise: float = 0.05
    gyro_bias_walk: float = 5e-5
    accel_bias_walk: float = 1e-3
    rate_walk: float = 0.0
    accel_walk: float = 0.0
    accel_rough: float = 0.0
    gnss_pos_floor: float = 0.5
    gnss_vpos_floor: float = 1.0
    gnss_vel_floor: float = 0.1
    gnss_delay: float = 0.0
    gnss_vel_window: float = 0.0
    baro_noise: float = 0.5
    mag_noise: float = 0.08
    init_tilt: float = np.deg2rad(5.0)
    init_yaw: float = np.deg2rad(15.0)
    init_yaw_course: float = np.deg2rad(20.0)
    init_vel: float = 1.0
    init_pos: float = 5.0
    init_gyro_bias: float = np.deg2rad(0.5)
    init_accel_bias: float = 0.2
    nofix_pos_noise: float = 10.0
    gnss_bias_h: float = 0.0
    gnss_bias_v: float = 0.0
    gnss_bias_tau: float = 0.0
    mag_ref_inc: float = 0.0
    mag_ref_dec: float = 0.0
    mag_ref_walk: float = 1e-5
    gyro_drift_walk: float = 0.0
    init_gyro_drift: float = 5e-5

    @property
    def gyro_drift(self) -> bool:
        """True when the model carries the gyro drift states (``gyro_drift_walk`` > 0)."""
        return self.gyro_drift_walk > 0

    @property
    def mag_ref(self) -> bool:
        """True when the model carries the magnetic reference states (a non-zero prior
        std for the inclination's or the declination's error)."""
        return self.mag_ref_inc > 0 or self.mag_ref_dec > 0

    @property
    def mag_ref_sd(self) -> Array:
        """The magnetic reference states' prior std, rad (inclination, declination; at
        least 1e-6: a zero would leave the covariance singular)."""
        return np.maximum([self.mag_ref_inc, self.mag_ref_dec], 1e-6)

    @property
    def gnss_bias(self) -> bool:
        """True when the model carries the GNSS receiver bias states (``gnss_bias_tau``
        > 0 and a non-zero std)."""
        return self.gnss_bias_tau > 0 and (self.gnss_bias_h > 0 or self.gnss_bias_v > 0)

    def gnss_pos_sd(self, h_acc: float | None, v_acc: float | None) -> tuple[float, float]:
        """The std (m) of a fix's independent error, horizontal and vertical: the
        receiver's accuracy (``h_acc``, ``v_acc`` m; None or NaN: not reported) less the
        GNSS bias states' share in quadrature when the model has them, at least the
        floors."""
        def part(acc: float | None, bias: float, floor: float) -> float:
            a = float(acc) if acc and np.isfinite(acc) else 0.0
            if self.gnss_bias:
                a = float(np.sqrt(max(a * a - bias * bias, 0.0)))
            return max(floor, a)
        return (part(h_acc, self.gnss_bias_h, self.gnss_pos_floor),
                part(v_acc, self.gnss_bias_v, self.gnss_vpos_floor))

    @property
    def gnss_bias_sd(self) -> Array:
        """The bias states' steady std, NED, m (3,) (at least 1 mm: a zero would leave
        the covariance singular)."""
        return np.maximum([self.gnss_bias_h, self.gnss_bias_h, self.gnss_bias_v], 1e-3)

    def with_(self, **kw: float) -> NavNoise:
        """Copy with fields replaced (unknown names raise TypeError)."""
        return replace(self, **kw)


#: Streamed MAVLink IMUs (RAW_IMU, SCALED_IMU*, HIGHRES_IMU): instantaneous samples at a
#: few Hz in telemetry (vtol.tlog: 3.8 Hz): the rate and the specific force change within
#: a step (``rate_walk``, ``accel_walk``, whose terms vanish as dt^3 at high rates), and
#: GPS_RAW_INT reports no accuracy, so the floors are the receiver's std. Fitted on the
#: airborne part of vtol.tlog (docs/navigation.md: optimistic for that log).
MAVLINK_PROFILE = NavNoise(gyro_noise=0.01, accel_noise=0.2, rate_walk=0.5, accel_walk=3.0,
                           mag_noise=0.12, gnss_pos_floor=1.0, gnss_vel_floor=0.3)

#: Streamed MAVLink IMUs at :data:`FAST_STREAM_HZ` or faster (an ArduPilot RAW_IMU at
#: 200 Hz: the autopilot's calibrated IMU after its 20 Hz low-pass): fitted with the EKF on
#: two ArduCopter SITL flights (logs/sitl_copter.tlog and a live session's, replayed)
#: once the replay models what the SITL's receiver and baro do (the velocity as a window
#: mean, its speed truncated to whole cm/s, the baro's delay; docs/navigation.md): the
#: least densities and velocity floor that keep the three NEES blocks in their 95 % band
#: on >= 80 % of the airborne steps on both flights at both rates. The velocity floor is
#: the SITL receiver's velocity residual once the window is modelled (0.004 m/s: its
#: centimetre steps). The position floors are the SITL receiver's h_acc / v_acc (0.3 m);
#: a receiver that reports more is taken at its word. Before (gyro 0.002, accel 0.02,
#: velocity floor 0.03, fitted without the window): airborne EKF 0.111 / 0.110 / 0.445
#: deg on logs/sitl_copter.tlog, NEES in band 0.88 / 0.73 / 0.84. The accelerometer
#: density follows the flight (``accel_rough``, :mod:`uavest.engine.nav_rough`): a fixed
#: 0.005 fitted to the windy logs/sitl_copter.tlog left calm live flights' velocity
#: under-confident (in band on 0.774-0.784 of their steps), 0.003 made the windy one's
#: live run over-confident; 0.0019 + 0.022 x the roughness keeps both in band
#: (docs/navigation.md, "An accelerometer density that follows the flight").
FAST_MAVLINK_PROFILE = NavNoise(gyro_noise=0.001, accel_noise=0.0019, accel_rough=0.022,
                                gnss_vel_floor=0.004, gnss_pos_floor=0.3,
                                gnss_vpos_floor=0.3, baro_noise=0.2)

#: Defaults by IMU source (as :data:`uavest.models.attitude.SENSOR_DEFAULTS`); only
#: ``mavlink_stream`` fitted to a log (the only real log with a GNSS stream here).
SENSOR_DEFAULTS: dict[str, NavNoise] = {
    "mavlink_stream": MAVLINK_PROFILE,
    "dataflash": NavNoise(),
    "px4": NavNoise(gyro_noise=0.004),
}


#: A streamed MAVLink IMU at least this fast (Hz) is not a coarsely sampled telemetry
#: IMU: it gets :data:`FAST_MAVLINK_PROFILE` (the 200 Hz RAW_IMU of an ArduCopter SITL
#: flight, docs/navigation.md), not :data:`MAVLINK_PROFILE`, whose noise densities were
#: fitted at 3.8 Hz.
FAST_STREAM_HZ = 50.0


def nav_noise_for_source(source: str, rate_hz: float | None = None) -> NavNoise:
    """Default :class:`NavNoise` for an IMU source name (families as ``sensor_family``)
    and its sample rate (Hz; None: unknown). A MAVLink stream slower than
    :data:`FAST_STREAM_HZ` (or of unknown rate) gets :data:`MAVLINK_PROFILE`, a faster
    one :data:`FAST_MAVLINK_PROFILE`: at 3.8 Hz the fitted densities absorb the change of
    rate and force within a step; at 200 Hz they would be 10-20x the IMU's own and leave
    tilt to the GNSS velocity only weakly (docs/navigation.md)."""
    family = sensor_family(source)
    if family == "mavlink_stream" and rate_hz is not None and rate_hz >= FAST_STREAM_HZ:
        return FAST_MAVLINK_PROFILE
    return SENSOR_DEFAULTS[family] if family else NavNoise()


class ImuTransition(Transition):
    """IMU mechanisation (module docstring), vectorised over (M, 16) rows; ``F`` the
    analytic tangent Jacobian for the right attitude error (Earth rate's dependence on
    q neglected in F, ~7e-5 rad/s)."""

    space = SPACE

    def __init__(self, noise: NavNoise | None = None, lat: float = 0.0, h: float = 0.0,
                 earth_rate: bool = False) -> None:
        self.noise = noise or NavNoise()
        self.space = nav_space(self.noise)
        self.lat = float(lat)  # rad
        self.g = float(gravity(lat, h))
        self.earth_rate = bool(earth_rate)
        self.w_ie = EARTH_RATE * np.array([np.cos(lat), 0.0, -np.sin(lat)])  # NED
        self._w_ie = read_only(self.w_ie)  # (the compiled kernels' argument)
        self._gyro = GyroTransition()

    def with_noise(self, noise: NavNoise) -> ImuTransition:
        """The same mechanisation (latitude, gravity, Earth rate) with ``noise`` (and
        its state space)."""
        out = copy.copy(self)
        out.noise = noise
        out.space = nav_space(noise)
        return out

    def _rates(self, X: Array, u: Array) -> tuple[Array, Array]:
        w = u[:3] - X[..., 10:13]
        if self.earth_rate:
            w = w - quat_rotate_inv(X[..., :4], self.w_ie)
        return w, u[3:6] - X[..., 13:16]

    def f(self, X: Array, t: float, dt: float, u: Array | None = None) -> Array:
        # (the compiled kernels know the GNSS bias and magnetic reference states, not the
        # gyro drift's: with those, numpy)
        nb = None if self.space.drift else NAV_KERNELS.get()
        return self._nb_f(nb, X, dt, u) if nb else self._np_f(X, t, dt, u)

    def _nb_f(self, nb: Any, X: Array, dt: float, u: Array | None) -> Array:
        """:meth:`f` by the compiled ``mech_rows`` of the kernel module ``nb``."""
        res: Array = nb.mech_rows(read_only(np.atleast_2d(X)), self._u(u), float(dt), self.g,
                                  self._w_ie, self.earth_rate, self._phi(dt),
                                  self.space.extra)
        return res[0] if X.ndim == 1 else res

    @staticmethod
    def _u(u: Array | None) -> Array:
        return read_only(np.zeros(6) if u is None else u)

    def _np_f(self, X: Array, t: float, dt: float, u: Array | None = None) -> Array:
        """:meth:`f` in numpy (the reference of the compiled ``mech_rows``)."""
        u = np.zeros(6) if u is None else np.asarray(u, float)
        one = X.ndim == 1
        X = np.atleast_2d(X)
        w, fb = self._rates(X, u)
        # the specific force rotated with the mid-step attitude (second order in w dt:
        # the first-order form, R(q) at the step's start, leaves a velocity error of
        # |f| |w| dt^2 / 2 per step while the vehicle turns)
        a = quat_rotate(_qstep(X[:, :4], w, 0.5 * dt), fb)
        a[:, 2] += self.g
        out = np.empty_like(X)
        out[:] = X
        out[:, :4] = _qstep(X[:, :4], w, dt)
        out[:, 4:7] = X[:, 4:7] + a * dt
        out[:, 7:10] = X[:, 7:10] + X[:, 4:7] * dt + 0.5 * dt * dt * a
        if self.space.extra:  # the GNSS bias decays towards 0
            out[:, 16:19] = X[:, 16:19] * self._phi(dt)
        if self.space.drift:  # the gyro bias moves at its rate (which is constant)
            out[:, 10:13] = X[:, 10:13] + X[:, self.space.drift_slice] * dt
        return out[0] if one else out  # the magnetic reference's errors: constant

    def _phi(self, dt: float) -> float:
        """The GNSS bias states' decay over ``dt`` s (1 without such states)."""
        if not self.space.extra:
            return 1.0
        return math.exp(-abs(dt) / self.noise.gnss_bias_tau)

    def Q(self, t: float, dt: float, u: Array | None = None) -> Array:
        n, dt = self.noise, abs(dt)
        qa = n.gyro_noise**2 * dt + n.rate_walk**2 * dt**3 / 3.0 + 1e-14
        qv = n.accel_noise**2 * dt + n.accel_walk**2 * dt**3 / 3.0 + 1e-14
        qp = n.accel_noise**2 * dt**3 / 3.0 + 1e-14
        qbg = n.gyro_bias_walk**2 * dt + 1e-16
        qba = n.accel_bias_walk**2 * dt + 1e-16
        size = self.space.dim
        Q = np.zeros((size, size))
        d = Q.reshape(-1)[:: size + 1]  # (its diagonal, a view: filled in place)
        d[0:3], d[3:6], d[6:9], d[9:12], d[12:15] = qa, qv, qp, qbg, qba
        Q[_VP_ROWS, _VP_COLS] = Q[_VP_COLS, _VP_ROWS] = n.accel_noise**2 * dt**2 / 2.0
        if self.space.extra:  # exact first-order Gauss-Markov discretisation
            d[15:18] = n.gnss_bias_sd**2 * (1.0 - self._phi(dt) ** 2) + 1e-14
        if self.space.mag:  # the magnetic reference's random walk (the last two)
            d[-2:] = n.mag_ref_walk**2 * dt + 1e-16
        if self.space.drift:  # the bias's rate a random walk, the bias its integral
            tg = self.space.drift_tangent
            i = np.arange(tg.start, tg.stop)
            qd = n.gyro_drift_walk**2
            d[i] = qd * dt + 1e-18
            d[9:12] += qd * dt**3 / 3.0
            Q[9 + np.arange(3), i] = Q[i, 9 + np.arange(3)] = qd * dt**2 / 2.0
        return Q

    def F(self, x: Array, t: float, dt: float, u: Array | None = None) -> Array:
        nb = None if self.space.drift else NAV_KERNELS.get()
        return self._nb_F(nb, x, dt, u) if nb else self._np_F(x, t, dt, u)

    def _nb_F(self, nb: Any, x: Array, dt: float, u: Array | None) -> Array:
        """:meth:`F` by the compiled ``mech_F`` of the kernel module ``nb``."""
        res: Array = nb.mech_F(read_only(x), self._u(u), float(dt), self._w_ie,
                               self.earth_rate, self._phi(dt), self.space.extra,
                               self.space.dim)
        return res

    def _np_F(self, x: Array, t: float, dt: float, u: Array | None = None) -> Array:
        """:meth:`F` in numpy (the reference of the compiled ``mech_F``)."""
        u = np.zeros(6) if u is None else np.asarray(u, float)
        w, fb = self._rates(x[None], u)
        Fa = self._gyro.F(np.concatenate([x[:4], np.zeros(3)]), t, dt, w[0])
        R = quat_to_dcm(x[:4])
        Rh = quat_to_dcm(_qstep(x[None, :4], w, 0.5 * dt)[0])  # mid-step attitude
        da_dth = -R @ skew(R.T @ Rh @ fb[0])
        F = np.eye(self.space.dim)
        if self.space.extra:
            F[15:18, 15:18] *= self._phi(dt)
        F[0:3, 0:3] = Fa[:3, :3]
        F[0:3, 9:12] = Fa[:3, 3:]
        F[3:6, 0:3] = da_dth * dt
        F[3:6, 12:15] = -Rh * dt
        # the mid-step rotation Exp((u_g - bg) dt / 2) moves with the gyro bias
        da_dbg = Rh @ skew(fb[0]) @ right_jacobian(w[0] * 0.5 * dt) * (0.5 * dt)
        F[3:6, 9:12] = da_dbg * dt
        F[6:9, 3:6] = np.eye(3) * dt
        F[6:9, 0:3] = 0.5 * dt * dt * da_dth
        F[6:9, 9:12] = 0.5 * dt * dt * da_dbg
        F[6:9, 12:15] = -0.5 * dt * dt * Rh
        if self.space.drift:
            F[9:12, self.space.drift_tangent] = np.eye(3) * dt
        return F


def _kernel_cases(nb: Any) -> Iterator[tuple[str, Array, Array]]:
    """The self-check (:mod:`uavest.compiled`): the compiled mechanisation and its
    Jacobian against :meth:`ImuTransition._np_f` / ``_np_F`` on the spaces the runs use
    (15 dimensions; with the GNSS bias states, 18; with the magnetic reference's too, 20),
    with and without the Earth's rate, one row and sigma points, a rotation near zero
    (the series branches), with the argument types the runs pass."""
    u = np.array([0.3, -0.2, 0.5, 0.4, -0.3, -9.6])
    bias = NavNoise(gnss_bias_h=1.0, gnss_bias_v=1.0, gnss_bias_tau=100.0)
    cases = [(NavNoise(), False, u), (bias, True, u),
             (replace(bias, mag_ref_inc=0.01, mag_ref_dec=0.02), False, u),
             (NavNoise(), False, np.array([1e-7, 0.0, 0.0, 0.1, 0.0, -9.8]))]
    for noise, earth, uu in cases:
        tr = ImuTransition(noise, lat=0.8, h=100.0, earth_rate=earth)
        n = tr.space.dim + 1
        rng = np.random.default_rng(n)
        X = rng.normal(0.0, 0.3, (5, n))
        X[:, :4] = np.array([0.9, 0.1, -0.3, 0.2]) + 0.05 * X[:, :4]
        X[:, :4] /= np.linalg.norm(X[:, :4], axis=1)[:, None]
        X[:, 10:13] = uu[:3] if uu[0] < 1e-6 else X[:, 10:13]  # (w - b_g = 0)
        label = f"n={n} earth={earth}"
        for dt in (0.04, -0.005):
            yield (f"mech_rows {label}", tr._nb_f(nb, X, dt, uu), tr._np_f(X, 0.0, dt, uu))
            yield (f"mech_rows one {label}", tr._nb_f(nb, X[0], dt, uu),
                   tr._np_f(X[0], 0.0, dt, uu))
            yield (f"mech_F {label}", tr._nb_F(nb, X[1], dt, uu),
                   tr._np_F(X[1], 0.0, dt, uu))
        # the magnetometer on this state: heading and field, now and ``back`` s before
        # (a field straight down: no heading, H 0)
        for inner in (MagHeading(np.array([0.2, -0.05, 0.4]), np.eye(1)),
                      MagHeading(np.array([0.0, 0.0, 0.4]), np.eye(1)),
                      MagField(np.array([0.5, 0.1, 0.85]), np.eye(3))):
            for back, w in ((0.0, None), (0.02, uu[:3])):
                m = OnNav(inner, back, w)
                got = m._nb_h_H(nb, X[2])
                want = Measurement.h_H(m, X[2])
                name = f"mag_h_H {type(inner).__name__} back={back} {label}"
                yield f"{name} h", got[0], want[0]
                yield f"{name} H", got[1], want[1]
        m = OnNav(MagHeading(np.array([0.2, -0.05, 0.4]), np.eye(1)), 0.02, uu[:3])
        yield f"back_q_rows {label}", nb.back_q_rows(X, m.w, -m.back), m._np_q(X)


#: The compiled IMU mechanisation (:mod:`uavest.models._compiled_nav`)
NAV_KERNELS = register("nav", "uavest.models._compiled_nav",
                       "numba navigation mechanisation kernels", _kernel_cases, rtol=0.0,
                       atol=1e-12)


_ZERO3 = np.zeros(3)

#: the velocity-position covariance's entries of Q (v_i with p_i, i = N, E, D)
_VP_ROWS, _VP_COLS = np.arange(3, 6), np.arange(6, 9)


def _gnss_biased(m: Measurement, size: int) -> bool:
    """A state of ambient ``size`` carries the GNSS bias states (``x[16:19]``, before the
    magnetic reference's errors, of which the model ``m`` is told by its ``space``)."""
    return size - getattr(m.space, "mag", 0) > 16


def _qstep(q: Array, w: Array, dt: float) -> Array:
    from uavest.geometry.rotation import _exp_rows, _normalise_into, _qmul_rows
    out = np.empty_like(q)
    _normalise_into(_qmul_rows(q, _exp_rows(np.ascontiguousarray(w * dt))), out)
    return out


class _Block(Measurement):
    """A measurement that reads one Euclidean block of the nav state linearly."""

    space = SPACE
    linear = False
    _sl: slice
    _sign = 1.0
    _offset = 0.0

    def __init__(self, R: Array, rows: tuple[int, ...] = (0, 1, 2)) -> None:
        self.rows = tuple(rows)
        self.R = np.asarray(R, float)
        idx = np.arange(self._sl.start, self._sl.stop)[list(self.rows)]
        self._idx = idx
        self._H = np.zeros((len(idx), 15))
        self._H[np.arange(len(idx)), idx - 1] = self._sign

    def h(self, X: Array) -> Array:
        return self._sign * X[..., self._idx] + self._offset

    def _H_for(self, size: int) -> Array:
        """``_H`` (m, 15) padded with zero columns to a state of ambient ``size``."""
        if size <= 16:
            return self._H
        return np.pad(self._H, ((0, 0), (0, size - 16)))

    def H(self, x: Array) -> Array:
        return self._H_for(x.shape[-1])

    def H_rows(self, X: Array) -> Array:
        H = self._H_for(X.shape[-1])
        return np.broadcast_to(H, (X.shape[0],) + H.shape)


class _Carried(_Block):
    """A block measured before the state's time and carried to it by the state:
    ``h = x_block + cv v + ca (R(q) (f - b_a) + (0, 0, g))`` with ``f`` a specific force
    (m/s^2, body FRD at the state's time) and ``g`` (m/s^2); without ``f`` (or with both
    coefficients 0) the plain block."""

    def __init__(self, R: Array, rows: tuple[int, ...], f: Array | None, g: float,
                 cv: float, ca: float) -> None:
        super().__init__(R, rows)
        self.f = None if f is None else np.asarray(f, float)
        self.g = float(g)
        self._cv, self._ca = float(cv), float(ca)
        self._carried = self.f is not None and bool(cv or ca)

    def h(self, X: Array) -> Array:
        if not self._carried:
            return super().h(X)
        assert self.f is not None
        a = quat_rotate(X[..., :4], self.f - X[..., 13:16])
        a[..., 2] += self.g
        y = X[..., self._sl] + self._cv * X[..., 4:7] + self._ca * a
        return y[..., list(self.rows)]

    def H(self, x: Array) -> Array:
        if not self._carried:
            return self._H_for(x.shape[-1])
        return self.H_rows(x[None, :])[0]

    def h_H(self, x: Array) -> tuple[Array, Array]:
        """(h, H) of one state (the EKF's update) on Python floats: the formulas of
        :meth:`h` and :meth:`H_rows`, which stay the reference, without numpy's per-call
        floor (their 15 calls were 240 us of a GNSS update)."""
        if not self._carried or x.ndim != 1:
            return super().h_H(x)
        assert self.f is not None
        xs = x.tolist()
        R = dcm_f(xs[:4])
        f = self.f.tolist()
        fb = (f[0] - xs[13], f[1] - xs[14], f[2] - xs[15])
        cv, ca, s0 = self._cv, self._ca, self._sl.start
        H = np.zeros((3, x.shape[0] - 1))
        y = []
        for i, (r0, r1, r2) in enumerate(R):
            a = r0 * fb[0] + r1 * fb[1] + r2 * fb[2] + (self.g if i == 2 else 0.0)
            y.append(xs[s0 + i] + cv * xs[4 + i] + ca * a)
            row = H[i]
            row[s0 - 1 + i] = 1.0
            row[3 + i] += cv
            # -ca R skew(fb), and -ca R for the accelerometer bias
            row[0:3] = (-ca * (r1 * fb[2] - r2 * fb[1]), -ca * (r2 * fb[0] - r0 * fb[2]),
                        -ca * (r0 * fb[1] - r1 * fb[0]))
            row[12:15] = (-ca * r0, -ca * r1, -ca * r2)
        rows = list(self.rows)
        return np.array(y)[rows], H[rows]

    def H_rows(self, X: Array) -> Array:
        """Jacobians (M, m, 15) at every row of ``X`` (M, 16), vectorised (more columns,
        zero, for a state with more components)."""
        if not self._carried:
            return super().H_rows(X)
        assert self.f is not None
        R = quat_to_dcm(X[:, :4])  # (M, 3, 3)
        H = np.zeros((X.shape[0], 3, X.shape[1] - 1))
        H[:, :, self._sl.start - 1:self._sl.stop - 1] = np.eye(3)
        H[:, :, 3:6] += self._cv * np.eye(3)
        H[:, :, 0:3] = -self._ca * R @ skew(self.f - X[:, 13:16])
        H[:, :, 12:15] = -self._ca * R
        return H[:, list(self.rows)]


class GnssPosition(_Carried):
    """GNSS position in NED, m (from lat/lon/alt through the LocalFrame). ``rows``
    (0, 1) for a 2-D fix (horizontal only). R from the receiver's eph/epv (or h_acc /
    v_acc) with the floors of :class:`NavNoise` (:meth:`from_fix`).

    ``back`` (s) and ``k`` (s^2): the fix is of the position ``back`` before the state's
    time, carried by the state: ``h = p - back v + k (R(q) (f - b_a) + (0, 0, g))``, with
    ``k f`` the specific force (m/s^2, body FRD at the state's time) weighted by the time
    since the fix over those ``back`` s (``k = back^2 / 2``;
    :func:`uavest.engine.nav_aiding.carry_force`). Without ``f`` the position is taken at
    the state's time (the stream carries it with the fix's velocity)."""

    _sl = slice(7, 10)

    def __init__(self, R: Array, rows: tuple[int, ...] = (0, 1, 2), back: float = 0.0,
                 k: float = 0.0, f: Array | None = None, g: float = 0.0,
                 biased: bool = True) -> None:
        self.back = float(back) if f is not None else 0.0
        self.k = float(k)
        #: on a state with the GNSS bias states (size 19) the fix is of ``p + bp``
        #: (False: of ``p`` alone, as the unaided run's constant-position hold)
        self.biased = bool(biased)
        super().__init__(R, rows, f, g, -self.back, self.k if self.back else 0.0)

    def h(self, X: Array) -> Array:
        y = super().h(X)
        if self._bias(X):
            y = y + X[..., 16:19][..., list(self.rows)]
        return y

    def _bias(self, X: Array) -> bool:
        return self.biased and _gnss_biased(self, X.shape[-1])

    def H(self, x: Array) -> Array:
        return self.H_rows(x[None, :])[0] if self._bias(x) else super().H(x)

    def h_H(self, x: Array) -> tuple[Array, Array]:
        y, H = super().h_H(x)
        if self._bias(x) and self._carried and x.ndim == 1:  # (else h and H have it)
            rows = list(self.rows)
            y = y + x[16:19][rows]
            H[np.arange(len(rows)), 15 + np.array(rows)] = 1.0
        return y, H

    def H_rows(self, X: Array) -> Array:
        H = super().H_rows(X)
        if self._bias(X):
            H = np.array(H)
            H[:, np.arange(len(self.rows)), 15 + np.array(self.rows)] = 1.0
        return H

    @staticmethod
    def from_fix(ned: Array, fix_type: int, h_acc: float | None, v_acc: float | None,
                 noise: NavNoise, carry: tuple[float, float, Array, float] | None = None
                 ) -> tuple[Array, GnssPosition] | None:
        """(z, model) for one fix, or None when the fix type is < 2 or a value is not
        finite (no position update below a 2-D fix; 2-D: horizontal only). ``carry``:
        (back s, k s^2, f m/s^2, g m/s^2) of a fix carried by the state (class doc)."""
        ned = np.asarray(ned, float)
        if fix_type < 2 or not np.all(np.isfinite(ned[:2])):
            return None
        sh, sv = noise.gnss_pos_sd(h_acc, v_acc)
        kw: dict[str, Any] = {}
        if carry is not None:
            kw = dict(zip(("back", "k", "f", "g"), carry, strict=True))
        if fix_type == 2 or not np.isfinite(ned[2]):
            return ned[:2], GnssPosition(np.diag([sh**2, sh**2]), rows=(0, 1), **kw)
        return ned, GnssPosition(np.diag([sh**2, sh**2, sv**2]), **kw)


class GnssVelocity(_Carried):
    """GNSS velocity in NED, m/s (or ``rows=(0, 1)`` from ground speed and course).

    ``back`` (s): the fix measures the velocity that long before the state's time (the
    step ends after the fix): ``h = v - back (R(q) (f - b_a) + (0, 0, g))`` with ``f``
    the step's mean specific force (m/s^2, body FRD) and ``g`` (m/s^2), so that a 25 Hz
    step does not apply a fix up to 40 ms late."""

    _sl = slice(4, 7)

    def __init__(self, R: Array, rows: tuple[int, ...] = (0, 1, 2), back: float = 0.0,
                 f: Array | None = None, g: float = 0.0) -> None:
        self.back = float(back) if f is not None else 0.0
        super().__init__(R, rows, f, g, 0.0, -self.back)


class BaroHeight(_Block):
    """Barometric height up, m: h = -p_D + offset. The offset (baro height minus the
    GNSS/initial height) is estimated once at start-up and held fixed; it is not a
    state, so baro drift shows up as a height error the GNSS corrects. On a state with
    the GNSS bias states the offset, taken against the GNSS's heights, carries the
    receiver's vertical bias: h = -(p_D + bp_D) + offset."""

    _sl = slice(7, 10)
    _sign = -1.0

    def __init__(self, R: Array, offset: float = 0.0, back: float = 0.0) -> None:
        self._offset = float(offset)
        super().__init__(R, rows=(2,))
        #: s: the sample is that much older than the state: h = -(p_D - back v_D) + offset
        self.back = float(back)
        if self.back:
            self._H = self._H.copy()
            self._H[0, 5] = self.back

    def h(self, X: Array) -> Array:
        y = -(X[..., 9:10] - self.back * X[..., 6:7]) + self._offset
        if _gnss_biased(self, X.shape[-1]):  # the offset is to the GNSS height: its bias
            y = y - X[..., 18:19]
        return y

    def _H_for(self, size: int) -> Array:
        H = super()._H_for(size)
        if _gnss_biased(self, size):
            H = H.copy()
            H[0, 17] = -1.0
        return H


class OnNav(Measurement):
    """An attitude measurement (MagHeading, MagField, GravityDirection: reading only
    q) on the navigation state: same h, residual and mean; H padded to 15 columns.

    ``back`` (s) with ``w`` (the step's mean gyro rate, rad/s, body FRD): the sample
    measured the attitude that long before the state's time, ``q Exp(-(w - b_g) back)``
    (a magnetometer sample older than the step that carries it)."""

    space = SPACE

    def __init__(self, inner: Measurement, back: float = 0.0, w: Array | None = None
                 ) -> None:
        self.inner = inner
        self.R = inner.R
        self.back = float(back) if w is not None else 0.0
        self.w = None if w is None else np.asarray(w, float)

    def _q(self, X: Array) -> Array:
        q = X[..., :4]
        if not self.back:
            return q
        assert self.w is not None
        if X.ndim == 2:  # members or sigma points: the compiled rows when in use
            nb = NAV_KERNELS.get()
            if nb:
                res: Array = nb.back_q_rows(X, self.w, -self.back)
                return res
        return self._np_q(X)

    def _np_q(self, X: Array) -> Array:
        """:meth:`_q` on numpy (the compiled rows' reference)."""
        assert self.w is not None
        q = X[..., :4]
        one = q.ndim == 1
        Q2 = np.atleast_2d(q)
        wb = self.w - np.atleast_2d(X[..., 10:13])
        out = _qstep(Q2, wb, -self.back)
        return out[0] if one else out

    def h(self, X: Array) -> Array:
        return self.inner.h(self._q(X))

    def h_H(self, x: Array) -> tuple[Array, Array]:
        """(h, H) of one state; the compiled ``mag_h_H`` for a magnetometer's heading or
        field (the EKF's update; the numpy h and H are its reference)."""
        nb = NAV_KERNELS.get() if type(self) is OnNav else None
        if nb and type(self.inner) in (MagHeading, MagField):
            return self._nb_h_H(nb, x)
        return super().h_H(x)

    def _nb_h_H(self, nb: Any, x: Array) -> tuple[Array, Array]:
        heading = type(self.inner) is MagHeading
        vec = self.inner.field if heading else self.inner.ref  # type: ignore[attr-defined]
        w = _ZERO3 if self.w is None else self.w
        res: tuple[Array, Array] = nb.mag_h_H(read_only(x), read_only(vec), read_only(w),
                                              self.back, heading)
        return res

    def H(self, x: Array) -> Array:
        qb = self._q(x)
        Ha = self.inner.H(np.concatenate([qb, np.zeros(3)]))
        H = np.zeros((Ha.shape[0], x.shape[-1] - 1))
        H[:, :3] = Ha[:, :3]
        if self.back:
            # q Exp(d) Exp(-phi) = q Exp(-phi) Exp(Exp(phi) d), phi = (w - b_g) back
            assert self.w is not None
            phi = (self.w - x[10:13]) * self.back
            Hq = H[:, :3].copy()
            H[:, :3] = Hq @ quat_to_dcm(quat_exp(phi))
            # and the gyro bias: Exp(-phi + back d) = Exp(-phi) Exp(J_r(-phi) back d)
            H[:, 9:12] = Hq @ right_jacobian(-phi) * self.back
        return H

    def residual(self, a: Array, b: Array) -> Array:
        return self.inner.residual(a, b)

    def mean(self, Y: Array, w: Array) -> Array:
        return self.inner.mean(Y, w)

    def arithmetic(self) -> str | None:
        return self.inner.arithmetic()


def innovation_gate(nu: Array, S: Array, chi2: float) -> bool:
    """True when the innovation ``nu`` with covariance ``S`` passes the chi-square gate
    ``nu^T S^-1 nu <= chi2`` (a 100 m GNSS jump fails it; callers count rejections)."""
    d2 = float(nu @ np.linalg.solve(S, nu))
    return bool(np.isfinite(d2) and d2 <= chi2)


class MagFieldRef(OnNav):
    """The magnetometer's 3-D field direction (:class:`~uavest.models.attitude.MagField`
    on the navigation state, as :class:`OnNav`) against a reference field whose
    inclination and declination errors are states (``x[space.mag_slice]``, rad,
    :attr:`NavNoise.mag_ref`): ``h = R(q_b)^T m(I + dI, D + dD)``, ``m(I, D) = (cos I cos
    D, cos I sin D, sin I)`` NED, ``q_b`` the attitude ``back`` s before the state's time.
    ``ref``: the unit reference field (NED) the errors are relative to."""

    def __init__(self, ref: Array, R: Array, space: NavSpace, back: float = 0.0,
                 w: Array | None = None) -> None:
        ref = np.asarray(ref, float)
        super().__init__(MagField(ref, R), back, w)
        self.space = space
        self.inc, self.dec = reference_inclination(ref), reference_declination(ref)

    def _angles(self, X: Array) -> tuple[Array, Array]:
        e = X[..., self.space.mag_slice]
        return self.inc + e[..., 0], self.dec + e[..., 1]

    def _m(self, X: Array) -> Array:
        """The reference field (unit, NED) of each row of ``X``."""
        inc, dec = self._angles(X)
        return mag_reference(dec, inc)

    def h(self, X: Array) -> Array:
        res: Array = quat_rotate_inv(self._q(X), self._m(X))
        return res

    def H(self, x: Array) -> Array:
        m = self._m(x)
        H = OnNav(MagField(m, self.R), self.back, self.w).H(x)
        inc, dec = self._angles(x)
        si, ci, sd, cd = np.sin(inc), np.cos(inc), np.sin(dec), np.cos(dec)
        dm = np.array([[-si * cd, -ci * sd], [-si * sd, ci * cd], [ci, 0.0]])  # d m / d(I, D)
        Rb = quat_to_dcm(self._q(x))
        k = self.space.dim - self.space.mag
        H[:, k:k + 2] = Rb.T @ dm
        return H
