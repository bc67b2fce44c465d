"""GNSS-aided navigation from a sample stream: typed samples in, navigation steps out.

:class:`NavStream` is the navigation counterpart of
:class:`~uavest.engine.attitude.AttitudeStream`: the same streaming pre-integration
(:class:`~uavest.engine.attitude._StepBuilder`, hold or trapezoid, ``rate_hz`` cap), but
the state is :class:`~uavest.geometry.navigation.NavSpace` (q, v NED, p NED, gyro bias,
accel bias), the transition :class:`~uavest.models.navigation.ImuTransition` with
``u = [gyro (rad/s), specific force (m/s^2)]`` of the step (the mean rate and mean specific
force of its IMU samples), and the updates are raw aiding measurements:

* GNSS position (:meth:`GnssPosition.from_fix` with the receiver's h_acc / v_acc: fix
  type < 2 no update, 2-D horizontal only) and velocity (:class:`GnssVelocity`, std
  max(s_acc, floor); horizontal only when the message has no vertical speed), applied to
  the step whose interval holds the fix's time minus ``gnss_delay``; the position is
  carried from that time to the step's end with the fix's own velocity;
* barometric height (:class:`BaroHeight`, the offset to the GNSS height taken once, at
  the first baro sample after the start, and held);
* the magnetometer through :class:`OnNav` (3-D field direction, or heading), declination
  as the attitude path (option, then the log's parameters, taken later if they arrive),
  at most at the attitude path's reference rate
  (:data:`~uavest.engine.nav_aiding.MAG_MIN_INTERVAL_S`).

Each update is tagged with its sensor (``Step.info["sensors"]``) so that
:class:`NavRunner` gates it per filter on its own innovation (chi-square 99.9 %)
and counts the rejections per sensor; a rejected update is skipped, never a reset.

**GNSS delay** ``gnss_delay`` (s): a fix stamped t measures the state at t - delay. The
stream holds closed steps until the newest sample is ``delay`` past their end, so every
fix finds the step it belongs to (the filters then run ``delay`` behind the stream).

**Alignment.** The first ``2 align_s`` of IMU data are held to choose the IMU source,
rate and integration as the attitude path does (then replayed). Steps are dropped until a
good fix (3-D, finite position and horizontal velocity) arrives; the first step holding
one is the start: roll/pitch from the mean accelerometer of the last ``align_s``
(``init_tilt``), yaw from the magnetometer (tilt-compensated, declination; ``init_yaw``)
or, without one, from the GNSS course once the ground speed is at least ``yaw_speed``
(``init_yaw_course``: the crab/sideslip that leaves), velocity and position from the fix
with its accuracies (position origin: that fix), biases zero (``init_gyro_bias``,
``init_accel_bias``). An IMU gap (as the attitude path defines it) re-aligns the same way
at the next good fix, keeping the filters' biases.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields, replace
from functools import partial
from typing import Any

import numpy as np

from ..core.gaussian import Gaussian
from ..core.guard import nis_gate
from ..errors import InputError
from ..geometry.geodesy import GEODESIES, LocalFrame, SphereFrame, make_frame
from ..geometry.navigation import DIM, DP, DV, NavSpace
from ..ingest.types import (
    AttitudeRef,
    BaroSample,
    GnssSample,
    ImuSample,
    MagSample,
    NoSamplesError,
    arrival_order,
)
from ..models.attitude import (
    mag_reference,
    reference_declination,
    reference_inclination,
)
from ..models.navigation import (
    GnssPosition,
    ImuTransition,
    NavNoise,
    names_gnss_bias,
    nav_noise_for_source,
    nav_space,
)
from .attitude import (
    GAP_MEDIANS,
    GAP_MIN_S,
    HeldAlignment,
    LateDeclination,
    StreamSnapshots,
    _Gap,
    _Raw,
    _StepBuilder,
    choose_imu,
    failover_rate,
    step_plan,
)
from .nav_aiding import (
    AidQueues,
    _Aid,
    baro_height,
    carry_force,
    finite3,
    good_fix,
    window_force,
)
from .nav_align import (
    MAG_SITE_KM,
    AlignWindow,
    add_gnss_bias,
    anchor_start,
    fix_prior,
    fix_start,
    gnss_acceleration,
    heading_noise_scale,
    kept_biases,
    level,
    start_inclination,
    unaided_start,
    widen_tilt,
    with_gnss_bias,
    with_mag_ref,
)
from .nav_rough import RoughDensity
from .records import NavAnchor, Start, Step, StepRecord
from .runner import FilterRunner

Array = np.ndarray

__all__ = ["GATE_PROB", "NavNotStarted", "NavOptions", "NavRunner", "NavStream",
           "baro_height"]

#: Innovation gate of every aiding update: the chi-square quantile for its dimension.
GATE_PROB = 0.999
#: Consecutive rejections of one sensor for this long (s) and its next update is taken
#: with R scaled to put it on the gate (one re-anchoring, counted; not a reset).
REANCHOR_S = 10.0
#: ... except the GNSS velocity: rejected for :data:`LOCKOUT_S`, the filter has left it (a tilt the
#: first turn shows wrong, a start's tilt error that the GNSS velocity then sees growing),
#: and one update on the gate does not bring it back (the velocity error grew on to 9-39
#: m/s on the simulator's 60-s flights, docs/live.md). It is a reset, as an autopilot's
#: EKF resets its velocity and position to the GNSS after a timeout: the running
#: estimate with its velocity variance widened by the innovation squared, its position
#: variance by the innovation times the time rejected, squared, and its tilt and
#: horizontal accelerometer bias as a start's (:data:`LOCKOUT_TILT`), then the update.
LOCKOUT_SENSORS = frozenset({"gnss_vel"})
#: ... after this long (s) of consecutive rejections (the re-anchorings among them do not
#: end the run), doubled for each such reset of the sensor but the first in the last
#: :data:`LOCKOUT_MEMORY_S`: the second comes as soon as the first (an IMU fault that
#: ends undoes what the first reset learnt), then 10, 20, 40 s: never a reset storm.
LOCKOUT_S = 5.0
LOCKOUT_MEMORY_S = 300.0
#: The tilt std (rad) a GNSS lock-out reset widens the tilt by (``NavNoise.init_tilt``'s
#: default, a start's at rest), with the horizontal accelerometer bias by ``g`` times it.
LOCKOUT_TILT = float(np.deg2rad(5.0))
_CHI2: dict[int, float] = {}  # GATE_PROB quantile by dimension
#: A start (or re-alignment) levels from at least this share of ``NavOptions.align_s`` of
#: IMU data (the steps seen while waiting for the fix).
ALIGN_SPAN = 0.95
#: Without a good GNSS fix this many alignment windows (``NavOptions.align_s``) into the
#: IMU data, the stream starts unaided (``NavOptions.before_fix``).
UNAIDED_WAIT_ALIGNS = 2.0
#: The unaided constant-position measurement is applied at most this often (s): a
#: GNSS-like rate, so its information does not grow with the IMU rate.
HOLD_INTERVAL_S = 0.2
#: A step longer than max(MAX_STEP_S, MAX_STEP_PERIODS x the nominal step) s (an IMU
#: interval below the gap threshold) is predicted in that many equal sub-steps.
MAX_STEP_S = 0.5
MAX_STEP_PERIODS = 2.0
#: Until the GNSS velocity's window is known (an option, the replay's probe, a live run's
#: estimate: :class:`~uavest.engine.gnss_delay.LiveDelayLearner`), the GNSS velocity std
#: is at least this (m/s): the window a receiver may average over is then not modelled
#: (an ArduPilot SITL's, 0.35 s, leaves 0.014 m/s of velocity error, up to 0.02 in
#: manoeuvres; the floor the noise profile had before the window was modelled).
UNMODELLED_WINDOW_VEL_FLOOR = 0.03
#: Until the GNSS delay is known (an option, the replay's probe, a live run's estimate),
#: the fix's velocity is taken as measured up to this long (s) before or after the time
#: the model gives it (an ArduCopter SITL's velocity lags the IMU by 0.085 s plus half
#: its 0.35-s window), so its std per axis gains this times the vehicle's acceleration
#: (from the last two fixes) in quadrature. 0.22 s is the GPS delay ArduPilot's EKF
#: assumed for every receiver before the drivers reported their own. Without it, a live
#: run against the ArduCopter SITL rejected 14 of 15 GNSS velocities in a 3-s turn before
#: it learned the delay, then took a 22-cm position step (docs/live.md). The fix's
#: position is not widened: its lag (speed x delay) stays within its std and the gate.
UNKNOWN_GNSS_LAG_S = 0.22
#: Fixes further apart than this (s) give no acceleration for :data:`UNKNOWN_GNSS_LAG_S`.
LAG_ACCEL_MAX_DT = 1.0
#: The acceleration (m/s^2 per axis) taken for it is at most this (2 g): a larger change
#: between two fixes is a bad velocity, which the gate is there to see.
LAG_ACCEL_MAX = 20.0
#: Until the baro's delay is known (an option, the replay's probe, a live run's estimate)
#: its noise is at least this (m): an ArduCopter SITL's baro lags 18-88 ms, 0.2 m in a
#: 2.5 m/s climb, which the profile's 0.2 m took into the pitch (airborne 0.19 deg
#: against 0.07 on logs/sitl_copter.tlog; 0.09 with this floor; docs/navigation.md).
UNKNOWN_BARO_DELAY_NOISE = 0.5
#: With a velocity window, a fix's height is paired with the baro interpolated at its
#: time from the baro samples of the last this many seconds.
BARO_RECENT_S = 3.0
#: Provisional latitude (rad) for gravity before the first fix gives the true one
#: (normal gravity differs by at most 0.026 m/s^2 from its value here).
UNAIDED_LAT = float(np.deg2rad(45.0))


class NavNotStarted(NoSamplesError):
    """The stream ended before the navigation model could start (no good GNSS fix, or
    no magnetometer and never fast enough for the course)."""


@dataclass(frozen=True)
class NavOptions:
    """How samples become navigation steps (module docstring; ``uavest replay --help``).

    ``start``/``end`` s clip the stream; ``rate_hz`` None -> the
    :data:`~uavest.engine.attitude.DEFAULT_MAX_RATE_HZ` cap, 0 -> every IMU sample;
    ``integration`` auto/hold/trapezoid; ``declination`` rad east positive (None: the
    log's parameters, else 0); ``noise`` overrides of
    :class:`~uavest.models.navigation.NavNoise`; ``imu``/``gnss``/``baro`` source names
    or None (the stream's choice); ``use_mag``, ``use_baro``; ``mag_mode`` field or
    heading; ``gnss_delay`` s (None: ``NavNoise.gnss_delay``) and ``gnss_delay_why``
    where it came from (None: "option --gnss-delay" / "default"); ``mag_delay`` s, the
    magnetometer sample's age (None: 0), and ``mag_delay_why``; ``baro_delay`` s, the
    barometer sample's age (None: 0, not estimated); ``mag_noise_why``: where
    the ``mag_noise`` of ``noise`` came from (None: an option or the default), and
    ``gnss_vel_window_why`` where its ``gnss_vel_window`` came from, ``baro_delay_why``
    and ``baro_noise_why`` where the baro's delay and noise came from, ``gnss_bias_why``
    where the GNSS bias states' ``gnss_bias_*`` came from, ``mag_ref_why`` where the
    magnetic reference states' priors came from; ``mag_inclination`` rad
    (None: the World Magnetic Model's within
    :data:`~uavest.engine.nav_align.WMM_INCLINATION_TOL` of the alignment window's
    accelerometer-magnetometer angle, else that angle; ``inclination_wmm`` False: always
    that angle) and
    ``mag_inclination_why``; ``mag_site`` (lat, lon deg): where that inclination was
    learned (``--aiding-from``; a start farther than
    :data:`~uavest.engine.nav_align.MAG_SITE_KM` from it does not take it; None: no such
    check); ``align_s`` s;
    ``yaw_speed`` m/s, the ground speed from which the GNSS course gives the start yaw
    without a magnetometer; ``imu_delay`` s, the lag of the IMU's samples behind the
    motion (None: :func:`imu_filter_delay` from the log's parameters); ``before_fix``:
    with a magnetometer and no good GNSS fix :data:`UNAIDED_WAIT_ALIGNS` alignment
    windows into the IMU data, start unaided (attitude from the accelerometer and
    magnetometer, velocity and position held near the start by a constant-position
    measurement, ``NavNoise.nofix_pos_noise``) and re-anchor velocity and position at
    the first good fix, attitude and biases kept. ``on_arrival``: samples come as they
    arrive (a live link run with the engine's history, :mod:`uavest.engine.history`): a
    step is made at the IMU sample that ends it and released at once (with no GNSS
    delay), an aiding sample of its time or older that comes later being late (the
    history applies it at its time)."""

    start: float | None = None
    end: float | None = None
    rate_hz: float | None = None
    integration: str = "auto"
    declination: float | None = None
    noise: dict[str, float] = field(default_factory=dict)
    imu: str | None = None
    gnss: str | None = None
    baro: str | None = None
    use_mag: bool = True
    use_baro: bool = True
    mag_mode: str = "field"
    gnss_delay: float | None = None
    gnss_delay_why: str | None = None
    mag_delay: float | None = None
    mag_delay_why: str | None = None
    baro_delay: float | None = None
    mag_noise_why: str | None = None
    gnss_vel_window_why: str | None = None
    baro_delay_why: str | None = None
    baro_noise_why: str | None = None
    gnss_bias_why: str | None = None
    #: where the magnetic reference states' priors (``mag_ref_inc`` / ``mag_ref_dec`` of
    #: ``noise``) came from (None: the option --noise)
    mag_ref_why: str | None = None
    mag_inclination: float | None = None
    mag_inclination_why: str | None = None
    mag_site: tuple[float, float] | None = None
    inclination_wmm: bool = True
    align_s: float = 1.0
    yaw_speed: float = 3.0
    imu_delay: float | None = None
    before_fix: bool = True
    on_arrival: bool = False
    geodesy: str = "auto"

    def in_window(self, t: float) -> bool:
        """True if ``t`` (s) lies in [start, end]."""
        return (self.start is None or t >= self.start) and (self.end is None or t <= self.end)

    def __post_init__(self) -> None:
        if self.integration not in ("auto", "hold", "trapezoid"):
            raise InputError(
                f"integration must be auto, hold or trapezoid, not {self.integration!r}")
        if self.geodesy not in ("auto", *GEODESIES):
            raise InputError(f"--geodesy must be auto, {' or '.join(GEODESIES)}, not "
                             f"{self.geodesy!r}")
        if self.mag_mode not in ("field", "heading"):
            raise InputError(f"mag_mode must be field or heading, not {self.mag_mode!r}")
        known = {f.name for f in fields(NavNoise)}
        bad = sorted(set(self.noise) - known)
        if bad:
            raise InputError(f"--noise {bad[0]}: not a parameter of the navigation model; "
                             f"known: {', '.join(sorted(known))}")
        if self.mag_mode == "heading" and NavNoise().with_(**self.noise).mag_ref:
            raise InputError("--noise mag_ref_inc / mag_ref_dec: the magnetic reference "
                             "states are for the 3-D field update, not --mag-mode heading")
        for d, option, model in ((self.gnss_delay, "--gnss-delay", ""),
                                 (self.mag_delay, "--mag-delay", " for the navigation model"),
                                 (self.baro_delay, "--baro-delay", "")):
            if d is not None and not (np.isfinite(d) and 0.0 <= d <= 2.0):
                raise InputError(f"{option} must be from 0 to 2 s{model}, got {d}")


#: ArduPilot SITL parameters that uavest's own simulator also reports (it answers only
#: ``SIM_SPEEDUP``, with WGS84 lat/lon): not evidence of an ArduPilot SITL.
UAVEST_SIM_PARAMS = frozenset({"SIM_SPEEDUP"})


#: Parameters only PX4 has (ArduPilot's are ``SYSID_THISMAV`` / ``MAV_SYSID``, ``EK2_`` /
#: ``EK3_``): PX4's SITL has ``SIM_*`` parameters of its own (``SIM_BAT_DRAIN``...), and
#: its GNSS positions are not made on ArduPilot's sphere.
PX4_PARAMS = frozenset({"SYS_AUTOSTART", "MAV_SYS_ID"})


def sitl_evidence(params: dict[str, Any]) -> str | None:
    """Why the log's parameters are an ArduPilot SITL's (a ``SIM_*`` parameter, which only
    its simulator has, but :data:`UAVEST_SIM_PARAMS`), or None; None for a PX4 log (any
    of :data:`PX4_PARAMS` or an ``EKF2_*`` parameter), whose SITL has ``SIM_*`` ones too."""
    if any(isinstance(k, str) and (k in PX4_PARAMS or k.startswith("EKF2_")) for k in params):
        return None
    for k in params:
        if isinstance(k, str) and k.startswith("SIM_") and k not in UAVEST_SIM_PARAMS:
            return f"its parameter {k}"
    return None


def imu_filter_delay(source: str, params: dict[str, Any]) -> tuple[float, str]:
    """(delay s, why) of a streamed ArduPilot IMU (RAW_IMU / SCALED_IMU* / HIGHRES_IMU,
    all sent from the same filtered sensor values; ``INS_GYRO_FILTER``, an ArduPilot
    parameter, tells the autopilot): the gyro and accelerometer after its 2-pole
    Butterworth low-pass (``INS_GYRO_FILTER`` Hz), whose group delay at low frequency is
    sqrt(2) / (2 pi f_c) (11.3 ms at 20 Hz; measured on the SITL copter flight: the
    airborne attitude RMSE is least with the estimate 10-15 ms earlier). 0 for other
    sources or without the parameter."""
    fc = params.get("INS_GYRO_FILTER")
    if not source.upper().startswith(("RAW_IMU", "SCALED_IMU", "HIGHRES_IMU")):
        return 0.0, "not a streamed ArduPilot IMU"
    if not isinstance(fc, (int, float)) or not np.isfinite(fc) or fc <= 0:
        return 0.0, "no INS_GYRO_FILTER parameter in the log"
    return float(np.sqrt(2.0) / (2.0 * np.pi * fc)), (
        f"group delay of the autopilot's {fc:g} Hz IMU low-pass (INS_GYRO_FILTER)")


class _NavBuilder(_StepBuilder):
    """The attitude path's step builder with the specific force of every step (the
    time-weighted trapezoid mean for snapshot IMUs, the plain mean for integrated ones)."""

    def __init__(self, integration: str, factor: int, close_now: bool = False) -> None:
        super().__init__(integration, factor, False, 1, 1, close_now)
        self.a_edge: Array | None = None

    def push_nav(self, s: ImuSample | MagSample) -> list[_Raw | _Gap]:
        """:meth:`_StepBuilder.push` for the stream's own IMU / magnetometer samples."""
        out: list[_Raw | _Gap] = list(self.push(s))
        if isinstance(s, ImuSample) and self.t_edge == s.t:
            self.a_edge = s.accel
        return out

    def _close(self) -> _Raw:
        b = self.block
        r: _Raw = super()._close()
        self.a_edge = b[-1].accel
        return r

    def _accel_mean(self, b: list[ImuSample]) -> Array | None:
        """Snapshot IMUs (``trapezoid``): the specific force linear between samples, the
        step's time-weighted mean from the edge's sample on (Python floats: numpy's
        per-call cost on a block of 3-vectors was a tenth of the stream's work); else the
        attitude path's mean."""
        t0, a0 = self.t_edge, self.a_edge
        if self.integration == "trapezoid" and a0 is not None and t0 is not None:
            tp, (px, py, pz) = t0, a0.tolist()
            sx = sy = sz = span = 0.0
            for s in b:
                dt = s.t - tp
                x, y, z = s.accel.tolist()
                sx += 0.5 * (x + px) * dt
                sy += 0.5 * (y + py) * dt
                sz += 0.5 * (z + pz) * dt
                span += dt
                tp, px, py, pz = s.t, x, y, z
            if span > 0:
                return np.array([sx / span, sy / span, sz / span])
        return super()._accel_mean(b)


def split_step(r: _Raw, max_step: float) -> list[_Raw]:
    """A step longer than ``max_step`` (s; an IMU interval below the gap threshold but
    several nominal steps long) as equal sub-steps with the same rate and specific force,
    the magnetometer on the last: aiding measurements inside the interval then update at
    their own times and each prediction stays short (one 3.4 s prediction left the
    sigma-point filters' attitude 30-160 deg off on vtol.tlog)."""
    dt = r.t - r.t0
    if not dt > max_step:
        return [r]
    k = int(np.ceil(dt / max_step))
    ts = r.t0 + dt * np.arange(k + 1) / k
    out = [_Raw(float(ts[i + 1]), float(ts[i]), r.w, r.a, 0, None, r.accel_ned)
           for i in range(k - 1)]
    out.append(_Raw(r.t, float(ts[k - 1]), r.w, r.a, r.n, r.mag, r.accel_ned))
    return out


class NavStream(LateDeclination, StreamSnapshots, HeldAlignment):
    """One :class:`Start` then navigation :class:`Step` s from a sample stream (module
    docstring). :meth:`push` / :meth:`flush` return the items they completed; iterating
    runs over ``samples``. :attr:`summary` has the keys of the attitude stream's summary
    (sources, rates, integration, steps, decisions...) plus ``gnss_source``,
    ``baro_source``, ``origin`` and ``aiding`` (per sensor: used and skipped counts).

    Its parts: the aiding samples waiting for their steps (:class:`AidQueues`,
    :mod:`~uavest.engine.nav_aiding`), the alignment's state and window
    (:class:`AlignWindow`) and arithmetic (:mod:`~uavest.engine.nav_align`); the stream
    makes the steps, the starts and the decisions."""

    def __init__(self, samples: Iterable[Any] = (), opts: NavOptions | None = None,
                 params: dict[str, Any] | None = None) -> None:
        self.samples = samples
        self.opts = opts or NavOptions()
        self.params: dict[str, Any] = {} if params is None else params
        self.space = NavSpace()
        self.noise: NavNoise = NavNoise().with_(**self.opts.noise)
        #: the IMU source's noise profile, before the options' overrides
        self.source_noise: NavNoise = NavNoise()
        self.summary: dict[str, Any] = {}
        self.decisions: list[dict[str, Any]] = []
        self.declination = 0.0
        self.delay = 0.0
        self.vel_window = 0.0  # s, NavNoise.gnss_vel_window
        #: the window is known (given or estimated, even as 0): else the velocity floor is
        #: at least UNMODELLED_WINDOW_VEL_FLOOR
        self.window_known = False
        self.baro_known = False  # the baro delay given or estimated
        #: (noise m, offset m) the baro was refit to at its learnt delay
        #: (:meth:`set_baro_fit`; None: not)
        self.baro_fit: tuple[float, float | None] | None = None
        self.delay_known = False  # the GNSS delay given or estimated
        #: the last fix's (time s, NED velocity m/s), for the acceleration that sizes the
        #: velocity's timing term while the delay is not known (UNKNOWN_GNSS_LAG_S)
        self._vfix_last: tuple[float, Array] | None = None
        self._aid_noise: NavNoise | None = None  # the aids' noise (:meth:`_noise_for_aids`)
        self._bias_pending = False  # GNSS bias states set: restart with them at next step
        #: rad^2 to add to the tilt variance at the next step (a new inclination)
        self._tilt_pending = 0.0
        #: the last steps released (end s, length s, rate, specific force) while a
        #: velocity window needs them (:func:`~uavest.engine.nav_aiding.window_force`)
        self._recent: deque[tuple[float, float, Array, Array]] = deque()
        #: the baro samples (time s, height m) of the last BARO_RECENT_S with a window
        self._baro_recent: deque[tuple[float, float]] = deque()
        self.imu_delay = 0.0
        self.frame: LocalFrame | SphereFrame | None = None
        #: why the stream is taken as an ArduPilot SITL's (its lat/lon on ArduPilot's
        #: sphere, :func:`sitl_evidence`), None while nothing says so
        self._sitl: str | None = None
        self._held: list[Any] | None = []
        self._imu_t0: float | None = None
        self._builder: _NavBuilder | None = None
        self._imu: str | None = None
        self._mag: str | None = None
        self._model: ImuTransition | None = None
        #: the accelerometer density that follows the flight's roughness (nav_rough)
        self._rough = RoughDensity()
        self._queue: deque[_Raw] = deque()
        #: the aiding samples waiting for their steps, the GNSS and baro choice, the
        #: per-sensor counts and the baro offset
        self._aids = AidQueues(self.opts.gnss, self.opts.baro)
        self.mag_delay = 0.0  # s, the magnetometer sample's age (NavOptions.mag_delay)
        self.baro_delay = 0.0  # s, the barometer sample's age (NavOptions.baro_delay)
        #: s after a step's end whose aids it takes: half a nominal step (an aid goes to
        #: the step whose end is nearest to it), or 0 on arrival
        self._aid_window = 0.0
        #: the alignment's state and the window it levels from
        self._align = AlignWindow()
        self._other_imu: dict[str, list[float]] = {}  # failover evidence per other IMU
        self._t_hold = -np.inf
        #: vehicle time (s) from which positions are in :attr:`frame` (the first-fix
        #: re-anchoring); None when the stream started at a fix
        self.fix_from: float | None = None
        self.max_step = np.inf  # s, set from the IMU's rate (_split)
        self._anchor_sample: NavAnchor | None = None  # for the sinks, with the next step
        self._t_out: float | None = None  # end of the last released step
        self._now = -np.inf
        self._k = 0
        self._imu_n = [0, 0.0, 0.0]
        self._mref: Array | None = None
        #: (the start's accelerometer-magnetometer angle, the magnetic model's
        #: inclination, the model's why), rad, when the start took the first for being
        #: beyond the tolerance of the second: an accelerating start and a local field
        #: look alike, and a live run's learner judges between them later
        #: (:meth:`set_mag_inclination`); None otherwise
        self.inclination_choice: tuple[float, float, str] | None = None
        #: ``--mag-mode heading``: the heading std is ``mag_noise`` times this
        #: (:func:`~uavest.engine.nav_align.heading_noise_scale`, set at the first start)
        self._heading_scale = 1.0
        self._decl_pending = False
        self._decl_seen: tuple[Any, ...] | None = None
        self._yaw_turn = 0.0  # LateDeclination
        #: a fix has shown a ground speed of ``yaw_speed`` or more: the GNSS has had a say
        #: in the yaw, which a declination learnt now does not turn
        self._moved = False

    @property
    def gnss_source(self) -> str | None:
        """The GNSS receiver the stream uses (None: not chosen yet)."""
        return self._aids.gnss

    def _noise_for_aids(self) -> NavNoise:
        """:attr:`noise` for the GNSS and baro updates: while the GNSS velocity's window
        is not known its floor at least :data:`UNMODELLED_WINDOW_VEL_FLOOR`, while the
        baro's delay is not known its noise at least :data:`UNKNOWN_BARO_DELAY_NOISE`."""
        if self._aid_noise is None:
            n = self.noise
            if not self.window_known:
                n = n.with_(gnss_vel_floor=max(n.gnss_vel_floor, UNMODELLED_WINDOW_VEL_FLOOR))
            if not self.baro_known:
                n = n.with_(baro_noise=max(n.baro_noise, UNKNOWN_BARO_DELAY_NOISE))
            self._aid_noise = n
        return self._aid_noise

    @property
    def baro_source(self) -> str | None:
        """The barometer the stream uses (None: not chosen yet, or no baro)."""
        return self._aids.baro if self.opts.use_baro else None

    @property
    def aiding(self) -> dict[str, dict[str, int]]:
        """Per sensor, the counts of what was used and skipped (``used``, ``late``,
        ``held``, ``nan``...)."""
        return self._aids.counts

    @property
    def mag_source(self) -> str | None:
        """The magnetometer the stream uses (None: none, or not chosen yet)."""
        return self._mag

    # ------------------------------------------------------------------ bookkeeping
    def _decide(self, what: str, value: Any, t: float, why: str) -> None:
        """Record a decision ``what`` = ``value`` from ``t`` (s) because ``why``."""
        self.decisions.append({"what": what, "value": value, "t": float(t), "why": why})
        self.summary["decisions"] = self.decisions

    def set_gnss_delay(self, delay: float, t: float, why: str) -> None:
        """From now on a fix stamped t measures the state at t - ``delay`` (s; a live run's
        estimate, :class:`~uavest.engine.gnss_delay.LiveDelayLearner`), decided at ``t``
        (s) because ``why``; fixes already queued keep their time. Before the stream's
        set-up (no IMU window yet) it waits: the options' delay is taken then."""
        if self._builder is None:
            return
        self.delay = float(delay)
        self.delay_known = True
        self.summary["gnss_delay_s"] = self.delay
        self._decide("GNSS delay", f"{self.delay:.3f} s", t, why)

    def set_gnss_window(self, window: float, t: float, why: str) -> None:
        """From now on the GNSS velocity is the mean over ``window`` s (as
        :meth:`set_gnss_delay`; fixes already queued keep theirs)."""
        if self._builder is None:
            return
        self.vel_window = float(window)
        self.window_known = True
        self._aid_noise = None
        self.summary["gnss_vel_window_s"] = self.vel_window
        self._decide("GNSS velocity window", f"{self.vel_window:.3f} s", t, why)

    def set_baro_delay(self, delay: float, t: float, why: str) -> None:
        """From now on a baro sample stamped t measures the height at t - ``delay`` (s; as
        :meth:`set_gnss_delay`)."""
        if self._builder is None:
            return
        self.baro_delay = float(delay)
        self.baro_known = True
        self._aid_noise = None
        self.summary["baro_delay_s"] = self.baro_delay
        self._decide("baro delay", f"{self.baro_delay * 1e3:.0f} ms", t, why)

    def set_mag_noise(self, noise: float, t: float, why: str) -> None:
        """From now on the magnetometer's noise is ``noise`` (rad, the std of the field's
        direction per axis, as ``NavNoise.mag_noise``): a live run's estimate (``why``;
        :class:`~uavest.engine.gnss_delay.LiveDelayLearner`, which is not asked to learn it
        when an option or the vehicle's spec gave it)."""
        if self._builder is None:
            return
        self.noise = self.noise.with_(mag_noise=float(noise))
        self._aid_noise = None
        self._decide("magnetometer noise", f"{noise:.3f} rad", t, why)

    def set_baro_fit(self, noise: float, offset: float | None, t: float, why: str) -> None:
        """From now on the baro's noise is ``noise`` (m; not when ``--noise baro_noise``
        gave one) and its offset to the GNSS height ``offset`` (m, baro height minus GNSS
        altitude, as :attr:`~uavest.engine.gnss_delay.BaroEstimate.offset`; None: the
        running one kept), both learnt at the baro's delay (``why``). The running offset,
        averaged while the baro's timing was not known, is off by more than the noise: a
        live ArduCopter SITL's 6 cm against its 0.02 m (docs/live.md). The running mean
        goes on from the new offset (in a WGS84 tangent frame the GNSS height is the
        altitude less the origin's less the Earth's curvature, d^2 / 2R: 7 mm at 300 m from
        the origin, left to the running mean)."""
        if self._builder is None:
            return
        self.baro_fit = (float(noise), offset)
        o = self.opts
        if "baro_noise" not in o.noise or o.baro_noise_why:
            self.noise = self.noise.with_(baro_noise=float(noise))
            self._aid_noise = None
            self._decide("baro noise", f"{noise:.3f} m", t, why)
        old = self._aids.baro_offset
        if offset is not None and old is not None and self.frame is not None:
            new = float(offset) + self.frame.h0
            self._aids.baro_offset = new
            self.summary["baro_offset_m"] = new
            self._decide("baro offset", f"{new:.2f} m", t,
                         f"refit at the baro's delay with its noise (was {old:.2f} m, "
                         "averaged while the baro's timing was not known; running mean "
                         "from here)")

    def restore(self, snap: dict[str, Any]) -> None:
        """:meth:`StreamSnapshots.restore`, the state space following the restored noise
        (GNSS bias states set after the snapshot are set again by who set them)."""
        super().restore(snap)
        self.space = nav_space(self.noise)

    def set_gnss_bias(self, bias: dict[str, float], t: float, why: str) -> None:
        """From the next step on the state carries GNSS bias states of ``bias``
        (``gnss_bias_h``, ``gnss_bias_v`` m, ``gnss_bias_tau`` s): a restart whose prior
        is each filter's running estimate with them appended
        (:func:`~uavest.engine.nav_align.add_gnss_bias`). Nothing when the state has them
        already or ``--noise`` named them."""
        if (self._builder is None or self.noise.gnss_bias
                or names_gnss_bias(self.opts.noise)):
            return
        self.noise = self.noise.with_(**bias)
        self.space = nav_space(self.noise)
        if self._model is not None:
            self._model = self._model.with_noise(self.noise)
        self._aid_noise = None
        self._bias_pending = True
        n = self.noise
        self.summary["gnss_bias"] = {"h_m": n.gnss_bias_h, "v_m": n.gnss_bias_v,
                                     "tau_s": n.gnss_bias_tau, "t": float(t)}
        self._decide_bias(t, why)

    def _decide_bias(self, t: float, why: str) -> None:
        """The decision line of the GNSS bias states the noise has."""
        n = self.noise
        self._decide("GNSS bias states", f"{n.gnss_bias_h:.2f} m horizontal, "
                     f"{n.gnss_bias_v:.2f} m vertical, {n.gnss_bias_tau:.0f} s", t, why)

    def __iter__(self) -> Iterator[Start | Step]:
        for s in self.samples:
            yield from self.push(s)
        yield from self.flush()

    # ------------------------------------------------------------------ history
    # (the engine's history, :mod:`uavest.engine.history`: samples on arrival)
    @property
    def _aid_age(self) -> float:
        """The largest of the GNSS delay and the magnetometer's and barometer's ages (s):
        a fix stamped t is applied at t - delay, a magnetometer or baro sample at t - its
        age."""
        return max(self.delay, self.mag_delay, self.baro_delay)

    @property
    def _hold(self) -> float:
        """s the stream holds closed steps: :attr:`_aid_age` and the aid window."""
        return self._aid_age + self._aid_window

    @property
    def committed(self) -> float:
        """End (s) of the last step released, plus :attr:`_aid_age`: an aid at or before
        it may be late."""
        return -np.inf if self._t_out is None else self._t_out + self._aid_age

    def order_sensitive(self, s: Any) -> bool:
        """The chosen IMU and magnetometer, the GNSS receiver (any before one is chosen)
        and the barometer: each changes the step it lands in."""
        if self._held is not None:
            return True
        if isinstance(s, ImuSample):
            return s.source == self._imu
        if isinstance(s, MagSample):
            return s.source == self._mag
        if isinstance(s, GnssSample):
            return self._aids.gnss is None or s.source == self._aids.gnss
        if isinstance(s, BaroSample):
            return self.opts.use_baro and (self._aids.baro is None
                                           or s.source == self._aids.baro)
        return False

    # ------------------------------------------------------------------ pushing
    def push(self, s: Any) -> list[Start | Step]:
        """Feed one sample; returns the items (start, steps) it completed."""
        o = self.opts
        if self._sitl is None and type(s) is AttitudeRef and s.source == "SIM_STATE":
            self._sitl = "SIM_STATE, an ArduPilot SITL's truth, in the stream"
        if not o.in_window(s.t):
            return []
        self._aids.seen(s)
        held = self._held_push(s)
        return self._feed(s) if held is None else held

    def flush(self) -> list[Start | Step]:
        """End of the stream: close and release the last steps."""
        out = self._held_flush()
        assert self._builder is not None
        for r in self._builder.flush():
            self._queue.append(r)
        self._now = np.inf
        out += self._release()
        self._finish_summary()
        if not self._align.started:
            raise NavNotStarted(
                "the navigation model could not start: " + self._align.why
                + " (GNSS sources seen: " + (", ".join(sorted(self._aids.gnss_srcs)) or "none")
                + "; use --model attitude)")
        return out

    def _feed(self, s: Any) -> list[Start | Step]:
        b = self._builder
        assert b is not None
        raws: list[_Raw | _Gap] = []
        if isinstance(s, ImuSample):
            if s.source != self._imu:
                return self._failover(s) if self.opts.imu is None else []
            if not finite3(s.gyro, s.accel):
                self._aids.count("imu", "nan")
                return []
            self._imu_n[0] += 1
            self._imu_n[2] = s.t
            raws = b.push_nav(s)
        elif isinstance(s, MagSample):
            if s.source != self._mag:
                return []
            raws = b.push_nav(s)
            self._aids.add_mag(s, self.mag_delay)
        elif isinstance(s, GnssSample):
            self._gnss_sample(s)
        elif isinstance(s, BaroSample):
            self._baro_sample(s)
        else:
            return []
        self._now = max(self._now, s.t)
        out: list[Start | Step] = []
        for r in raws:
            if isinstance(r, _Gap):
                out += self._release(upto=r.t0)
                self._queue.clear()
                self._go_wait(f"re-alignment after an IMU gap of {r.t1 - r.t0:.1f} s",
                              r.t1)
            else:
                self._queue.extend(self._split(r))
        return out + self._release()

    def _split(self, r: _Raw) -> list[_Raw]:
        """:func:`split_step` of ``r`` at :attr:`max_step`, counted in the summary."""
        out = split_step(r, self.max_step)
        if len(out) > 1:
            dt = r.t - r.t0
            self.summary["imu_split_intervals"] = self.summary.get("imu_split_intervals",
                                                                   0) + 1
            self.summary["imu_split_longest_s"] = max(
                self.summary.get("imu_split_longest_s", 0.0), dt)
        return out

    def _failover(self, s: ImuSample) -> list[Start | Step]:
        """The IMU choice re-decided when the evidence arrives, as the attitude stream
        does (:meth:`uavest.engine.attitude.AttitudeStream._failover`): the chosen IMU
        silent for longer than the gap threshold while ``s.source`` delivered
        :data:`FAILOVER_SAMPLES` samples since its last one. Then ``s.source`` is the IMU
        from ``s.t`` (its own noise, rate and integration) and the filters re-align at
        the next good fix (biases not kept: they belong to the other sensor)."""
        b = self._builder
        assert b is not None
        if not finite3(s.gyro, s.accel):
            return []
        last = b.t_last if b.t_last is not None else s.t
        rate = failover_rate(self._other_imu, s, last, b.gap_s)
        if rate is None:
            return []
        o, old = self.opts, self._imu
        integ, why, factor = step_plan(s.source, rate, o.integration, o.rate_hz)
        for r in b.flush():  # what the silent IMU left, before the switch
            self._queue.append(r)
        out = self._release(upto=last)
        self._queue.clear()
        nb = _NavBuilder(integ, factor, o.on_arrival)
        nb.gaps, nb.dropped = b.gaps, b.dropped
        nb.gap_s = max(GAP_MIN_S, GAP_MEDIANS / max(rate, 1e-9))
        nb.gaps.append((last, s.t))
        self._builder = nb
        self._imu, self._align.switched = s.source, True
        if self._mag == old:  # that sensor's magnetometer went with it
            self._mag = s.source if self._mag is not None else None
        self._set_noise(s.source, rate)
        if self.frame is not None:
            self._model = ImuTransition(self.noise, lat=self.frame.lat0, h=self.frame.h0)
        self._other_imu.pop(s.source)
        self.summary.setdefault("imu_switches", []).append(
            {"from": old, "to": s.source, "t": float(s.t)})
        self._decide("IMU", s.source, s.t,
                     f"{old} silent since t={last:.1f} s ({s.t - last:.1f} s), {s.source} "
                     f"continued ({rate:.1f} Hz, {integ}: {why})")
        self._go_wait(f"re-alignment after the switch to {s.source}", s.t)
        return out + self._feed(s)

    def _go_wait(self, why: str, t: float) -> None:
        self._align.wait(why)
        self._decide("navigation", "waiting for a good GNSS fix", t, why)

    # ------------------------------------------------------------------ aiding input
    def _gnss_sample(self, s: GnssSample) -> None:
        """Queue a fix of the GNSS receiver (chosen at its first 3-D fix); the first
        3-D fix with a height sets the local frame's origin."""
        if self._aids.choose_gnss(s):
            self._decide("GNSS", s.source, s.t, "option --gnss" if self.opts.gnss else
                         "first receiver with a 3-D fix (raw, not the autopilot's fused "
                         "position)")
        lla = self._aids.gnss_lla(s)
        if lla is None:
            return
        if self.frame is None:
            if s.fix_type < 3 or not np.isfinite(lla[2]):
                return
            geo, why = self._geodesy()
            self.frame = make_frame(lla[0], lla[1], lla[2], geo)
            self.summary["origin"] = {"lat": float(lla[0]), "lon": float(lla[1]),
                                      "alt": float(lla[2])}
            self.summary["geodesy"] = geo
            self._decide("geodesy", "ArduPilot's sphere" if geo == "sphere" else "WGS84",
                         s.t, why)
            lat = np.deg2rad(lla[0])
            self._model = ImuTransition(self.noise, lat=lat, h=float(lla[2]))
        self._aids.add_gnss(s, lla, self.frame, self.delay, self.vel_window)

    def _geodesy(self) -> tuple[str, str]:
        """(the local frame's geodesy, why): the option, else ArduPilot's sphere for an
        ArduPilot SITL (:func:`sitl_evidence`), else WGS84."""
        if self.opts.geodesy != "auto":
            return self.opts.geodesy, "option --geodesy"
        why = self._sitl or sitl_evidence(self.params)
        if why is not None:
            return "sphere", (f"an ArduPilot SITL ({why}): its GNSS lat/lon are made from "
                              "its metric positions on ArduPilot's sphere; --geodesy wgs84 "
                              "to override")
        return "wgs84", "a receiver's lat/lon (no ArduPilot SITL seen; --geodesy to set it)"

    def _baro_sample(self, s: BaroSample) -> None:
        if not self.opts.use_baro:
            return
        if self._aids.choose_baro(s):
            self._decide("baro", s.source, s.t, "option --baro" if self.opts.baro else
                         "first barometer in the stream")
            o = self.opts
            self._decide("baro delay", f"{self.baro_delay * 1e3:.0f} ms", s.t,
                         (o.baro_delay_why or ("option --baro-delay" if o.baro_delay
                                               is not None else "default"))
                         + ("" if self.baro_known else
                            f"; until it is known the baro noise is at least "
                            f"{UNKNOWN_BARO_DELAY_NOISE:g} m"))
            if o.baro_noise_why:
                self._decide("baro noise", f"{self.noise.baro_noise:.3f} m", s.t,
                             o.baro_noise_why)
            self.summary["baro_delay_s"] = self.baro_delay
        self._aids.add_baro(s, self.baro_delay)

    # ------------------------------------------------------------------ releasing steps
    def _release(self, upto: float | None = None) -> list[Start | Step]:
        out: list[Start | Step] = []
        lim = self._now - self._hold if upto is None else upto
        incl = upto is not None or (self.opts.on_arrival and not self._hold > 0)
        while self._queue and (self._queue[0].t < lim or (incl and self._queue[0].t <= lim)):
            r = self._queue.popleft()
            aids = self._aids.take(self._stamp(r) + self._aid_window, self._t_out)
            self._t_out = self._stamp(r) + self._aid_window
            if self._align.waiting:
                out += self._try_start(r, aids)
            elif self._align.unaided:
                fix = good_fix(aids)
                if fix is not None:
                    out += self._anchor(r, fix)
                else:
                    out += self._restarts(r)
                    out.append(self._step(r, [a for a in aids if a.sensor != "gnss"]))
            else:
                out += self._restarts(r)
                out.append(self._step(r, aids))
        return out

    def _restarts(self, r: _Raw) -> list[Start]:
        """The restarts due before the step of ``r``, each from every filter's running
        estimate: the yaw turned by a declination learnt since the last step
        (:meth:`_check_declination`), the GNSS bias states appended once set
        (:meth:`set_gnss_bias`), the tilt variance widened for a new inclination
        (:meth:`set_mag_inclination`)."""
        t0 = self._stamp(r)
        out = self._turn_start(r.t, t0, self._size_prior)
        if self._bias_pending:
            self._bias_pending = False
            out.append(Start(t0, self._size_prior(), self.space,
                             reason="GNSS bias states",
                             augment=partial(add_gnss_bias, noise=self.noise)))
        if self._tilt_pending:
            var, self._tilt_pending = self._tilt_pending, 0.0
            out.append(Start(t0, self._size_prior(), self.space, reason="inclination",
                             augment=partial(widen_tilt, var=var)))
        return out

    def _size_prior(self) -> Gaussian:
        """A prior of the state's size for a restart from the running estimates
        (``Start.augment``: it only gives the size)."""
        x, P = with_mag_ref(*with_gnss_bias(np.r_[1.0, np.zeros(15)], np.eye(15),
                                            self.noise, False), self.noise)
        return Gaussian(x, P)

    def _try_start(self, r: _Raw, aids: list[_Aid]) -> list[Start | Step]:
        o, al = self.opts, self._align
        fix = al.add(r, aids, o.align_s)
        mags = al.mags()
        use_mag = self._mag is not None and bool(mags)
        if (fix is not None and al.recent
                and r.t - al.recent[0].t0 < ALIGN_SPAN * o.align_s):
            # the level needs the accelerometer's mean over the alignment window: one
            # 200 Hz sample with the airframe's vibration in it left sim_200hz's pitch
            # 2 deg off (seed 5) until the manoeuvres separated it from the accel bias
            al.why = (f"{r.t - al.recent[0].t0:.2f} s of IMU data for the level "
                      f"(needs {ALIGN_SPAN * o.align_s:g} s)")
            return []
        if fix is None and not al.started and al.recent and use_mag and o.before_fix \
                and r.t - self._imu_n[1] >= UNAIDED_WAIT_ALIGNS * o.align_s:
            return self._start_unaided(r, mags)
        if fix is None or fix.gnss is None or fix.ned is None or not al.recent:
            return []
        g = fix.gnss
        vh = np.asarray(g.vel_ned[:2], float)
        speed = float(np.hypot(vh[0], vh[1]))
        if not use_mag and speed < o.yaw_speed:
            al.why = (f"no magnetometer: waiting for a GNSS ground speed of "
                      f"{o.yaw_speed:g} m/s for the course (fastest so far "
                      f"{max(speed, self.summary.get('_vmax', 0.0)):.1f} m/s)")
            self.summary["_vmax"] = max(speed, self.summary.get("_vmax", 0.0))
            return []
        first = not al.started
        if not first and speed >= o.yaw_speed and len(al.vfix) < 2:
            al.why = ("moving after an IMU gap: waiting for a second GNSS velocity "
                      "(the acceleration to take out of the accelerometer)")
            return []
        if first:
            self._first_start(r)
        # the vehicle's own acceleration over the window, out of the accelerometer
        a_ned = gnss_acceleration(al.vfix, r.t - o.align_s - 0.25)
        q, syaw, ywhy = level(al.recent, a_ned, mags if use_mag else [], vh, self.noise,
                              self.declination)
        n = self.noise
        # moving, the compensation rests on a differenced GNSS velocity: a wider tilt prior
        tilt = n.init_tilt if speed < o.yaw_speed else 3.0 * n.init_tilt
        v, p, pv = fix_prior(fix, self._stamp(r) - fix.t + 0.5 * fix.span, self.noise)
        x, P = fix_start(q, tilt, syaw, v, p, pv, n)
        al.done()
        if al.unaided:
            self._anchored(r)
        elif first:
            self._announce(r, "start at a GNSS fix")
        comp = (f" less the GNSS acceleration ({np.linalg.norm(a_ned):.1f} m/s^2)"
                if np.any(a_ned) else "")
        why = (f"roll/pitch from the accelerometer{comp}, yaw from {ywhy}, velocity and "
               f"position from the {self._aids.gnss} fix at t={g.t:.1f} s")
        self._decide("alignment", "done" if first else "re-aligned", r.t, why)
        kx, kp = ((), ()) if first or al.switched else kept_biases(self.space)
        al.switched = False
        return [Start(self._stamp(r), Gaussian(x, P), self.space,
                      reason="start" if first else "gap", keep_x=kx, keep_P=kp)]

    def _start_unaided(self, r: _Raw, mags: list[Any]) -> list[Start | Step]:
        """The first start without a GNSS fix (``NavOptions.before_fix``): level from the
        accelerometer, yaw from the magnetometer, velocity 0 +- ``init_vel``, position at
        the provisional origin; gravity at :data:`UNAIDED_LAT` until the fix."""
        n = self.noise
        self._first_start(r)
        if self._model is None:
            self._model = ImuTransition(self.noise, lat=UNAIDED_LAT, h=0.0)
        q, syaw, ywhy = level(self._align.recent, np.zeros(3), mags, np.zeros(2), self.noise,
                              self.declination)
        x, P = unaided_start(q, syaw, n)
        self._align.done()
        self._align.unaided = True
        wait = UNAIDED_WAIT_ALIGNS * self.opts.align_s
        self._decide("alignment", "done without a GNSS fix", r.t,
                     f"no good GNSS fix {wait:g} s into the IMU data: roll/pitch from the "
                     f"accelerometer, yaw from {ywhy}; velocity and position held near the "
                     f"start ({n.nofix_pos_noise:g} m constant-position measurement) until "
                     "the first fix")
        return [Start(self._stamp(r), Gaussian(x, P), self.space, reason="start")]

    def _stamp(self, r: _Raw) -> float:
        """The time (s) the step ``r`` describes: its samples' end less the IMU delay."""
        return r.t - self.imu_delay

    def _anchored(self, r: _Raw) -> None:
        """The unaided run ends at ``r``: positions are in :attr:`frame` from here."""
        self._align.unaided = False
        self.fix_from = self.summary["fix_from_t"] = self._stamp(r)
        self._announce(r, "first fix after an unaided start")

    def _announce(self, r: _Raw, reason: str) -> None:
        """The frame's origin and the time from which positions are in it, handed to the
        sinks with the next step (:class:`~uavest.engine.records.NavAnchor`)."""
        o = self.summary.get("origin")
        if o is not None:
            self._anchor_sample = NavAnchor(self._stamp(r), o["lat"], o["lon"], o["alt"],
                                            str(self._aids.gnss), reason,
                                            self.summary["geodesy"])

    def _anchor(self, r: _Raw, fix: _Aid) -> list[Start | Step]:
        """The first good fix after an unaided start: velocity and position from it, the
        running attitude, IMU biases and magnetic reference errors kept
        (:func:`~uavest.engine.nav_align.kept_biases`)."""
        n, g = self.noise, fix.gnss
        assert g is not None
        v, p, pv = fix_prior(fix, self._stamp(r) - fix.t + 0.5 * fix.span, self.noise)
        x, P = anchor_start(v, p, pv, n)
        self._anchored(r)
        self._align.vfix.clear()
        self._decide("alignment", "velocity and position from the first fix", r.t,
                     f"the {self._aids.gnss} fix at t={g.t:.1f} s; attitude and biases kept "
                     "from the unaided start")
        kx, kp = kept_biases(self.space)
        return [Start(self._stamp(r), Gaussian(x, P), self.space, reason="first fix",
                      keep_x=(0, 1, 2, 3, *kx), keep_P=(0, 1, 2, *kp))]

    def _given_inclination(self, t: float) -> float | None:
        """``opts.mag_inclination``, unless it was learned at a place (``opts.mag_site``)
        more than :data:`~uavest.engine.nav_align.MAG_SITE_KM` from this run's origin
        (then None, and the decision says why)."""
        o = self.opts
        inc: float | None = o.mag_inclination
        if inc is None or o.mag_site is None or self.frame is None:
            return inc
        # the place in this run's own frame (tangent plane or ArduPilot's sphere)
        n, e, _ = self.frame.geodetic_to_ned(np.array(o.mag_site[0]), np.array(o.mag_site[1]),
                                             np.array(self.frame.h0))
        km = math.hypot(float(n), float(e)) / 1e3
        if km <= MAG_SITE_KM:
            return inc
        self._decide("inclination given", "not taken", t,
                     f"{o.mag_inclination_why or 'given'}, learned {km:.0f} km from this "
                     f"run's origin (more than {MAG_SITE_KM:g} km: another site's field)")
        return None

    def _first_start(self, r: _Raw) -> None:
        """Declination and the magnetic reference, at the first start."""
        o = self.opts
        self._first_declination(r.t)
        if self._mag is None:
            return
        inc, why, alt = start_inclination(self._align.recent, self.params,
                                          self._given_inclination(r.t),
                                          o.mag_inclination_why, o.inclination_wmm)
        if o.mag_mode == "heading":
            self._heading_scale, hwhy = heading_noise_scale(inc, why)
            self._decide("magnetometer heading noise",
                         f"{self.noise.mag_noise * self._heading_scale:.4f} rad", r.t, hwhy)
        elif inc is not None:
            self._mref = mag_reference(self.declination, inc)
            self.summary["inclination_rad"] = float(inc)
            if self.space.mag:
                why += ("; the filters' magnetic reference states learn its error (no "
                        "later judgement of it)")
                gap = abs(float(inc) - alt[0]) if alt is not None else 0.0
                if gap > self.noise.mag_ref_inc:
                    # the window's angle and the model's disagree by that much: a prior
                    # narrower than that would hold the filters to the angle taken
                    self.noise = self.noise.with_(mag_ref_inc=gap)
                    why += (f", its prior std widened to {np.degrees(gap):.2f} deg, the "
                            "distance from the magnetic model's")
            self._decide("inclination", f"{np.degrees(inc):.2f} deg", r.t, why)
            # with the states, a later change of the reference would move the field the
            # filters have learnt (relative to this one) by the change
            if alt is not None and not self.space.mag:
                self.inclination_choice = (float(inc), *alt)

    def mag_ref_learnt(self, runner: FilterRunner) -> dict[str, float] | None:
        """The magnetic field a filter has learnt with the magnetic reference states
        (:attr:`NavNoise.mag_ref`): the reference's inclination and declination plus
        the filter's last estimate of their errors, with its std (deg; JSON
        ``mag_ref``); None without the states, a 3-D reference or an estimate."""
        if not self.space.mag or self._mref is None or runner.state is None:
            return None
        g = runner.filter.estimate(runner.state)
        if len(g.x) != self.space.size:
            return None
        e, sd = g.x[self.space.mag_slice], np.sqrt(np.diag(g.P)[-2:])
        inc0, dec0 = reference_inclination(self._mref), reference_declination(self._mref)
        return {"inclination_deg": float(np.degrees(inc0 + e[0])),
                "inclination_sd_deg": float(np.degrees(sd[0])),
                "declination_deg": float(np.degrees(dec0 + e[1])),
                "declination_sd_deg": float(np.degrees(sd[1])),
                "reference_inclination_deg": float(np.degrees(inc0)),
                "reference_declination_deg": float(np.degrees(dec0))}

    def gyro_drift_learnt(self, runner: FilterRunner) -> dict[str, list[float]] | None:
        """The gyro bias's rate a filter has learnt with the gyro drift states
        (:attr:`NavNoise.gyro_drift`): its last estimate and std per body axis, deg/s per
        minute (JSON ``gyro_drift``); None without the states or an estimate."""
        if not self.space.drift or runner.state is None:
            return None
        g = runner.filter.estimate(runner.state)
        if len(g.x) != self.space.size:
            return None
        sl = self.space.drift_slice
        sd = np.sqrt(np.diag(g.P)[self.space.drift_tangent])
        k = float(np.degrees(60.0))  # rad/s^2 -> deg/s per minute
        return {"deg_s_per_min": [float(v) * k for v in g.x[sl]],
                "sd_deg_s_per_min": [float(v) * k for v in sd]}

    def learnt(self, runner: FilterRunner) -> dict[str, Any]:
        """A filter's JSON row entries for what its extra states learnt: ``mag_ref``
        (:meth:`mag_ref_learnt`) and ``gyro_drift`` (:meth:`gyro_drift_learnt`), each
        only when there is one."""
        got = {"mag_ref": self.mag_ref_learnt(runner),
               "gyro_drift": self.gyro_drift_learnt(runner)}
        return {k: v for k, v in got.items() if v is not None}

    def set_mag_inclination(self, inc: float, t: float, why: str) -> None:
        """From now on the magnetometer's reference field has the inclination ``inc``
        (rad, down positive; a live run's judgement of :attr:`inclination_choice`),
        decided at ``t`` (s) because ``why``. Nothing before the first start or without
        a 3-D field reference, or with the magnetic reference states (which learn it)."""
        if self._builder is None or self._mref is None or self.space.mag:
            return
        old = reference_inclination(self._mref)
        self._mref = mag_reference(self.declination, float(inc))
        self.summary["inclination_rad"] = float(inc)
        # the filters' tilt was held to the old field: its error can be that far off
        self._tilt_pending += (float(inc) - old) ** 2
        self._decide("inclination", f"{np.degrees(inc):.2f} deg", t,
                     why + "; the filters' tilt variance widened by the change")

    def _yaw_from_mag(self) -> tuple[bool, str]:
        """:meth:`LateDeclination._yaw_from_mag`: until a fix has shown a ground speed of
        ``yaw_speed`` (the GNSS then has had a say in the yaw, which a declination learnt
        now does not turn)."""
        return (self._mag is not None and not self._moved,
                f"from the magnetometer alone so far: no fix at {self.opts.yaw_speed:g} m/s "
                "or more yet")

    # ------------------------------------------------------------------ steps
    def _step(self, r: _Raw, aids: list[_Aid]) -> Step:
        n = self.noise
        assert self._model is not None and r.a is not None
        ups: list[tuple[Array, Any]] = []
        sensors: list[str] = []
        fix = next((a for a in reversed(aids) if a.sensor == "gnss"), None)
        if fix is not None and fix.gnss is not None and not self._moved:
            v = np.asarray(fix.gnss.vel_ned, float)
            self._moved = bool(np.hypot(v[0], v[1]) >= self.opts.yaw_speed)
        stamp = self._stamp(r)
        carry = None
        if self.vel_window > 0:
            self._recent.append((stamp, r.t - r.t0, r.w, r.a))
            while self._recent[0][0] < stamp - self.vel_window - self.delay - 1.0:
                self._recent.popleft()
        if fix is not None and fix.gnss is not None and fix.ned is not None:
            if fix.span > 0:
                steps = list(self._recent)
                back, f = window_force(steps, stamp, fix.t - 0.5 * fix.span, fix.span)
                carry = carry_force(steps, stamp, fix.t - 0.5 * fix.span)
            else:
                back, f = stamp - fix.t, r.a
            self._aids.gnss_updates(fix, back, f, self._model.g, self._noise_for_aids(), ups,
                                    sensors, carry, self._timing_sd(fix))
        if carry is not None and self._aids.h_fix is not None and self._baro_recent:
            # a windowed fix is taken after its time: pair its height with the baro's
            # at that time (the last baro after it, in a climb, is off by the climb)
            tb, hb = np.array(self._baro_recent).T
            t_h, h = self._aids.h_fix
            i = int(np.searchsorted(tb, t_h))
            if 0 < i < len(tb) and tb[i] - tb[i - 1] <= 0.5:
                a = (t_h - tb[i - 1]) / (tb[i] - tb[i - 1])
                self._offset_pair((1 - a) * hb[i - 1] + a * hb[i] - h, r.t)
        baro = next((a for a in reversed(aids) if a.sensor == "baro"), None)
        if baro is not None:
            h_fix = self._aids.h_fix
            if self.vel_window > 0:
                while self._baro_recent and self._baro_recent[0][0] < stamp - BARO_RECENT_S:
                    self._baro_recent.popleft()
                self._baro_recent.append((baro.t, baro.height))
            elif h_fix is not None and baro.t - h_fix[0] <= 0.5:
                self._offset_pair(baro.height - h_fix[1], r.t)
            self._aids.baro_updates(baro, stamp, self._noise_for_aids(), ups, sensors)
        mag = next((a for a in reversed(aids) if a.sensor == "mag"), None)
        if mag is not None:
            self._aids.mag_updates(mag, stamp, r.w, self._mref, self.declination, n,
                                   ups, sensors, self._heading_scale, self.space)
        if self._align.unaided and r.t - self._t_hold >= HOLD_INTERVAL_S:
            self._t_hold = r.t
            ups.append((np.zeros(3), GnssPosition(np.eye(3) * n.nofix_pos_noise**2,
                                                  biased=False)))
            sensors.append("hold")
        if self.space.dim != DIM:  # the models read (or pass over) the appended states
            for _, m in ups:
                m.space = self.space
        self._k += 1
        u = np.concatenate([r.w, r.a])
        info: dict[str, Any] | None = {"sensors": tuple(sensors)} if sensors else None
        if self._anchor_sample is not None:
            info = {**(info or {}), "samples": (self._anchor_sample,)}
            self._anchor_sample = None
        model = self._rough.model(self._model, r.a, r.t - r.t0)
        return Step(self._k, stamp, r.t - r.t0, model, tuple(ups), u, info)

    def _timing_sd(self, fix: _Aid) -> Array | None:
        """The std (m/s per NED axis) a fix's velocity gains while the GNSS delay is not
        known (:data:`UNKNOWN_GNSS_LAG_S` times the acceleration between the last fix and
        this one; None once the delay is known, or without a previous fix close enough).
        Once the delay is known it stays known (a rewind restores both), so the fixes are
        no longer kept."""
        if self.delay_known:
            return None
        assert fix.gnss is not None
        v = np.asarray(fix.gnss.vel_ned, float)
        last, self._vfix_last = self._vfix_last, (fix.t, v)
        if last is None or not 0.0 < fix.t - last[0] <= LAG_ACCEL_MAX_DT:
            return None
        a = np.nan_to_num((v - last[1]) / (fix.t - last[0]))  # m/s^2 (NaN axis: none)
        sd: Array = UNKNOWN_GNSS_LAG_S * np.minimum(np.abs(a), LAG_ACCEL_MAX)
        return sd

    def _offset_pair(self, d: float, t: float) -> None:
        """One (baro height - GNSS height) pair (m) for the offset
        (:meth:`AidQueues.offset_pair`)."""
        if self._aids.offset_pair(d):
            self._decide("baro offset", f"{d:.2f} m", t,
                         "baro height minus the GNSS height, running mean from here")
        self.summary["baro_offset_m"] = self._aids.baro_offset

    # ------------------------------------------------------------------ setup
    def _set_noise(self, imu: str, rate: float) -> None:
        """The noise of the IMU ``imu`` at ``rate`` Hz: its source's profile with the
        options' values; an accelerometer density given is used as it is (no share that
        follows the flight's roughness unless ``accel_rough`` is given too)."""
        o = self.opts
        self.source_noise = nav_noise_for_source(imu, rate)
        self.noise = self.source_noise.with_(**o.noise)
        if "accel_noise" in o.noise and "accel_rough" not in o.noise:
            self.noise = self.noise.with_(accel_rough=0.0)

    def _setup(self) -> list[Start | Step]:
        """Choose the sources, rate and integration from the held window; replay it."""
        o, held = self.opts, self._held
        assert held is not None
        self._held = None
        if o.on_arrival:  # time order (an IMU sample after the rest of its message)
            held.sort(key=arrival_order)
        imu, imu_counts, mag, _ = choose_imu(held, o.imu, o.use_mag)
        ti = [s.t for s in held if isinstance(s, ImuSample) and s.source == imu]
        rate = (len(ti) - 1) / max(ti[-1] - ti[0], 1e-9) if len(ti) > 1 else 0.0
        integ, why, factor = step_plan(imu, rate, o.integration, o.rate_hz)
        self._set_noise(imu, rate)
        self.space = nav_space(self.noise)
        self.delay = float(self.noise.gnss_delay if o.gnss_delay is None else o.gnss_delay)
        self.vel_window = float(self.noise.gnss_vel_window)
        self.window_known = ("gnss_vel_window" in o.noise
                             or o.gnss_vel_window_why is not None)
        self.delay_known = o.gnss_delay is not None or "gnss_delay" in o.noise
        self.baro_known = o.baro_delay is not None
        self._aid_noise = None
        self.mag_delay = float(o.mag_delay or 0.0)
        self.baro_delay = float(o.baro_delay or 0.0)
        med = float(np.median(np.diff(ti))) if len(ti) > 1 else 0.0  # s, IMU interval
        half_step = 0.5 * med * factor
        # on arrival a step goes out at the IMU sample that ends it (no half-step wait):
        # an aid after its end goes to the next step; the history re-steps a late one
        self._aid_window = 0.0 if o.on_arrival else half_step
        if o.imu_delay is None:
            self.imu_delay, dwhy = imu_filter_delay(imu, self.params)
        else:
            self.imu_delay, dwhy = float(o.imu_delay), "option"
        self.summary["imu_delay_s"] = self.imu_delay
        self._imu, self._mag = imu, mag
        self.summary.update(
            imu_source=imu, imu_sources=imu_counts, mag_source=mag, accel_compensation=None,
            integration=integ, integration_why=why, preintegrated_samples_per_step=factor,
            align_rate_hz=rate, steps_per_update=1, gnss_delay_s=self.delay,
            gnss_vel_window_s=self.vel_window,
            mag_delay_s=self.mag_delay if mag is not None else None,
        )
        t_first = ti[0]
        self._decide("IMU", imu, t_first,
                     "option --imu" if o.imu is not None else
                     f"most samples in the first {2 * o.align_s:g} s ("
                     + ", ".join(f"{k} {v}" for k, v in sorted(imu_counts.items())) + ")")
        self._decide("integration", integ, t_first, "option" if o.integration != "auto" else why)
        self._decide("GNSS delay", f"{self.delay:.3f} s", t_first, o.gnss_delay_why or (
            "option --gnss-delay" if o.gnss_delay is not None else
            "option --noise" if self.delay_known else
            f"default; until it is known each fix's velocity std gains "
            f"{UNKNOWN_GNSS_LAG_S:g} s x the vehicle's acceleration"))
        if self.vel_window > 0 or self.window_known:
            self._decide("GNSS velocity window", f"{self.vel_window:.3f} s", t_first,
                         o.gnss_vel_window_why or "option --noise")
        else:
            self._decide("GNSS velocity window", "not known", t_first,
                         f"not estimated yet: the GNSS velocity std is at least "
                         f"{UNMODELLED_WINDOW_VEL_FLOOR:g} m/s until it is")
        self._decide("IMU delay", f"{self.imu_delay * 1e3:.1f} ms", t_first, dwhy)
        if self.noise.gnss_bias:
            self._decide_bias(t_first, o.gnss_bias_why or "option --noise")
        if mag is not None:
            self._decide("magnetometer delay", f"{self.mag_delay * 1e3:.0f} ms", t_first,
                         o.mag_delay_why or ("option --mag-delay" if o.mag_delay is not None
                                             else "default"))
            self._decide("magnetometer noise", f"{self.noise.mag_noise:.3f} rad", t_first,
                         o.mag_noise_why or ("option --noise" if "mag_noise" in o.noise
                                             else "default for the IMU source"))
            n = self.noise
            if n.mag_ref:
                def prior(x: float) -> str:
                    return f"+- {np.degrees(x):.2f} deg" if x > 0 else "fixed"

                self._decide("magnetic reference states",
                             f"inclination {prior(n.mag_ref_inc)}, "
                             f"declination {prior(n.mag_ref_dec)}",
                             t_first, f"{o.mag_ref_why or 'option --noise'} (random walk "
                             f"{n.mag_ref_walk:g} rad/sqrt(s))")
        if self.noise.gyro_drift:
            self._decide("gyro drift states",
                         f"the gyro bias's rate, +- {self.noise.init_gyro_drift:g} rad/s^2",
                         t_first, f"option --noise (random walk {self.noise.gyro_drift_walk:g} "
                         "rad/s^2/sqrt(s); the bias moves at this rate)")
        self._builder = _NavBuilder(integ, factor, o.on_arrival)
        self._builder.gap_s = max(GAP_MIN_S, GAP_MEDIANS * med)
        self.summary["imu_gap_threshold_s"] = self._builder.gap_s
        self.max_step = max(MAX_STEP_S, MAX_STEP_PERIODS * med * factor)
        self.summary["max_step_s"] = self.max_step
        self._imu_n = [0, t_first, t_first]
        self._go_wait("no good GNSS fix yet", t_first)
        self.decisions.pop()  # the first wait is the start, not a decision
        out: list[Start | Step] = []
        for s in held:
            out += self._feed(s)
        return out

    def _finish_summary(self) -> None:
        n, t0, t1 = self._imu_n
        span = t1 - t0
        gaps = self._builder.gaps if self._builder else []
        self.summary.pop("_vmax", None)
        self.summary.update(
            steps=self._k, imu_samples=n, t_first=t0, t_last=t1,
            imu_dropped=self._builder.dropped if self._builder else 0,
            imu_gaps=len(gaps), imu_gap_longest_s=max((b - a for a, b in gaps), default=0.0),
            imu_gap_list=[[a, b] for a, b in gaps], duration_s=span,
            imu_rate_hz=(n - 1) / span if span > 0 else 0.0,
            filter_rate_hz=self._k / span if span > 0 else 0.0,
            gnss_source=self._aids.gnss, gnss_sources=dict(self._aids.gnss_srcs),
            baro_source=self._aids.baro if self.opts.use_baro else None,
            aiding={k: dict(v) for k, v in self.aiding.items()},
        )
        if (density := self.accel_density) is not None:
            self.summary["accel_density"] = density

    @property
    def accel_density(self) -> dict[str, Any] | None:
        """The accelerometer densities the steps used when they follow the flight's
        roughness (:meth:`~uavest.engine.nav_rough.RoughDensity.summary`; None with a
        fixed density)."""
        return self._rough.summary()


class NavRunner(FilterRunner):
    """:class:`FilterRunner` that gates each aiding update of a navigation step
    (``Step.info["sensors"]`` names them): the update is dropped when its NIS (the
    filter's own innovation, as :func:`~uavest.models.navigation.innovation_gate`
    computes it) is above the :data:`GATE_PROB` chi-square quantile, and
    counts per sensor what was ``accepted``, ``rejected``, ``reanchored`` (after
    :data:`REANCHOR_S` of consecutive rejections one update is taken with R scaled onto
    the gate, so a filter that drifted away from a sensor comes back without a reset) and
    ``reset`` (the GNSS velocity instead, :data:`LOCKOUT_SENSORS`: a reset, reported as
    the guard's are). Steps without sensors run as in :class:`FilterRunner`."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.gates: dict[str, dict[str, int]] = {}
        self._rej_since: dict[str, float] = {}
        self._reset_why = ""  # a lock-out reset in the step running, why
        self._lock_since: dict[str, float] = {}  # LOCKOUT_SENSORS: rejected since (s)
        self._lockouts: dict[str, list[float]] = {}  # LOCKOUT_SENSORS: reset times (s)

    def start(self, st: Start) -> None:
        super().start(st)
        self._rej_since.clear()
        self._lock_since.clear()

    def snapshot(self) -> tuple[Any, ...]:
        """:meth:`FilterRunner.snapshot` with the gate counts and rejection times."""
        return (super().snapshot(), {k: dict(v) for k, v in self.gates.items()},
                dict(self._rej_since), dict(self._lock_since),
                {k: list(v) for k, v in self._lockouts.items()})

    def restore(self, snap: tuple[Any, ...]) -> None:
        base, gates, rej, lock, lockouts = snap
        super().restore(base)
        self.gates = {k: dict(v) for k, v in gates.items()}
        self._rej_since = dict(rej)
        self._lock_since = dict(lock)
        self._lockouts = {k: list(v) for k, v in lockouts.items()}

    def _gated_update(self, s: Any, z: Array, m: Any, sensor: str, t: float
                      ) -> tuple[Any, Any]:
        """(state, innovation) after the update with ``(z, m)``, or (``s``, None) when
        its NIS (the filter's own innovation and S) is above the gate: the update is
        computed and dropped, so the gate costs nothing when it passes."""
        f: Any = self.filter
        s1, inn = f.update(s, z, m, self.rng)
        c = self.gates.setdefault(sensor, {"accepted": 0, "rejected": 0, "reanchored": 0,
                                           "reset": 0})
        if inn is None:
            return s1, None
        k = len(inn.nu)
        chi2 = _CHI2.get(k)
        if chi2 is None:
            chi2 = _CHI2[k] = nis_gate(k, GATE_PROB)
        d2 = float(inn.nis)
        if np.isfinite(d2) and d2 <= chi2:
            self._rej_since.pop(sensor, None)
            self._lock_since.pop(sensor, None)
            c["accepted"] += 1
            return s1, inn
        t0 = self._rej_since.setdefault(sensor, t)
        if sensor in LOCKOUT_SENSORS and np.isfinite(d2):
            tl = self._lock_since.setdefault(sensor, t)
            past = [u for u in self._lockouts.get(sensor, []) if t - u < LOCKOUT_MEMORY_S]
            if t - tl >= LOCKOUT_S * 2 ** max(len(past) - 1, 0):
                self._rej_since.pop(sensor, None)
                self._lock_since.pop(sensor, None)
                self._lockouts[sensor] = [*past, t]
                c["reset"] += 1
                return self._lockout_reset(s, z, m, inn, sensor, t - tl)
        if t - t0 >= REANCHOR_S and np.isfinite(d2):
            # R scaled so that S' = S d2 / chi2: the update lands on the gate
            r = d2 / chi2
            m2 = copy.copy(m)
            m2.R = m.R * r + (np.asarray(inn.S) - m.R) * (r - 1.0)
            self._rej_since.pop(sensor, None)
            c["reanchored"] += 1
            return f.update(s, z, m2, self.rng)  # type: ignore[no-any-return]
        c["rejected"] += 1
        return s, None

    def _lockout_reset(self, s: Any, z: Array, m: Any, inn: Any, sensor: str,
                       held: float) -> tuple[Any, Any]:
        """(state, innovation) of a :data:`LOCKOUT_SENSORS` reset: ``sensor`` rejected
        for ``held`` s, its last innovation ``inn``; the filter restarts from its running
        estimate widened (:data:`LOCKOUT_SENSORS`) and takes the update ``(z, m)``."""
        f: Any = self.filter
        g = f.estimate(s)
        nu2 = float(np.sum(np.square(inn.nu)))  # (m/s)^2
        P = np.array(g.P, float)
        P[DV, DV] += np.eye(3) * nu2
        P[DP, DP] += np.eye(3) * nu2 * held**2
        g = widen_tilt(Gaussian(np.array(g.x, float), P), LOCKOUT_TILT**2)
        resets = int(getattr(s, "resets", 0)) + 1
        s2 = f.init(g, self.space, self.rng)
        if hasattr(s2, "resets"):
            s2 = replace(s2, resets=resets)
        self._reset_why = (f"{sensor} rejected for {held:.1f} s (innovation "
                           f"{np.sqrt(nu2):.2f}): velocity, position and tilt widened")
        return f.update(s2, z, m, self.rng)  # type: ignore[no-any-return]

    def _finish(self, rec: StepRecord) -> StepRecord:
        """:meth:`FilterRunner._finish`, the record marked as a reset (with why) when a
        lock-out reset (:meth:`_lockout_reset`) took place in its step."""
        why, self._reset_why = self._reset_why, ""
        if why:
            rec = replace(rec, reset=True, reason=why)
        return super()._finish(rec)

    def update(self, s: Any, z: Array, m: Any, st: Step, i: int) -> tuple[Any, Any]:
        """The ``i``-th update of ``st``, gated when the step names its sensors."""
        sensors = st.info.get("sensors") if st.info else None
        if not sensors:
            return super().update(s, z, m, st, i)
        return self._gated_update(s, z, m, sensors[i], st.t)
