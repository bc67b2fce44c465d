"""The navigation stream's aiding queues: GNSS, magnetometer and barometer samples
validated, stamped with their effective time (the sample's time less its delay) and
held until the step they belong to is released (:class:`~uavest.engine.navigation.NavStream`).

:class:`AidQueues` chooses the GNSS receiver and the barometer (the option, else the
first receiver with a 3-D fix / the first barometer), counts per sensor what it used and
skipped (``counts``: ``no_fix``, ``nan``, ``fix_2d``, ``held``, ``late``, ...; the
stream's ``summary["aiding"]``), and keeps the barometer's offset to the GNSS height. It
makes no decisions itself: its methods say when a choice was made and the stream
records it. Its state is part of the stream's snapshot (:meth:`AidQueues.snapshot`)."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry.geodesy import LocalFrame, SphereFrame
from ..geometry.rotation import quat_exp, quat_mul, quat_rotate_inv
from ..ingest.types import BaroSample, GnssSample, MagSample
from ..models.attitude import MagField, MagHeading
from ..models.navigation import (
    BaroHeight,
    GnssPosition,
    GnssVelocity,
    MagFieldRef,
    NavNoise,
    OnNav,
)
from .attitude import DEFAULT_MAX_RATE_HZ
from .history import restore_vars, snapshot_vars

Array = np.ndarray

#: Pairs of (baro, GNSS) heights the baro offset averages over (then its memory).
BARO_OFFSET_PAIRS = 200
#: Magnetometer updates at most this often (s): the attitude path's reference rate
#: (``mag_noise`` describes one update per reference step; a 200 Hz magnetometer at
#: ``--rate 0`` would otherwise carry 8 times the information and pull the tilt).
MAG_MIN_INTERVAL_S = 1.0 / DEFAULT_MAX_RATE_HZ - 1e-6
#: A magnetometer field equal to the last new one is that reading held (MAVLink's IMU
#: messages repeat the last compass value between its updates, 10 Hz on ArduPilot) for
#: this long (s); after it, the same field is read again: a vehicle at rest with a
#: noise-free magnetometer (the ArduCopter SITL's) reads the same field for minutes, and
#: taken as held it left yaw without its magnetometer on the ground (sigma 15-21 deg
#: before takeoff, 3.5 deg of drift in 50 s after landing).
MAG_HOLD_MAX_S = 0.5


def finite3(*vs: Any) -> bool:
    """Whether every component of the 3-vectors ``vs`` is finite, on Python floats (the
    streams check every IMU and magnetometer sample: numpy's per-call cost made this a
    tenth of a navigation replay's stream work; an array's components taken by
    ``tolist``, a third of the time of unpacking it into numpy scalars)."""
    for v in vs:
        x, y, z = v.tolist() if type(v) is np.ndarray else v
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            return False
    return True


@dataclass
class NewReadings:
    """Tells new magnetometer readings from held ones (:data:`MAG_HOLD_MAX_S`): the one
    rule of the navigation stream's aiding and the replay's delay probe. A mutable
    dataclass, so that the history's snapshots copy it (:mod:`uavest.engine.history`)."""

    last: Array | None = None  # the last new field
    t_last: float = -np.inf  # s, its time

    def new(self, t: float, field: Array) -> bool:
        """Whether ``field`` at ``t`` (s) is a new reading (and then remember it)."""
        if (self.last is not None and t - self.t_last < MAG_HOLD_MAX_S
                and np.shape(field) == np.shape(self.last)
                and np.asarray(field).tolist() == np.asarray(self.last).tolist()):
            return False
        self.last, self.t_last = field, float(t)
        return True


def baro_height(s: BaroSample) -> float:
    """Height up (m) of a barometer sample: the logged pressure altitude when there is
    one, else the ISA barometric formula from the pressure (Pa); NaN if neither is
    usable. Only differences matter (the offset to the GNSS height is estimated)."""
    if np.isfinite(s.alt):
        return float(s.alt)
    p = float(s.pressure)
    if not (np.isfinite(p) and 1.0e3 < p < 2.0e5):
        return float("nan")
    return float(44330.77 * (1.0 - (p / 101325.0) ** 0.190263))


@dataclass
class _Aid:
    """One validated aiding sample waiting for its step: effective time ``t`` (s, the
    stamp minus the delay), ``sensor`` name and its payload."""

    t: float
    sensor: str
    gnss: GnssSample | None = None
    ned: Array | None = None
    height: float = float("nan")
    vec: Array | None = None  # a magnetometer sample's field (gauss, body FRD)
    #: a fix's velocity window (s, NavNoise.gnss_vel_window): ``t`` is its end, its
    #: centre (the time the position is of) ``t - span / 2``
    span: float = 0.0


Steps = list[tuple[float, float, Array, Array]]


def _weighted_force(steps: Steps, t_end: float, W: Any, total: float) -> Array:
    """The specific force (m/s^2, body FRD at ``t_end``) of ``steps`` (each ``(end s,
    length s, rate rad/s, mean specific force m/s^2)``, oldest first, the last ending at
    ``t_end``) weighted by ``w``, ``W`` its integral from -inf (``W(tau)`` = 0 before the
    weighted span), divided by ``total`` (the integral of ``w`` up to ``t_end``); each
    step's force turned into the body frame at ``t_end`` with the gyro (its bias
    neglected). A span reaching before the first step takes the first step's force for
    the part it lacks."""
    acc = np.zeros(3)
    q = np.array([1.0, 0.0, 0.0, 0.0])  # body at a step's end -> body at t_end
    covered = 0.0
    for end, dt, w, f in reversed(steps):
        wt = W(min(end, t_end)) - W(end - dt)
        if wt > 0:
            q_mid = quat_mul(quat_exp(0.5 * dt * np.asarray(w, float)), q)
            acc += wt * quat_rotate_inv(q_mid, np.asarray(f, float))
            covered += wt
        if W(end - dt) <= 0:
            break
        q = quat_mul(quat_exp(dt * np.asarray(w, float)), q)
    if covered < total:
        acc += (total - covered) * quat_rotate_inv(q, np.asarray(steps[0][3], float))
    return acc / total


def window_force(steps: Steps, t_end: float, center: float, span: float
                 ) -> tuple[float, Array]:
    """(``back`` s, ``f`` m/s^2 body FRD at ``t_end``) such that the velocity a fix
    measures, the mean over ``[center - span / 2, center + span / 2]`` (s), is
    ``v(t_end) - back (R(q) (f - b_a) + (0, 0, g))`` (:class:`GnssVelocity`), with ``q``
    and ``v`` the state at ``t_end``.

    ``steps``: the steps up to the one ending at ``t_end`` (:func:`_weighted_force`).
    The mean over the window of ``v(t_end) - v(s)`` is the integral of the NED
    acceleration ``a(tau)`` weighted by ``w(tau) = clip((tau - w0) / span, 0, 1)``,
    ``w0 = center - span / 2``; so ``back`` is the integral of ``w`` up to ``t_end``
    (``t_end - center``) and ``f`` the specific force weighted by ``w``."""
    w0 = center - 0.5 * span

    def W(tau: float) -> float:
        x = tau - w0
        if x <= 0:
            return 0.0
        return 0.5 * x * x / span if x <= span else x - 0.5 * span

    back = t_end - center
    if not back > 0:
        return back, np.asarray(steps[-1][3], float)
    return back, _weighted_force(steps, t_end, W, back)


def carry_force(steps: Steps, t_end: float, t_fix: float) -> tuple[float, float, Array]:
    """(``back`` s, ``k`` s^2, ``f`` m/s^2 body FRD at ``t_end``) carrying a position of
    ``t_fix`` (s) to ``t_end`` by the state (:class:`GnssPosition`): ``p(t_fix) = p(t_end)
    - back v(t_end) + k a``, with ``k f`` the integral of the specific force weighted by
    ``tau - t_fix`` from ``t_fix`` to ``t_end``, ``k = back^2 / 2``."""
    back = t_end - t_fix

    def W(tau: float) -> float:
        x = tau - t_fix
        return 0.5 * x * x if x > 0 else 0.0

    k = 0.5 * back * back
    if not back > 0:
        return back, k, np.asarray(steps[-1][3], float)
    return back, k, _weighted_force(steps, t_end, W, k)


def good_fix(aids: list[_Aid]) -> _Aid | None:
    """The last good fix of ``aids`` (3-D, finite position and horizontal velocity)."""
    for a in reversed(aids):
        g = a.gnss
        if (g is not None and a.ned is not None and g.fix_type >= 3
                and np.isfinite(a.ned).all() and np.isfinite(g.vel_ned[:2]).all()):
            return a
    return None


class AidQueues:
    """The aids waiting for their steps, one queue per sensor (each in time order), the
    chosen GNSS receiver and barometer (``gnss``, ``baro``: None until chosen), the
    samples seen per source, the per-sensor counts and the baro offset (module
    docstring)."""

    def __init__(self, gnss: str | None = None, baro: str | None = None) -> None:
        self.gnss = gnss
        self.baro = baro
        self.queues: dict[str, deque[_Aid]] = {"gnss": deque(), "baro": deque(),
                                               "mag": deque()}
        self.mag_new = NewReadings()  # the magnetometer fields queued
        self.gnss_srcs: dict[str, int] = {}
        self.baro_srcs: dict[str, int] = {}
        self.baro_offset: float | None = None
        self.off_n = 0  # (baro, GNSS) height pairs seen
        self.h_fix: tuple[float, float] | None = None  # last GNSS (t s, height up m)
        self.t_mag = -np.inf  # time of the last magnetometer update
        self.counts: dict[str, dict[str, int]] = {}

    def snapshot(self) -> dict[str, Any]:
        """This moment, for :meth:`restore` (:mod:`uavest.engine.history`)."""
        return snapshot_vars(self)

    def restore(self, snap: dict[str, Any]) -> None:
        restore_vars(self, snap)

    def count(self, sensor: str, what: str) -> None:
        """One more ``what`` for ``sensor``."""
        d = self.counts.setdefault(sensor, {})
        d[what] = d.get(what, 0) + 1

    def seen(self, s: Any) -> None:
        """Count a GNSS or barometer sample's source (every one, chosen or not)."""
        if isinstance(s, GnssSample):
            self.gnss_srcs[s.source] = self.gnss_srcs.get(s.source, 0) + 1
        elif isinstance(s, BaroSample):
            self.baro_srcs[s.source] = self.baro_srcs.get(s.source, 0) + 1

    # ------------------------------------------------------------------ GNSS
    def choose_gnss(self, s: GnssSample) -> bool:
        """True when ``s`` makes its receiver the GNSS source (none chosen yet, a 3-D
        fix)."""
        if self.gnss is None and s.fix_type >= 3:
            self.gnss = s.source
            return True
        return False

    def gnss_lla(self, s: GnssSample) -> Array | None:
        """(lat deg, lon deg, alt m) of a fix of the chosen receiver with a valid
        horizontal position (counted: ``no_fix``, ``nan``, ``fix_2d``), else None."""
        if self.gnss is None or s.source != self.gnss:
            return None
        if s.fix_type < 2:
            self.count("gnss", "no_fix")
            return None
        lla = np.asarray(s.lat_lon_alt, float)
        if not np.isfinite(lla[:2]).all() or abs(lla[0]) > 90 or abs(lla[1]) > 180:
            self.count("gnss", "nan")
            return None
        if s.fix_type == 2:
            self.count("gnss", "fix_2d")
        return lla

    def add_gnss(self, s: GnssSample, lla: Array, frame: LocalFrame | SphereFrame,
                 delay: float, window: float = 0.0) -> None:
        """Queue the fix ``s`` (``lla`` from :meth:`gnss_lla`) at its time less ``delay``
        (s) plus half its velocity ``window`` (s: the step that takes it holds the end of
        the window its velocity is the mean over), its position NED in ``frame`` (no
        height for a 2-D fix)."""
        alt = lla[2] if np.isfinite(lla[2]) else frame.h0
        ned = np.asarray(frame.geodetic_to_ned(np.array(lla[0]), np.array(lla[1]),
                                               np.array(alt)), dtype=float)
        if s.fix_type == 2 or not np.isfinite(lla[2]):
            ned[2] = np.nan
        self.queues["gnss"].append(_Aid(s.t - delay + 0.5 * window, "gnss", gnss=s,
                                        ned=ned, span=window))

    # ------------------------------------------------------------------ magnetometer
    def add_mag(self, s: MagSample, delay: float) -> None:
        """Queue a magnetometer sample as an aid at its time less the magnetometer delay
        (s), when it is a new reading (:class:`NewReadings`: a field equal to the previous
        one within :data:`MAG_HOLD_MAX_S` is the same reading held; MAVLink's IMU messages
        repeat the last compass value, the ArduCopter SITL's changes 10 times a second in
        a 200 Hz RAW_IMU), not a new measurement."""
        f = np.asarray(s.field, float)
        if not (finite3(f) and any(f.tolist())):
            return
        if not self.mag_new.new(s.t, f):
            self.count("mag", "held")
            return
        self.queues["mag"].append(_Aid(s.t - delay, "mag", vec=f))

    # ------------------------------------------------------------------ barometer
    def choose_baro(self, s: BaroSample) -> bool:
        """True when ``s`` makes its sensor the barometer (none chosen yet)."""
        if self.baro is None:
            self.baro = s.source
            return True
        return False

    def add_baro(self, s: BaroSample, delay: float) -> None:
        """Queue a sample of the chosen barometer at its time less ``delay`` (s), its
        height (:func:`baro_height`; NaN counted, not queued)."""
        if s.source != self.baro:
            return
        h = baro_height(s)
        if not np.isfinite(h):
            self.count("baro", "nan")
            return
        self.queues["baro"].append(_Aid(s.t - delay, "baro", height=h))

    def offset_pair(self, d: float) -> bool:
        """One (baro height - GNSS height) pair (m): the offset is their running mean
        over the first :data:`BARO_OFFSET_PAIRS` pairs, then an exponential mean with
        that many pairs' memory (slow baro drift follows the GNSS height). True for the
        first pair (the offset starts)."""
        self.off_n += 1
        if self.baro_offset is None:
            self.baro_offset = d
            return True
        a = 1.0 / min(self.off_n, BARO_OFFSET_PAIRS)
        self.baro_offset += a * (d - self.baro_offset)
        return False

    def gnss_updates(self, fix: _Aid, back: float, f: Array, g: float, noise: NavNoise,
                     ups: list[tuple[Array, Any]], sensors: list[str],
                     carry: tuple[float, float, Array] | None = None,
                     timing_sd: Array | None = None) -> None:
        """Append the updates of a fix taken by a step (counted ``used``) to ``ups`` and
        their names to ``sensors``: the velocity (:class:`GnssVelocity`, std
        max(s_acc, floor), with ``timing_sd`` (m/s per NED axis: the receiver's timing not
        known) added in quadrature; horizontal only without a vertical speed; NaN counted
        ``vel_nan``) ``back`` s before the step's end (the specific force ``f`` m/s^2
        and gravity ``g`` carry it there), the position carried to the step's end with
        the fix's velocity (:meth:`GnssPosition.from_fix`); the fix's height is kept
        for the baro offset (``h_fix``). ``carry`` (back s, k s^2, f m/s^2,
        :func:`carry_force`): the position is carried by the state instead
        (:class:`GnssPosition`; a fix with a velocity window)."""
        gs, n = fix.gnss, noise
        assert gs is not None and fix.ned is not None
        v = np.asarray(gs.vel_ned, float)
        if np.isfinite(v[:2]).all():
            sv = max(n.gnss_vel_floor, gs.s_acc if np.isfinite(gs.s_acc) else 0.0)
            rows = (0, 1, 2) if np.isfinite(v[2]) else (0, 1)
            var = np.full(len(rows), sv * sv)
            if timing_sd is not None:
                var = var + np.asarray(timing_sd, float)[list(rows)] ** 2
            ups.append((v[list(rows)], GnssVelocity(np.diag(var), rows, back=back, f=f, g=g)))
            sensors.append("gnss_vel")
            vx = np.where(np.isfinite(v), v, 0.0)
        else:
            self.count("gnss", "vel_nan")
            vx = np.zeros(3)
        ned = fix.ned + vx * back if carry is None else fix.ned
        if np.isfinite(fix.ned[2]):  # the GNSS height (up, m) for the baro offset
            self.h_fix = (fix.t - 0.5 * fix.span, -float(fix.ned[2]))
        pf = GnssPosition.from_fix(ned, 3 if np.isfinite(ned[2]) else 2,
                                   gs.h_acc, gs.v_acc, n,
                                   None if carry is None else (*carry, g))
        if pf is not None:
            ups.append(pf)
            sensors.append("gnss_pos")
        self.count("gnss", "used")

    def baro_updates(self, baro: _Aid, stamp: float, noise: NavNoise,
                     ups: list[tuple[Array, Any]], sensors: list[str]) -> None:
        """Append the height update of a baro aid taken by the step ending at ``stamp``
        (s) to ``ups`` (counted ``used``), once the offset has started."""
        if self.baro_offset is not None:
            ups.append((np.array([baro.height]),
                        BaroHeight(np.array([[noise.baro_noise**2]]), self.baro_offset,
                                   back=stamp - baro.t)))
            sensors.append("baro")
            self.count("baro", "used")

    def mag_updates(self, mag: _Aid, stamp: float, w: Array, mref: Array | None,
                    declination: float, noise: NavNoise, ups: list[tuple[Array, Any]],
                    sensors: list[str], heading_scale: float = 1.0,
                    space: Any = None) -> None:
        """Append the update of a magnetometer aid taken by the step ending at ``stamp``
        (s) with the rate ``w`` (rad/s) to ``ups`` (counted ``used``), at most every
        :data:`MAG_MIN_INTERVAL_S`: the 3-D field direction against the unit reference
        ``mref`` (NED), or without one the heading against ``declination`` (rad), its
        std ``mag_noise`` times ``heading_scale`` (the field's direction noise seen in its
        horizontal part: :func:`~uavest.engine.nav_align.heading_noise_scale`). On a
        ``space`` with the magnetic reference states the field is against ``mref`` with
        their errors (:class:`~uavest.models.navigation.MagFieldRef`)."""
        if mag.vec is None or mag.t - self.t_mag < MAG_MIN_INTERVAL_S:
            return
        self.t_mag = mag.t
        f, n = mag.vec, noise
        back = stamp - mag.t  # s the sample is older than the step (< 0: newer)
        if mref is not None and space is not None and space.mag:
            ups.append((f / np.linalg.norm(f), MagFieldRef(
                mref, np.eye(3) * n.mag_noise**2, space, back, w)))
        elif mref is not None:
            ups.append((f / np.linalg.norm(f), OnNav(
                MagField(mref, np.eye(3) * n.mag_noise**2), back, w)))
        else:
            ups.append((np.array([declination]), OnNav(
                MagHeading(f, np.array([[(n.mag_noise * heading_scale)**2]])), back, w)))
        sensors.append("mag")
        self.count("mag", "used")

    # ------------------------------------------------------------------ release
    def take(self, upto: float, t_out: float | None) -> list[_Aid]:
        """The aids at or before ``upto`` (s), each sensor's in time order; those at or
        before ``t_out`` (the end of the last released step) are late: counted and
        dropped."""
        aids = []
        for q in self.queues.values():
            while q and q[0].t <= upto:
                a = q.popleft()
                if t_out is not None and a.t <= t_out:
                    self.count(a.sensor, "late")
                    continue
                aids.append(a)
        return aids
