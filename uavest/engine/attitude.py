"""Attitude from an IMU stream: typed samples in, filter steps out, one sample at a time.

:class:`AttitudeStream` turns a time-ordered stream of :mod:`uavest.ingest` samples (from
a log file or a live link) into a :class:`~uavest.engine.records.Start` and then
:class:`~uavest.engine.records.Step` s for the attitude filters of
:mod:`uavest.models.attitude`. Everything is incremental; memory is bounded by the
alignment window.

**Alignment** (the first ``align_s`` = 1 s of IMU data, as an autopilot aligns before it
flies): the samples of that window are held to choose the IMU source (most samples; within
2 % of the best the primary source by preference, as :func:`uavest.ingest.read_log`
does), the IMU rate and so the integration and the pre-integration factor, the
magnetometer source, the velocity source for accelerometer compensation, the magnetic
inclination (median angle between field and gravity over the window) and the prior
(roll/pitch from the first accelerometer sample, yaw from the magnetometer sample at or
before it, else the first one of the window). The held samples are then replayed through
the step builder, so no sample is lost.

**Steps.** A step k covers (t_{k-1}, t_k]; it predicts with the gyro over that interval
and updates with the accelerometer (mean specific force of the step, as gravity
direction, compensated by the vehicle's acceleration when a velocity source exists) and
the latest magnetometer sample of the step, stacked in one update. Two ways of turning
gyro samples into the step's rate, chosen by ``integration``:

* ``"hold"``: each sample is the mean rate over the interval ending at it (integrated
  IMUs: PX4 ``sensor_combined``, DataFlash ``IMT``); consecutive samples are
  pre-integrated exactly (product of their rotations) when the filter runs slower than
  the IMU (``rate_hz``).
* ``"trapezoid"``: samples are instantaneous rates (MAVLink ``RAW_IMU`` streamed at a
  few Hz; DataFlash ``IMU``, snapshots of the filtered gyro at the logging rate): each
  interval between samples uses the mean of the rates at its ends, pre-integrated the
  same way when a step holds several samples.

``"auto"`` picks by what the IMU message is (:mod:`uavest.ingest.semantics`, printed
with the reason), and for an unknown message trapezoid below 20 Hz, else hold.
``rate_hz`` (default :data:`DEFAULT_MAX_RATE_HZ`) caps the filter rate; ``rate_hz = 0``
runs at the IMU rate.
A step is closed when the first sample later than its end arrives (a magnetometer sample
with the same time stamp as the step's last IMU sample still belongs to it); with
``on_arrival`` (a live link releasing samples as they arrive, run with the engine's
history, :mod:`uavest.engine.history`) at the IMU sample that ends it, the link having
released the other items of that message before it: a sample of the step's time or older
that comes later is late and the history applies it.

Vehicle acceleration (NED, m/s^2) at a step's end is the backward difference of the last
two velocity samples at or before it (none when they are more than 1 s apart or old):
causal, so a live link computes it exactly as a replay does.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from ..core.gaussian import Gaussian
from ..errors import InputError
from ..geometry.rotation import (
    G0,
    AttitudeSpace,
    qexp_f,
    qlog_f,
    qmul_f,
    quat_exp,
    quat_mul,
    quat_rotate,
)
from ..ingest.api import choose_source
from ..ingest.semantics import default_integration
from ..ingest.types import (
    ImuSample,
    MagSample,
    NoSamplesError,
    PositionSample,
    Sample,
    arrival_order,
)
from ..models.attitude import (
    AttitudeNoise,
    GravityDirection,
    GyroTransition,
    MagField,
    MagHeading,
    Stacked,
    declination_and_source,
    inclination_from_samples,
    initial_attitude,
    mag_reference,
    noise_for_source,
    reference_inclination,
    triad_attitude,
)
from .history import restore_vars, snapshot_vars
from .records import Start, Step

Array = np.ndarray

__all__ = ["DEFAULT_MAX_RATE_HZ", "AttitudeOptions", "AttitudeStream", "StreamSnapshots"]

DEFAULT_MAX_RATE_HZ = 25.0
#: An IMU interval longer than max(GAP_MIN_S, GAP_MEDIANS x the median interval of the
#: alignment window) is a gap: reported, not integrated across, the filters re-aligned.
GAP_MIN_S = 0.5
GAP_MEDIANS = 20.0
#: samples another IMU must have delivered since the chosen one's last before it takes over
FAILOVER_SAMPLES = 10


def step_plan(source: str, rate: float, integration: str, rate_hz: float | None
              ) -> tuple[str, str, int]:
    """(integration, why, samples per step) for an IMU ``source`` at ``rate`` Hz: the
    option ``integration`` or, for "auto", what the message is
    (:func:`uavest.ingest.semantics.default_integration`); ``rate_hz`` the filter rate cap
    (None: :data:`DEFAULT_MAX_RATE_HZ`, 0: every sample)."""
    integ, why = integration, "option"
    if integ == "auto":
        integ, why = default_integration(source, rate)
    cap = DEFAULT_MAX_RATE_HZ if rate_hz is None else float(rate_hz)
    return integ, why, 1 if cap <= 0 else max(1, round(rate / cap))


def failover_rate(other: dict[str, list[float]], s: ImuSample, last: float, gap_s: float
                  ) -> float | None:
    """The failover evidence of both streams: counts ``s`` for its source in ``other``
    (per source: samples since the chosen IMU's ``last`` time, first and last time, total)
    and returns its rate (Hz) once the chosen IMU has been silent longer than ``gap_s``
    while ``s.source`` delivered :data:`FAILOVER_SAMPLES` samples; else None."""
    ev = other.setdefault(s.source, [0, s.t, s.t, 0])
    ev[0] = ev[0] + 1 if ev[2] > last else 1  # delivered since the chosen one's last
    ev[2], ev[3] = s.t, ev[3] + 1
    if s.t - last <= gap_s or ev[0] < FAILOVER_SAMPLES:
        return None
    return (ev[3] - 1) / max(ev[2] - ev[1], 1e-9)


@dataclass(frozen=True)
class AttitudeOptions:
    """How samples become steps (see the module docstring and ``uavest replay --help``).

    ``start``/``end`` s (vehicle clock) clip the stream; ``rate_hz`` None -> the
    :data:`DEFAULT_MAX_RATE_HZ` cap, 0 -> every IMU sample; ``update_hz`` caps the rate
    of the accelerometer/magnetometer updates when the filter runs faster than
    :data:`DEFAULT_MAX_RATE_HZ` (None -> that rate, 0 -> an update every step, weighted
    and averaged over a reference step); ``declination`` rad east
    positive, None -> the source's parameters at the end of the alignment
    (``COMPASS_DEC``, ``ATT_MAG_DECL``), else 0; ``noise`` overrides of
    :class:`~uavest.models.attitude.AttitudeNoise`;
    ``imu`` an IMU source name or None (the stream's choice); ``mag_mode`` "field" (3-D
    direction) or "heading"; ``mag_delay`` s, the magnetometer sample's age, compensated
    with the step's gyro rate; ``accel_comp`` "auto" (use a velocity source when there is
    one) or "none"; ``on_arrival``: samples come as they arrive, steps are made at the
    IMU sample that ends them (module docstring)."""

    start: float | None = None
    end: float | None = None
    rate_hz: float | None = None
    update_hz: float | None = None
    integration: str = "auto"
    declination: float | None = None
    noise: dict[str, float] = field(default_factory=dict)
    imu: str | None = None
    use_mag: bool = True
    accel_comp: str = "auto"
    mag_mode: str = "field"
    mag_delay: float = 0.0
    align_s: float = 1.0
    on_arrival: bool = False

    def in_window(self, t: float) -> bool:
        """True if ``t`` (s) lies in [start, end]."""
        return (self.start is None or t >= self.start) and (self.end is None or t <= self.end)

    def __post_init__(self) -> None:
        if self.integration not in ("auto", "hold", "trapezoid"):
            raise InputError(
                f"integration must be auto, hold or trapezoid, not {self.integration!r}")
        if self.mag_mode not in ("field", "heading"):
            raise InputError(f"mag_mode must be field or heading, not {self.mag_mode!r}")
        if self.update_hz is not None and not self.update_hz >= 0:
            raise InputError(f"update rate must be >= 0 Hz, got {self.update_hz}")
        if self.accel_comp not in ("auto", "none"):
            raise InputError(f"accel_comp must be auto or none, not {self.accel_comp!r}")


@dataclass
class _Raw:
    """A closed step before its measurement models: end time ``t``, start ``t0``, rate
    ``w`` rad/s, mean specific force ``a`` (None: a prediction-only step), the samples it
    holds (``n``)."""

    t: float
    t0: float
    w: Array
    a: Array | None
    n: int
    mag: Array | None = None
    accel_ned: Array | None = None


@dataclass
class _Gap:
    """No IMU sample in (``t0``, ``t1``) s, longer than the gap threshold: the builder
    does not integrate across it; the stream re-aligns at the first step after it."""

    t0: float
    t1: float


class _StepBuilder:
    """Streaming pre-integration and grouping (see the module docstring)."""

    def __init__(self, integration: str, factor: int, use_pos: bool, ref: int = 1,
                 every: int = 1, close_now: bool = False) -> None:
        self.integration = integration
        self.close_now = close_now  # finish a step at the IMU sample that ends it
        self.t_done = -np.inf  # end of the last finished step (s)
        self.factor = factor
        self.every = every  # steps per accelerometer/magnetometer update
        self.since = 0  # steps since the last update
        self.t_upd: float | None = None  # end of the last step with an update
        self.acc_upd: list[Array] = []  # accelerometer samples since that update
        self.acc_hist: deque[Array] = deque(maxlen=max(ref, factor) if every == 1 else 1)
        self.use_pos = use_pos
        self.t_edge: float | None = None  # end of the last closed step (t_{k-1})
        self.g_edge: Array | None = None  # gyro at that edge (trapezoid)
        self.t_last: float | None = None  # last accepted IMU sample time
        self.block: list[ImuSample] = []
        self.pending: _Raw | None = None
        self.mag_last: tuple[float, Array] | None = None
        self.vel: list[tuple[float, Array]] = []  # the last two finite velocities
        self.dropped = 0  # IMU samples not after the previous one
        self.gap_s = np.inf  # an IMU interval longer than this (s) is a gap
        self.gaps: list[tuple[float, float]] = []  # (start, end) s of each gap

    def snapshot(self) -> dict[str, Any]:
        """This moment, for :meth:`restore` (:mod:`uavest.engine.history`)."""
        return snapshot_vars(self, appended=("gaps",))

    def restore(self, snap: dict[str, Any]) -> None:
        restore_vars(self, snap)

    def _finish(self, r: _Raw) -> _Raw:
        self.t_done = r.t
        if r.a is None:  # a prediction-only step (updates every ``every`` steps)
            return r
        # the magnetometer sample of the update interval: since the last update's end
        t0 = self.t_upd if self.every > 1 and self.t_upd is not None else r.t0
        self.t_upd = r.t
        if self.mag_last is not None and t0 < self.mag_last[0] <= r.t:
            r.mag = self.mag_last[1]
        if self.use_pos:
            acc = np.full(3, np.nan)
            if len(self.vel) == 2:
                (t1, v1), (t2, v2) = self.vel
                dtv = t2 - t1
                if dtv > 1e-3 and dtv <= 1.0 and r.t - t2 <= 1.0:
                    acc = (v2 - v1) / dtv
            r.accel_ned = acc
        return r

    def push(self, s: Sample) -> list[_Raw | _Gap]:
        """Feed one sample (of the chosen IMU / mag / position source); returns the steps
        it closed (zero or one), after an IMU gap with the :class:`_Gap`."""
        out: list[_Raw | _Gap] = []
        if self.pending is not None and s.t > self.pending.t:
            out.append(self._finish(self.pending))
            self.pending = None
        if isinstance(s, ImuSample):
            if self.t_last is not None and s.t <= self.t_last:
                self.dropped += 1
                return out
            if self.t_edge is None:  # the first sample: t_0 of the first step
                self.t_edge, self.g_edge, self.t_last = s.t, s.gyro, s.t
                return out
            assert self.t_last is not None  # set with t_edge
            if s.t - self.t_last > self.gap_s:  # a gap: close what came before, restart
                if self.block:
                    if self.pending is not None:
                        out.append(self._finish(self.pending))
                    out.append(self._finish(self._close()))
                    self.pending = None
                self.gaps.append((self.t_last, s.t))
                out.append(_Gap(self.t_last, s.t))
                self.t_edge, self.g_edge, self.t_last = s.t, s.gyro, s.t
                self.acc_hist.clear()
                self.acc_upd, self.since, self.t_upd = [], 0, None
                return out
            self.block.append(s)
            self.t_last = s.t
            if len(self.block) >= self.factor:
                self.pending = self._close()
                if self.close_now:
                    out.append(self._finish(self.pending))
                    self.pending = None
        elif isinstance(s, MagSample):
            self.mag_last = (s.t, s.field)
        elif isinstance(s, PositionSample):
            if s.vel_ned is not None and np.isfinite(s.vel_ned).all():
                self.vel = (self.vel + [(s.t, s.vel_ned)])[-2:]
        return out

    def flush(self) -> Iterator[_Raw]:
        if self.block:
            if self.pending is not None:
                yield self._finish(self.pending)
            self.pending = self._close()
        if self.pending is not None:
            yield self._finish(self.pending)
            self.pending = None

    def _close(self) -> _Raw:
        b, t0 = self.block, self.t_edge
        assert t0 is not None and self.g_edge is not None  # set by the first IMU sample
        t1 = b[-1].t
        if self.integration == "trapezoid":
            if len(b) == 1:
                w = 0.5 * (self.g_edge + b[-1].gyro)
            else:  # snapshots: the rate linear between samples, each interval's mean
                w = np.array(_preintegrate(t0, b, self.g_edge)) / max(t1 - t0, 1e-12)
        elif len(b) == 1:  # full rate: Log(Exp(g dt)) / dt = g (up to rounding)
            w = b[0].gyro
        else:
            w = np.array(_preintegrate(t0, b)) / max(t1 - t0, 1e-12)
        a = self._accel_mean(b)
        self.t_edge, self.g_edge = t1, b[-1].gyro
        self.block = []
        return _Raw(t1, t0, w, a, len(b))

    def _accel_mean(self, b: list[ImuSample]) -> Array | None:
        """The specific force (m/s^2, body FRD) of the step closing with the block ``b``
        (before the edge moves to its end): the block's mean, or None on a
        prediction-only step."""
        a: Array | None
        if self.every > 1:  # updates once per reference step: its mean specific force
            self.acc_upd.extend(s.accel for s in b)
            self.since += 1
            a = None
            if self.since >= self.every:
                a = np.sum(self.acc_upd, axis=0) / len(self.acc_upd)
                self.acc_upd, self.since = [], 0
        elif (self.acc_hist.maxlen or 0) > self.factor:  # faster than the reference rate
            self.acc_hist.extend(s.accel for s in b)
            a = np.sum(list(self.acc_hist), axis=0) / len(self.acc_hist)
        else:
            a = np.sum([s.accel for s in b], axis=0) / len(b)
        return a


def _preintegrate(t0: float, block: list[ImuSample], g0: Array | None = None
                  ) -> tuple[float, float, float]:
    """Log of the product of Exp(g_i (t_i - t_{i-1})) over the block's samples (rad, body
    FRD): the exact rotation of the step, on Python floats (``qexp_f``, ``qmul_f``,
    ``qlog_f``: the formulas of ``quat_exp``, ``quat_mul`` and ``quat_log``). With ``g0``
    (the rate at ``t0``, rad/s) each interval uses the mean of the rates at its ends
    (snapshots, trapezoid) instead of the rate at its end (hold)."""
    q = (1.0, 0.0, 0.0, 0.0)
    tp = t0
    gp = None if g0 is None else g0.tolist()
    for smp in block:
        dt = smp.t - tp
        tp = smp.t
        gx, gy, gz = g = smp.gyro.tolist()
        if gp is not None:
            gx, gy, gz = 0.5 * (gx + gp[0]), 0.5 * (gy + gp[1]), 0.5 * (gz + gp[2])
            gp = g
        q = qmul_f(q, qexp_f((gx * dt, gy * dt, gz * dt)))
    return qlog_f(q)


def turn_yaw(g: Any, angle: float) -> Any:
    """A running estimate ``g`` (a Gaussian whose state starts with the body-to-NED
    attitude quaternion: the attitude and the navigation states) turned about the NED
    down axis by ``angle`` (rad, east of north positive): ``q -> q_z(angle) q``, the rest
    of the state and the covariance as they are (the attitude's tangent is in the body
    frame). For a declination learnt after the start while the yaw came from the
    magnetometer alone (:class:`LateDeclination`): the filter's yaw is then off by the
    declination's change, which its updates would take out over tens of seconds,
    through its gyro bias."""
    x = np.array(g.x, float)
    x[:4] = quat_mul(quat_exp(np.array([0.0, 0.0, angle])), x[:4])
    return type(g)(x, np.array(g.P, float))


class LateDeclination:
    """The declination a stream's source gives only after the start (no parameter yet,
    automatic declination before the GNSS fix: :func:`declination_and_source`), taken when
    it comes (:meth:`_check_declination`, while ``_decl_pending``), the magnetic reference
    turned with it; while the stream's yaw is the magnetometer's alone
    (:meth:`_yaw_from_mag`) the filters' yaw is turned with it too, by a restart from
    their running estimates before the next step (:meth:`_turn_start`)."""

    params: Any
    opts: Any
    space: Any
    summary: dict[str, Any]
    declination: float
    _mref: Array | None
    _mag: str | None
    _decl_pending: bool
    _decl_seen: tuple[Any, ...] | None
    #: the yaw turn (rad) a declination learnt since the last step asks of the filters
    _yaw_turn: float

    def _decide(self, what: str, value: Any, t: float, why: str) -> None:
        raise NotImplementedError

    def _yaw_from_mag(self) -> tuple[bool, str]:
        """(the filters' yaw so far is the magnetometer's alone, the words saying why)."""
        return self._mag is not None, "the magnetometer's"

    def _first_declination(self, t: float) -> None:
        """The declination at the stream's first start (at ``t`` s): the option's, else
        the source's (:func:`declination_and_source`), else 0; said, and watched for a
        later one where it may come (:meth:`_declination_pending`)."""
        decl, src = self.opts.declination, "option"
        if decl is None:
            d, src = declination_and_source(self.params)
            decl = d or 0.0
        self.declination = float(decl)
        self.summary.update(declination_rad=self.declination, declination_source=src)
        self._decl_pending, note = self._declination_pending(src)
        self._decide("declination", f"{np.degrees(self.declination):.2f} deg", t, src + note)

    def _declination_pending(self, src: str) -> tuple[bool, str]:
        """(watch the source's parameters for a declination, the words saying so) after a
        declination from ``src`` (:func:`declination_and_source`'s words, or "option"):
        none yet, or the magnetic model's, which the vehicle's own parameter replaces when
        it comes (an autopilot with automatic declination sets it after its GPS lock: a
        replay of its log takes that one, so a live run does too)."""
        if self.opts.declination is not None or src.startswith("log parameter"):
            return False, ""
        if src.startswith("none"):
            return True, " (taken later if the log gives one)"
        return True, " (the vehicle's own parameter taken if it comes)"

    def _check_declination(self, t: float) -> None:
        """Take the source's declination once its parameters give one (at ``t`` s): the
        magnetic model's at a first fix, the vehicle's own parameter when it comes."""
        p = self.params
        key = (len(p), bool(getattr(p, "geo", None)),
               *(p.get(k) for k in ("COMPASS_DEC", "EKF2_MAG_DECL", "ATT_MAG_DECL")))
        if key == self._decl_seen:
            return
        self._decl_seen = key
        decl, src = declination_and_source(p)
        if decl is None or (float(decl) == self.declination
                            and src == self.summary.get("declination_source")):
            return
        self._decl_pending, note = self._declination_pending(src)
        turn = float(decl) - self.declination
        self.declination = float(decl)
        if self._mref is not None:
            self._mref = mag_reference(self.declination, reference_inclination(self._mref))
        self.summary.update(declination_rad=self.declination, declination_source=src,
                            declination_from_t=float(t))
        alone, what = self._yaw_from_mag()
        if alone and turn:  # the yaw so far is the magnetometer's at the old declination
            self._yaw_turn += turn
            src += f"; the yaw turned by {np.degrees(turn):+.2f} deg with it ({what})"
        self._decide("declination", f"{np.degrees(self.declination):.2f} deg", t, src + note)

    def _turn_start(self, t: float, t0: float, prior: Callable[[], Gaussian]) -> list[Start]:
        """Before the step ending at ``t`` (s), from ``t0`` (s): the declination's check
        while it is pending, then the restart at ``t0`` that turns the yaw if one is due
        (``prior()`` of the state's size: the restart takes each filter's running
        estimate, :func:`turn_yaw`)."""
        if self._decl_pending:
            self._check_declination(t)
        if not self._yaw_turn:
            return []
        a, self._yaw_turn = self._yaw_turn, 0.0
        return [Start(t0, prior(), self.space, reason="declination",
                      augment=partial(turn_yaw, angle=a))]


class StreamSnapshots:
    """``snapshot`` / ``restore`` of a step builder (:class:`AttitudeStream`,
    :class:`~uavest.engine.navigation.NavStream`) for the engine's history
    (:mod:`uavest.engine.history`): every attribute but the shared ones (the sample
    iterable, the options, the source's parameters, the state space), the decisions as
    their number (only ever appended)."""

    summary: dict[str, Any]
    decisions: list[dict[str, Any]]

    def snapshot(self) -> dict[str, Any]:
        """This moment of the stream, for :meth:`restore`."""
        return snapshot_vars(self, skip=("samples", "opts", "params", "space"),
                             appended=("decisions",))

    def restore(self, snap: dict[str, Any]) -> None:
        restore_vars(self, snap)
        if "decisions" in self.summary:
            self.summary["decisions"] = self.decisions


class HeldAlignment:
    """The first samples of a step builder (:class:`AttitudeStream`,
    :class:`~uavest.engine.navigation.NavStream`), held until its IMU has run for two
    alignment windows; then its ``_setup`` (the sources chosen from what was held, the
    held samples fed through)."""

    opts: Any
    _held: list[Any] | None  # samples of the alignment window (None once set up)
    _imu_t0: float | None

    def _setup(self) -> list[Start | Step]:
        raise NotImplementedError

    def _held_push(self, s: Sample) -> list[Start | Step] | None:
        """``s`` held: the items the set-up completed (none while it waits); None once
        the stream is set up (``s`` is for the steps)."""
        if self._held is None:
            return None
        self._held.append(s)
        if isinstance(s, ImuSample):
            if self._imu_t0 is None:
                self._imu_t0 = s.t
            elif s.t > self._imu_t0 + 2.0 * self.opts.align_s:
                return self._setup()
        return []

    def _held_flush(self) -> list[Start | Step]:
        """At the end of the stream: the set-up if it is still waiting (nothing held at
        all: :class:`NoSamplesError`), else nothing."""
        if self._held is None:
            return []
        if not self._held:
            raise NoSamplesError("no samples in the stream (or in the chosen window)")
        return self._setup()


def choose_imu(held: Sequence[Sample], imu: str | None, use_mag: bool
               ) -> tuple[str, dict[str, int], str | None, dict[str, int]]:
    """``(imu, imu_counts, mag, mag_counts)`` of the alignment window ``held``: the IMU
    ``imu`` (the option), else the source with the most samples; the IMU's own
    magnetometer when it has one, else the magnetometer with the most samples (none
    without ``use_mag``); samples per source name. No IMU: :class:`NoSamplesError`;
    ``imu`` naming an absent one: :class:`InputError`."""
    imu_counts: dict[str, int] = {}
    mag_counts: dict[str, int] = {}
    for s in held:
        if isinstance(s, ImuSample):
            imu_counts[s.source] = imu_counts.get(s.source, 0) + 1
        elif isinstance(s, MagSample):
            mag_counts[s.source] = mag_counts.get(s.source, 0) + 1
    if imu is None:
        imu = choose_source(imu_counts, slack=1)
    if imu is None or imu not in imu_counts:
        have = ", ".join(sorted(imu_counts)) or "none"
        if not imu:
            raise NoSamplesError(f"no IMU samples (IMU sources seen: {have})")
        raise InputError(f"IMU source {imu!r} not in the stream (IMU sources seen: {have})")
    mag = None
    if use_mag and mag_counts:
        mag = imu if imu in mag_counts else choose_source(mag_counts, slack=1)
    return imu, imu_counts, mag, mag_counts


class AttitudeStream(LateDeclination, StreamSnapshots, HeldAlignment):
    """One :class:`Start` then :class:`Step` s from a sample stream (see the module
    docstring). Push samples one at a time (:meth:`push`, :meth:`flush`: each returns the
    items it completed), or iterate it over ``samples``. :attr:`summary` describes what
    was chosen and counted (sources, rates, integration, steps, inclination...)."""

    # set when the alignment window is complete (_setup) and when it ends (_start)
    _imu: str
    _mag: str | None
    _pos: str | None
    _model: GyroTransition
    _first: ImuSample
    _mag0: Array | None
    _mref: Array | None  # unit Earth field, NED (None: heading-only or no magnetometer)
    _accel_weight: float
    _mag_weight: float

    def __init__(
        self, samples: Iterable[Sample] = (), opts: AttitudeOptions | None = None,
        params: dict[str, Any] | None = None,
    ) -> None:
        self.samples = samples
        self.opts = opts or AttitudeOptions()
        self.params = {} if params is None else params  # filled by the source as it reads
        self.declination = 0.0
        self.space = AttitudeSpace()
        self.summary: dict[str, Any] = {}
        self.noise: AttitudeNoise | None = None
        self._held: list[Sample] | None = []  # samples of the alignment window (None once set up)
        self._imu_t0: float | None = None
        self._align: list[_Raw] | None = None  # steps of the alignment, before the Start
        self._builder: _StepBuilder | None = None
        self._k = 0
        self._imu_n = [0, 0.0, 0.0]  # samples, first and last time
        #: what was decided and when it took effect: dicts of ``what``, ``value``, ``t``
        #: (s, vehicle clock) and ``why``, in the order they were made (see
        #: :meth:`_decide`); also ``summary["decisions"]``
        self.decisions: list[dict[str, Any]] = []
        self._decl_pending = False  # declination unknown so far: take it when it arrives
        self._gap: _Gap | None = None  # an IMU gap waiting for its first step after it
        #: (params size, geo, the declination parameters) last looked at
        self._decl_seen: tuple[Any, ...] | None = None
        self._yaw_turn = 0.0  # LateDeclination
        #: other IMU sources seen after the set-up: name -> [samples since the chosen IMU's
        #: last sample, first time, last time, samples in all] (the failover's evidence)
        self._other_imu: dict[str, list[float]] = {}
        self._switched = False  # the gap pending is an IMU switch (biases not kept)

    def _decide(self, what: str, value: Any, t: float, why: str) -> None:
        """Record a decision ``what`` = ``value`` taking effect at ``t`` (s) because ``why``."""
        self.decisions.append({"what": what, "value": value, "t": float(t), "why": why})
        self.summary["decisions"] = self.decisions

    def __iter__(self) -> Iterator[Start | Step]:
        for s in self.samples:
            yield from self.push(s)
        yield from self.flush()

    # ------------------------------------------------------------------ history
    # (the engine's history, :mod:`uavest.engine.history`, on a live link: samples on
    # arrival, a late one applied at its time)
    @property
    def committed(self) -> float:
        """End (s) of the last step made (steps held for the alignment included)."""
        return self._builder.t_done if self._builder is not None else -np.inf

    def order_sensitive(self, s: Sample) -> bool:
        """The chosen IMU, magnetometer and velocity source (and, before compensation is
        on, any velocity: the first one switches it on at its time). Other IMUs only
        feed the failover, decided after a silence of the gap threshold (>= 0.5 s):
        their order within it does not change the decision."""
        if self._held is not None:
            return True
        if isinstance(s, ImuSample) or isinstance(s, MagSample):
            return s.source == (self._imu if isinstance(s, ImuSample) else self._mag)
        if isinstance(s, PositionSample):
            return s.source == self._pos or (
                self._pos is None and self.opts.accel_comp == "auto"
                and s.vel_ned is not None)
        return False

    # ------------------------------------------------------------------ pushing
    def push(self, s: Sample) -> list[Start | Step]:
        """Feed one sample; returns the items (start, steps) it completed."""
        if not self.opts.in_window(s.t):
            return []
        held = self._held_push(s)
        return self._feed(s) if held is None else held

    def flush(self) -> list[Start | Step]:
        """End of the stream: close the last step; returns the remaining items."""
        out = self._held_flush()
        assert self._builder is not None  # made by _setup
        out += self._emit(list(self._builder.flush()))
        if self._align is not None:  # the stream ended during the alignment
            out += self._start()
        self._finish_summary()
        return out

    # ------------------------------------------------------------------ internals
    def _mine(self, s: Sample) -> bool:
        if isinstance(s, ImuSample):
            return s.source == self._imu
        if isinstance(s, MagSample):
            return s.source == self._mag
        return isinstance(s, PositionSample) and s.source == self._pos

    def _feed(self, s: Sample) -> list[Start | Step]:
        if (isinstance(s, ImuSample) and s.source != self._imu and self.opts.imu is None
                and self._builder is not None and self._align is None):
            before = self._failover(s)
            if before is None:
                return []
            return before + self._feed(s)
        if not self._mine(s):
            if (self._pos is None and self.opts.accel_comp == "auto"
                    and isinstance(s, PositionSample) and s.vel_ned is not None
                    and np.isfinite(s.vel_ned).all()):
                self._accel_comp_on(s)  # the velocity arrived after the alignment
            else:
                return []
        if isinstance(s, ImuSample):
            self._imu_n[0] += 1
            self._imu_n[2] = s.t
        assert self._builder is not None  # made by _setup
        raws = self._builder.push(s)
        return self._emit(raws) if raws else []

    def _emit(self, raws: Sequence[_Raw | _Gap]) -> list[Start | Step]:
        out: list[Start | Step] = []
        if self._align is None:
            for r in raws:
                if isinstance(r, _Gap):
                    self._gap = r
                elif self._gap is not None and r.a is not None:
                    out += self._realign(r)
                else:
                    out += self._steps(r)
            return out
        steps = [r for r in raws if not isinstance(r, _Gap)]  # in the alignment: no filter yet
        for i, r in enumerate(steps):
            self._align.append(r)
            if r.t > self._first.t + self.opts.align_s:
                out += self._start()
                for x in steps[i + 1:]:
                    out += self._steps(x)
                break
        return out

    def _realign(self, r: _Raw) -> list[Start | Step]:
        """The first step after an IMU gap: a new Start at its beginning, attitude from its
        accelerometer (and magnetometer) with the alignment's uncertainty, the filters'
        gyro biases kept (``keep_tail``), then the step itself. Nothing is propagated
        across the gap (one step of 17 s through a UKF's sigma points diverged)."""
        gap, self._gap = self._gap, None
        switched, self._switched = self._switched, False
        noise = self.noise
        assert gap is not None and r.a is not None  # called so by _emit
        assert noise is not None and self._builder is not None  # set by _setup
        mag = r.mag
        if mag is None and self._builder.mag_last is not None \
                and self._builder.mag_last[0] >= gap.t1 - 1.0:
            mag = self._builder.mag_last[1]
        use_mag = self._mag is not None and mag is not None and np.any(mag)
        acc = r.accel_ned
        comp = acc is not None and np.isfinite(acc).all()
        # TRIAD: exact in a turn with the vehicle's acceleration
        if use_mag and mag is not None and np.any(r.a):
            f_ned = (acc if comp else np.zeros(3)) - np.array([0.0, 0.0, G0])
            m_ned = (self._mref if self._mref is not None
                     else mag_reference(self.declination, 0.0))
            q0 = triad_attitude(r.a, f_ned, mag, m_ned)
        else:
            q0 = initial_attitude(r.a, mag if use_mag else None, self.declination)
        P0 = np.diag([noise.init_tilt**2, noise.init_tilt**2, noise.init_yaw**2]
                     + [noise.init_bias**2] * 3)
        prior = Gaussian(np.concatenate([q0, np.zeros(3)]), P0)
        what = (f"after the IMU switch to {self._imu}" if switched
                else f"after an IMU gap of {gap.t1 - gap.t0:.1f} s")
        self._decide("re-alignment", what, r.t0,
                     "no IMU data from t=" f"{gap.t0:.1f} s; attitude from the accelerometer"
                     + (" and magnetometer" if use_mag else "")
                     + (" with the vehicle's acceleration" if comp else "")
                     + (", gyro biases from zero (another sensor)" if switched
                        else ", gyro biases kept"))
        return [Start(r.t0, prior, self.space, reason="imu switch" if switched else "gap",
                      keep_tail=0 if switched else 3), *self._steps(r)]

    def _failover(self, s: ImuSample) -> list[Start | Step] | None:
        """The IMU choice re-decided when the evidence arrives: the chosen IMU has been
        silent for longer than the gap threshold while ``s.source`` kept delivering (at
        least :data:`FAILOVER_SAMPLES` samples since its last one). Then ``s.source``
        becomes the IMU from ``s.t``: its own noise, rate and integration, a re-alignment
        at its first step (gyro biases not kept: they belong to the other sensor).
        Returns None (no switch) or the items the silent IMU's last samples closed."""
        b = self._builder
        assert b is not None  # _feed calls this after the set-up only
        last = b.t_last if b.t_last is not None else s.t
        rate = failover_rate(self._other_imu, s, last, b.gap_s)
        if rate is None:
            return None
        o, old = self.opts, self._imu
        integ, why, factor = step_plan(s.source, rate, o.integration, o.rate_hz)
        nb = _StepBuilder(integ, factor, b.use_pos, 1, 1, o.on_arrival)
        nb.mag_last, nb.vel, nb.gaps, nb.dropped = b.mag_last, b.vel, b.gaps, b.dropped
        nb.t_done = b.t_done
        nb.gap_s = max(GAP_MIN_S, GAP_MEDIANS / max(rate, 1e-9))
        nb.gaps.append((last, s.t))
        out = self._emit(list(b.flush()))  # what the silent IMU left, before the switch
        self._builder = nb
        self._imu, self._gap, self._switched = s.source, _Gap(last, s.t), True
        if self._mag == old:  # that sensor's magnetometer went with it
            self._mag = s.source if self._mag is not None else None
        self.noise = noise_for_source(s.source).with_(**o.noise)
        self._model = GyroTransition(self.noise)
        self._accel_weight = 1.0
        self._other_imu.pop(s.source)
        switches = self.summary.setdefault("imu_switches", [])
        switches.append({"from": old, "to": s.source, "t": float(s.t)})
        self._decide("IMU", s.source, s.t,
                     f"{old} silent since t={last:.1f} s ({s.t - last:.1f} s), {s.source} "
                     f"continued ({rate:.1f} Hz, {integ}: {why})")
        return out

    def _accel_comp_on(self, s: PositionSample) -> None:
        """Compensation switches on with the first valid velocity of ``s.source`` (a log
        that starts before the GNSS fix has none in the alignment window)."""
        self._pos = s.source
        assert self._builder is not None  # made by _setup
        self._builder.use_pos = True
        self.summary["accel_compensation"] = s.source
        self.summary["accel_compensation_from_t"] = float(s.t)
        self._decide("acceleration compensation", f"on ({s.source})", s.t,
                     f"first valid velocity from {s.source}")

    def _steps(self, r: _Raw) -> list[Start | Step]:
        """The step of ``r``, after the restart a declination learnt since asks
        (:meth:`LateDeclination._turn_start`)."""
        return [*self._turn_start(r.t, r.t0, self._size_prior), self._step(r)]

    def _size_prior(self) -> Gaussian:
        """A prior of the state's size for a restart from the running estimates
        (``Start.augment``: it only gives the size)."""
        return Gaussian(np.r_[1.0, np.zeros(6)], np.eye(6))

    def _step(self, r: _Raw) -> Step:
        self._k += 1
        return Step(self._k, r.t, r.t - r.t0, self._model, self._updates(r, self._mref), r.w)

    def _setup(self) -> list[Start | Step]:
        """Choose sources, rate and integration from the held window; replay it."""
        o, held = self.opts, self._held
        assert held is not None  # called once, while holding
        self._held = None
        if o.on_arrival:  # time order (an IMU sample after the rest of its message)
            held.sort(key=arrival_order)
        imu, imu_counts, mag, mag_counts, pos = self._choose_sources(held)
        ti = [s.t for s in held if isinstance(s, ImuSample) and s.source == imu]
        n_mag = mag_counts.get(mag, 0) if mag else 0
        integ, why, factor, ref, every, rate = self._plan_steps(imu, ti, n_mag)
        self.noise = noise_for_source(imu).with_(**o.noise)
        self._model = GyroTransition(self.noise)
        self.summary.update(
            imu_source=imu, imu_sources=imu_counts, mag_source=mag, accel_compensation=pos,
            integration=integ, integration_why=why, preintegrated_samples_per_step=factor,
            align_rate_hz=rate, steps_per_update=every,
        )
        self._imu, self._mag, self._pos = imu, mag, pos
        t_first = next(s.t for s in held if isinstance(s, ImuSample) and s.source == imu)
        self._decide_sources(imu, imu_counts, integ, why, pos, t_first)
        self._builder = _StepBuilder(integ, factor, pos is not None, ref, every,
                                     o.on_arrival)
        med = float(np.median(np.diff(ti))) if len(ti) > 1 else 0.0
        self._builder.gap_s = max(GAP_MIN_S, GAP_MEDIANS * med)
        self.summary["imu_gap_threshold_s"] = self._builder.gap_s
        self._first_samples(held, imu, mag)
        self._imu_n = [0, self._first.t, self._first.t]
        self._align = []
        out: list[Start | Step] = []
        for s in held:
            out += self._feed(s)
        return out

    def _choose_sources(self, held: list[Sample]) -> tuple[
            str, dict[str, int], str | None, dict[str, int], str | None]:
        """The IMU, magnetometer and velocity (acceleration compensation) sources of the
        held window: ``(imu, imu_counts, mag, mag_counts, pos)``, counts per source name.
        No IMU: :class:`NoSamplesError`; ``--imu`` naming an absent one: :class:`InputError`."""
        o = self.opts
        imu, imu_counts, mag, mag_counts = choose_imu(held, o.imu, o.use_mag)
        pos = None
        if o.accel_comp == "auto":
            for s in held:
                if (isinstance(s, PositionSample) and s.vel_ned is not None
                        and np.isfinite(s.vel_ned).all()):
                    pos = s.source
                    break
        return imu, imu_counts, mag, mag_counts, pos

    def _plan_steps(self, imu: str, ti: list[float], n_mag: int
                    ) -> tuple[str, str, int, int, int, float]:
        """Integration, pre-integration and update cadence from the IMU ``imu``'s held
        sample times ``ti`` (s) and the magnetometer's sample count ``n_mag`` over the same
        window; sets the accelerometer and magnetometer update weights. Returns
        ``(integration, why, factor, ref, every, rate)``: IMU samples per step, IMU samples
        per reference step (at ``DEFAULT_MAX_RATE_HZ``), steps per update, and the IMU's
        rate (Hz)."""
        o = self.opts
        rate = (len(ti) - 1) / max(ti[-1] - ti[0], 1e-9) if len(ti) > 1 else 0.0
        integ, why, factor = step_plan(imu, rate, o.integration, o.rate_hz)
        ref = max(1, round(rate / DEFAULT_MAX_RATE_HZ))
        # faster than the reference rate: updates at most at ``update_hz`` (default the
        # reference rate), on the mean specific force of the samples since the last one
        ucap = DEFAULT_MAX_RATE_HZ if o.update_hz is None else float(o.update_hz)
        frate = rate / factor if factor else rate
        every = 1 if ucap <= 0 or factor >= ref else max(1, round(frate / ucap))
        self._accel_weight = min(1.0, factor * every / ref)  # 1.0 at the default rate
        # the magnetometer: its updates per second now against those at the default rate
        # (each step uses its latest sample): 1 when it is slower than both filter rates
        span = (ti[-1] - ti[0]) if len(ti) > 1 else 0.0
        mrate = n_mag / span if span > 0 else 0.0
        urate = frate / every
        ref_rate = rate / ref
        self._mag_weight = (min(1.0, min(mrate, ref_rate) / min(mrate, urate))
                            if mrate > 0 else 1.0)
        return integ, why, factor, ref, every, rate

    def _decide_sources(self, imu: str, imu_counts: dict[str, int], integ: str, why: str,
                        pos: str | None, t_first: float) -> None:
        """Log the IMU, integration and acceleration-compensation decisions at ``t_first``
        (s, the first IMU sample)."""
        o = self.opts
        self._decide("IMU", imu, t_first,
                     "option --imu" if o.imu is not None else
                     f"most samples in the first {2 * o.align_s:g} s ("
                     + ", ".join(f"{k} {v}" for k, v in sorted(imu_counts.items())) + ")")
        self._decide("integration", integ, t_first,
                     "option" if o.integration != "auto" else why)
        if o.accel_comp == "none":
            self._decide("acceleration compensation", "off", t_first, "option --accel-comp none")
        elif pos is not None:
            self._decide("acceleration compensation", f"on ({pos})", t_first,
                         f"velocity from {pos} at the start")
        else:
            self._decide("acceleration compensation", "off", t_first,
                         "no valid velocity yet (switches on when one arrives)")

    def _first_samples(self, held: list[Sample], imu: str, mag: str | None) -> None:
        """The first IMU sample of ``imu`` (``_first``) and the magnetometer field at/before
        it (``_mag0``; else the first one held; None without a magnetometer)."""
        self._first = first = next(s for s in held if isinstance(s, ImuSample)
                                   and s.source == imu)
        self._mag0 = None
        for s in held:
            if isinstance(s, MagSample) and s.source == mag:
                if self._mag0 is None or s.t <= first.t:
                    self._mag0 = s.field
                if s.t > first.t:
                    break

    def _start(self) -> list[Start | Step]:
        """Alignment done: declination, inclination, prior; the Start and held steps."""
        o, first, mag0, noise = self.opts, self._first, self._mag0, self.noise
        align, self._align = self._align, None
        assert align is not None and noise is not None  # set by _setup
        self._first_declination(first.t)
        decl = self.declination
        self._mref = None
        if self._mag is not None and o.mag_mode == "field":
            win = [r for r in align if r.t <= first.t + o.align_s and r.mag is not None]
            acc: list[Array | None] = [r.a for r in win]  # every step with a field has an a
            fld: list[Array | None] = [r.mag for r in win]
            if mag0 is not None:
                acc, fld = [first.accel, *acc], [mag0, *fld]
            self._mref = mag_reference(
                decl, inclination_from_samples(np.array(acc).reshape(-1, 3),
                                               np.array(fld).reshape(-1, 3)))
            self.summary["inclination_rad"] = reference_inclination(self._mref)
        q0 = initial_attitude(first.accel, mag0 if self._mag is not None else None, decl)
        P0 = np.diag([noise.init_tilt**2, noise.init_tilt**2, noise.init_yaw**2]
                     + [noise.init_bias**2] * 3)
        start = Start(first.t, Gaussian(np.concatenate([q0, np.zeros(3)]), P0), self.space)
        t_al = align[-1].t if align else first.t
        self._decide("alignment", "done", t_al,
                     f"roll/pitch from the accelerometer at t={first.t:.1f} s"
                     + (", yaw from the magnetometer" if mag0 is not None and self._mag
                        else ", yaw 0 (no magnetometer)")
                     + f"; {len(align)} steps of the {o.align_s:g} s window held")
        return [start, *(x for r in align for x in self._steps(r))]

    def _finish_summary(self) -> None:
        n, t0, t1 = self._imu_n
        span = t1 - t0
        gaps = self._builder.gaps if self._builder else []
        self.summary.update(
            steps=self._k, imu_samples=n, t_first=t0, t_last=t1,
            imu_dropped=self._builder.dropped if self._builder else 0,
            imu_gaps=len(gaps), imu_gap_longest_s=max((b - a for a, b in gaps), default=0.0),
            imu_gap_list=[[a, b] for a, b in gaps],
            duration_s=span,
            imu_rate_hz=(n - 1) / span if span > 0 else 0.0,
            filter_rate_hz=self._k / span if span > 0 else 0.0,
        )

    def _updates(self, r: _Raw, mref: Array | None) -> tuple[tuple[Array, Any], ...]:
        """The step's (z, measurement model) pairs: gravity direction, magnetometer
        (field or heading), stacked into one when both are there."""
        o, noise = self.opts, self.noise
        if r.a is None:
            return ()
        assert noise is not None  # set by _setup
        meas: list[tuple[Array, Any]] = []
        a = GravityDirection.from_accel(r.a, noise, accel_ned=r.accel_ned,
                                        weight=self._accel_weight)
        if a is not None:
            meas.append(a)
        if r.mag is not None:
            fld = r.mag
            if o.mag_delay:
                fld = quat_rotate(quat_exp(-o.mag_delay * r.w), fld)
            m = (MagField.from_field(fld, noise, mref, weight=self._mag_weight)
                 if mref is not None else MagHeading.from_field(
                     fld, noise, self.declination, weight=self._mag_weight))
            if m is not None:
                meas.append(m)
        if len(meas) > 1:
            meas = [Stacked.of(meas)]
        return tuple(meas)
