"""The GNSS measurement delay estimated from a flight: the lag of the GNSS velocity behind
the IMU.

A fix stamped ``t`` measures the vehicle's velocity at ``t - d``. Between a fix ``i`` and
the first fix ``j`` at least :data:`PAIR_S` later the GNSS velocity changes by
``dv_ij = v_j - v_i``; the IMU says that the velocity changed by

    dV_ij(d) = V(t_j - d) - V(t_i - d),   V(t) = integral of a_n,
    a_n = R(q) (f - b_a) + (0, 0, g)                     (NED, m/s^2)

with ``f`` each step's mean specific force (body FRD), ``q`` and ``b_a`` a navigation
filter's attitude and accelerometer bias at that step (``V`` linear inside a step).
:class:`DelayProbe` collects ``a_n`` per step and the GNSS velocities;
:meth:`DelayProbe.estimate` picks the ``d`` of a grid (:data:`MIN_DELAY_S` to
:data:`MAX_DELAY_S`, every :data:`GRID_S`) that minimises
``J(d) = sum |dv_ij - dV_ij(d)|^2`` over the components the receiver gives (horizontal
for MAVLink's ground speed and course), refined by a parabola through the three grid
points round the least cost. Velocity *changes* make the estimate blind to a constant
velocity error and to slow attitude errors; what fixes ``d`` is the timing of the
manoeuvres (the change of acceleration across the pair), so a hover gives no estimate
(:data:`MIN_EXCITATION`). Pairs 1 s apart rather than consecutive fixes: across 0.2 s
the acceleration hardly changes, and the receiver's velocity noise dominated (standard
error 15 ms on sim_200hz with 0.2 s, 4 ms with 1 s).

Its standard error comes from the curvature of ``J`` at the least cost:
``sd = sqrt(2 s2 / J'')`` with ``s2 = J_min / (n_components - 1)``; the estimate is
taken when ``sd`` is at most :data:`MAX_SD_S`.

:func:`estimate_gnss_delay` runs one navigation filter over a stretch of samples (the
replay's probe, :func:`uavest.apps.replay.probe_gnss_delay`: at most :data:`PROBE_S` s
of the log, held and handed back for the run itself) and returns the estimate with the
held samples.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import InputError
from ..geometry.rotation import dcm_f, qexp_f, qmul_f, quat_rotate, quat_slerp_interp
from ..ingest.types import BaroSample, GnssSample, ImuSample, MagSample
from .nav_aiding import NewReadings, baro_height
from .navigation import NavOptions, NavRunner, NavStream
from .records import Start, Step

Array = np.ndarray

__all__ = ["BARO_NOISE_MIN", "GRID_S", "LIVE_CHECK_S", "LIVE_FIRST_S", "MAG_NOISE_MIN",
           "MAX_BARO_DELAY_S", "MAX_DELAY_S", "MAX_MAG_DELAY_S", "MAX_SD_S", "MIN_DELAY_S",
           "MIN_EXCITATION", "PAIR_S", "PROBE_MIN_IMU_HZ", "PROBE_S", "BaroEstimate",
           "DelayEstimate", "DelayProbe", "LiveDelayLearner", "MagEstimate",
           "baro_noise_from_spread", "delay_used", "estimate_gnss_delay",
           "mag_noise_from_scatter"]

#: The delays tried (s): MIN_DELAY_S to MAX_DELAY_S every GRID_S (a negative delay, the
#: GNSS stamped before the IMU, is reported as found and used as 0).
MIN_DELAY_S = -0.1
MAX_DELAY_S = 0.6
GRID_S = 0.005
#: The velocity changes compared span this long (s): fix i with the first fix at least
#: this much later (within 1.5 times this).
PAIR_S = 1.0
#: The estimate is taken when its standard error is at most this (s) ...
MAX_SD_S = 0.01
#: ... and the GNSS velocity changed enough: the sum of |dv_i|^2 over the pairs, (m/s)^2
#: (a hover with 2 cm/s of noise over 10 min gives ~1).
MIN_EXCITATION = 20.0
#: The GNSS velocity windows tried (s): 0 to this every WINDOW_GRID_S; the window is
#: taken when the cost falls by more than the noise would explain: ``(J_0 - J_L) /
#: (J_L / (m_eff - 1))`` above WINDOW_F (chi-square, 1 dof, 99.9 %), with ``m_eff`` the
#: residual components over WINDOW_OVERLAP (the 1-s pairs of 5-Hz fixes overlap, so
#: their residuals are not independent), and to at most WINDOW_GAIN of J_0.
MAX_WINDOW_S = 0.8
WINDOW_GRID_S = 0.025
WINDOW_F = 10.83
WINDOW_OVERLAP = 5.0
WINDOW_GAIN = 0.95
WINDOW_POINTS = 12  # the window mean: of this many midpoints
#: With the GNSS delay given, the window is estimated at it only when the data's own lag
#: is within this (s), or 3 of its standard errors, of it: at a delay the data contradict
#: the velocity's timing is not modelled and the stream keeps its floor for an unknown
#: window (``--gnss-delay 0`` on logs/sitl_copter.tlog, whose lag is 0.083 s: 473 fixes
#: gated and pitch 0.304 deg with the floor dropped, 226 and 0.240 with it kept).
GIVEN_DELAY_TOL_S = 0.01
#: The barometer delays tried (s): MIN_DELAY_S to this.
MAX_BARO_DELAY_S = 0.5
#: The baro noise taken from its spread against the GNSS height (the replay's probe; a
#: live run's suggestion for the next run, ``--aiding-from``: :func:`baro_noise_from_spread`)
#: is at least this (m) and at most the IMU source's default: the spread is against the
#: GNSS height, which an ArduPilot SITL gives without noise (4-5 mm on its flights), and a
#: real baro's noise changes with the airflow round the vehicle, which a stretch of the
#: flight may not show. A real receiver's height noise (decimetres) puts the spread above
#: it, so the floor binds on a simulator's noiseless GNSS height only. With 0.05 the EKF's
#: replayed position NEES was in band on 0.668-0.919 of the airborne steps of six
#: ArduCopter SITL flights (under-confident), with 0.02 on 0.808-0.950; with 0.02 the
#: velocity NEES of two live SITL sessions was in band on 0.735-0.790 (under-confident,
#: the vertical velocity's std 3.6 times its error), with 0.01 on 0.820-0.841 replayed
#: (docs/navigation.md, "The baro noise floor").
BARO_NOISE_MIN = 0.01
#: The magnetometer noise taken from the spread of its readings (a replay's probe, a
#: live run's learner: :func:`mag_noise_from_scatter`) is at least this (rad, 2.9 deg)
#: and at most the IMU source's default. The scatter sees the sensor, not the error of the
#: reference field it is compared with: the inclination taken from the flight was 0.3
#: deg off on sim_200hz (63.82 against the simulator's 63.5 deg, before the probe corrected
#: it for its tilt error), and with 0.01-0.02 rad
#: the magnetometer pulled the tilt after it (airborne 0.35-0.44 deg roll against 0.20 at
#: 0.05; 0.066 with the true inclination at 0.01), while the SITL flight's (0.06 deg off)
#: gained (yaw 0.22 deg at 0.02, 0.40 at 0.05).
MAG_NOISE_MIN = 0.05
#: The magnetometer ages tried (s): 0 to this.
MAX_MAG_DELAY_S = 0.3
#: The replay's pre-pass looks at the first this many seconds of IMU data (s).
PROBE_S = 240.0
#: The estimates are used for an IMU at least this fast (Hz), in a replay and live:
#: between two samples of vtol.tlog's 3.8 Hz RAW_IMU the acceleration is not resolved,
#: and the probe put its GNSS delay at 0.09 s where the replay is best at 0.25 s
#: (docs/navigation.md).
PROBE_MIN_IMU_HZ = 20.0


def baro_noise_from_spread(spread: float, top: float) -> tuple[float, str]:
    """The baro noise (m) a run takes from the ``spread`` (m) of the baro heights against
    the GNSS heights at the baro's delay (:meth:`DelayProbe.estimate_baro`): clipped to
    [:data:`BARO_NOISE_MIN`, ``top``] (``top`` m, the noise the run has for its IMU source),
    with the words saying so."""
    hi = max(float(top), BARO_NOISE_MIN)
    return (float(np.clip(spread, BARO_NOISE_MIN, hi)),
            f"the spread of the baro height against the GNSS height at that delay, "
            f"{spread:.3f} m, within [{BARO_NOISE_MIN:g}, {hi:g}] m "
            "(--noise baro_noise=M to set it)")


def mag_noise_from_scatter(scatter: float, top: float) -> tuple[float, str]:
    """The magnetometer noise (rad) a run takes from the ``scatter`` (rad, per axis) of its
    readings' direction turned to NED with the filter's attitude: clipped to
    [:data:`MAG_NOISE_MIN`, ``top``] (``top`` rad, the IMU source's default), with the
    words saying so."""
    hi = max(float(top), MAG_NOISE_MIN)
    return (float(np.clip(scatter, MAG_NOISE_MIN, hi)),
            f"the spread of the field direction at that age, {np.degrees(scatter):.2f} deg "
            f"per axis, within [{np.degrees(MAG_NOISE_MIN):.2f}, {np.degrees(hi):.2f}] deg "
            "(--noise mag_noise=RAD to set it)")


def delay_used(delay: float) -> tuple[float, str]:
    """The GNSS delay (s) a run takes from an estimate ``delay`` (s): clipped to [0, 2]
    s, with the note saying so for a negative one (the GNSS stamped before the IMU)."""
    return float(np.clip(delay, 0.0, 2.0)), " (negative: used as 0)" if delay < 0 else ""


@dataclass
class DelayEstimate:
    """The GNSS delay ``delay`` (s; None: not estimated, ``why`` says why), its standard
    error ``sd`` (s), the fix pairs ``pairs`` and ``excitation`` ((m/s)^2) it rests
    on, and the cost curve ``grid`` (s) / ``cost`` ((m/s)^2)."""

    delay: float | None
    sd: float | None
    pairs: int
    excitation: float
    why: str
    grid: Array = field(default_factory=lambda: np.zeros(0))
    cost: Array = field(default_factory=lambda: np.zeros(0))
    imu_rate_hz: float = 0.0  # the probe run's IMU rate (Hz)
    #: the GNSS velocity's window (s, NavNoise.gnss_vel_window; None: not estimated,
    #: ``window_why`` says why) and the cost there over the cost without one
    window: float | None = None
    window_ratio: float | None = None
    window_why: str = ""
    #: with the delay given: the delay the data show (s; None: none found) and its
    #: standard error, for the user to compare
    data_delay: float | None = None
    data_sd: float | None = None
    #: the fixes' positions against their velocities (:meth:`DelayProbe.estimate_drift`)
    drift: DriftEstimate | None = None

    def lag(self, fallback: float) -> float:
        """The GNSS lag (s) the baro and the magnetometer are timed against: the data's own
        where found (a delay given or not), else ``fallback``; as :func:`delay_used`."""
        d = next((d for d in (self.data_delay, self.delay) if d is not None), fallback)
        return delay_used(d)[0]

    def given_note(self) -> str:
        """With the delay given, what the data say of it (else "")."""
        if self.why != "given":
            return ""
        if self.data_delay is None or self.data_sd is None:
            return "; the data give no delay of their own"
        return (f"; the data's own lag {self.data_delay:.3f} s, standard error "
                f"{self.data_sd * 1e3:.1f} ms")


#: The GNSS position is compared with its own velocity, integrated, over these spans (s)
DRIFT_SHORT_S = 1.0
DRIFT_LONG_S = 10.0
#: ... and said to carry correlated errors when the long span's difference is more than
#: this many times the short one's (independent errors give the same at every span) and
#: more than DRIFT_MIN_M (the integration's own error: 3 mm over 10 s circling at 8 m/s)
DRIFT_GROWTH = 2.0
DRIFT_MIN_M = 0.05
#: the longest correlation time the GNSS bias states are given from the drift, s
DRIFT_TAU_MAX_S = 3600.0


@dataclass
class DriftEstimate:
    """How the GNSS fixes' positions move against their own velocities, integrated: the
    root mean square per horizontal axis (m) of ``(p(t + T) - p(t)) - integral of v`` over
    T = :data:`DRIFT_SHORT_S` (``short``) and :data:`DRIFT_LONG_S` (``long``), from
    ``pairs`` long pairs (None with ``why`` when too few). Independent position errors
    of std s give s sqrt(2) at both spans; errors correlated over seconds (a receiver's
    multipath and atmosphere; uavest's simulator: a 60-s Gauss-Markov process) grow with
    the span, and a filter taking the fixes as independent does not carry them in its
    covariance (its position NEES is then optimistic). logs/sitl_copter.tlog (an ArduPilot
    SITL, on its sphere): 0.007 and 0.011 m; vtol.tlog 0.067 and 0.127 m; sim_200hz 0.169
    and 0.452 m."""

    short: float | None
    long: float | None
    pairs: int
    why: str = ""
    #: the receiver's median reported accuracy (h_acc, v_acc, m) over those fixes (None:
    #: not reported)
    h_acc: float | None = None
    v_acc: float | None = None

    def bias_model(self) -> tuple[dict[str, float] | None, str]:
        """The GNSS bias states (:class:`~uavest.models.navigation.NavNoise` names
        ``gnss_bias_h``, ``gnss_bias_v``, ``gnss_bias_tau``) for correlated errors, with
        why (None: no states, why not). The receiver's accuracy is the error's steady std
        (the drift alone cannot give it: a fix's absolute error is not in the fixes); the
        drift's growth from the short span to the long one, ``2 sigma^2 / tau`` per s for a
        Gauss-Markov error of correlation time ``tau`` much longer than the spans, gives
        ``tau`` (at least :data:`DRIFT_LONG_S`). Without a vertical accuracy the vertical
        std is the horizontal one."""
        if not self.correlated or self.short is None or self.long is None:
            return None, "no error correlated over seconds"
        if self.h_acc is None:
            return None, "the receiver reports no accuracy to size them with"
        slope = (self.long**2 - self.short**2) / (DRIFT_LONG_S - DRIFT_SHORT_S)  # m^2/s
        tau = float(np.clip(2.0 * self.h_acc**2 / slope, DRIFT_LONG_S, DRIFT_TAU_MAX_S))
        v = self.v_acc if self.v_acc is not None else self.h_acc
        return ({"gnss_bias_h": self.h_acc, "gnss_bias_v": v, "gnss_bias_tau": tau},
                f"std the receiver's median accuracy ({self.h_acc:.2f} m horizontal, "
                f"{v:.2f} m vertical{'' if self.v_acc is not None else ' (as horizontal)'}), "
                f"correlation time {tau:.0f} s from the drift's growth "
                f"({slope * 1e3:.1f} mm^2/s per axis)")

    def as_dict(self) -> dict[str, Any]:
        """For the result documents (the replay's probe, the live learner)."""
        return {"short_m": self.short, "long_m": self.long, "pairs": self.pairs,
                "correlated": self.correlated, "h_acc_m": self.h_acc, "v_acc_m": self.v_acc}

    @property
    def correlated(self) -> bool:
        """The long span's difference is :data:`DRIFT_GROWTH` times the short one's and
        more than :data:`DRIFT_MIN_M`."""
        return (self.short is not None and self.long is not None
                and self.long > max(DRIFT_GROWTH * self.short, DRIFT_MIN_M))


@dataclass
class BaroEstimate:
    """The barometer's delay ``delay`` (s; None: not estimated, ``why`` says why) behind
    the GNSS height taken at the GNSS delay, its standard error ``sd`` (s), the spread
    ``spread`` (m) of baro minus GNSS height at that delay (the baro's noise with the GNSS
    height's in it) and the ``samples`` it rests on (:meth:`DelayProbe.estimate_baro`)."""

    delay: float | None
    sd: float | None
    samples: int
    why: str
    spread: float | None = None
    #: the baro noise (m) the probe's stream took for its IMU source
    noise_default: float | None = None
    #: baro height minus GNSS altitude (m) at the last baro sample, at the delay found:
    #: the fitted offset and drift's line there (None: no delay found)
    offset: float | None = None
    grid: Array = field(default_factory=lambda: np.zeros(0))
    cost: Array = field(default_factory=lambda: np.zeros(0))


@dataclass
class MagEstimate:
    """The magnetometer's age ``delay`` (s, against the IMU-delay-corrected steps; None:
    not estimated, ``why`` says why), its standard error ``sd`` (s), the ``scatter``
    (rad, per axis of the field direction, with the filter's attitude error in it), the
    field's ``inclination`` (rad, down positive: the mean direction at that age, against
    the down direction corrected for the filter's tilt error, :meth:`DelayProbe.estimate_mag`)
    and the ``readings`` it rests on, with the spread curve ``grid`` (s) / ``cost``."""

    delay: float | None
    sd: float | None
    readings: int
    why: str
    scatter: float | None = None
    inclination: float | None = None
    #: the mean direction's inclination before the tilt correction (rad), and the
    #: readings the correction had (0: none, ``inclination`` is the mean direction's)
    inclination_uncorrected: float | None = None
    tilt_corrected: int = 0
    #: the magnetometer noise (rad) the probe's stream took for its IMU source
    noise_default: float | None = None
    imu_rate_hz: float = 0.0  # the probe run's IMU rate (Hz)
    grid: Array = field(default_factory=lambda: np.zeros(0))
    cost: Array = field(default_factory=lambda: np.zeros(0))
    #: the readings inside the steps, which the spread curve sums over
    inside: int = 0

    def scatter_at(self, age: float) -> float | None:
        """The scatter (rad, per axis) at the grid's age nearest ``age`` (s): what a run
        that takes its readings at that age sees (None: no spread curve)."""
        if not self.cost.size or self.inside <= 0:
            return None
        k = int(np.argmin(np.abs(self.grid - age)))
        return float(np.sqrt(self.cost[k] / (2 * self.inside)))


class DelayProbe:
    """What the estimate needs from a navigation run: per step the time (s, the step's
    end), its length (s) and the NED acceleration ``a_n`` (m/s^2) from a filter's
    estimate; per GNSS fix its time (s) and NED velocity (m/s, NaN where the receiver
    gives none). A restart of the filters (:meth:`start`) begins a new segment: the
    integral does not run across it."""

    def __init__(self) -> None:
        self._t: list[float] = []
        self._dt: list[float] = []
        self._a: list[Array] = []
        self._a_raw: list[Array] = []  # the same without the filter's accelerometer bias
        self._seg: list[int] = []
        self._segment = 0
        self._gt: list[float] = []
        self._gv: list[Array] = []
        self._q: list[Array] = []
        self._mt: list[float] = []
        self._mf: list[Array] = []
        self._ht: list[float] = []  # GNSS heights: times (s), heights up (m)
        self._hh: list[float] = []
        self._bt: list[float] = []  # baro heights: times (s), heights up (m)
        self._bh: list[float] = []
        self._pt: list[float] = []  # 3-D fixes: times (s), lat/lon/alt, NED velocity
        self._pl: list[Array] = []
        self._pv: list[Array] = []
        self._pacc: list[tuple[float, float]] = []  # their h_acc, v_acc (m; NaN: none)
        self._gravity: float | None = None  # m/s^2, the model's, from the first step

    def start(self) -> None:
        """The filters restarted (alignment, re-alignment)."""
        self._segment += 1

    def mark(self) -> tuple[int, int]:
        """This moment of the steps (their number, the segment), for :meth:`rewind`."""
        return len(self._t), self._segment

    def rewind(self, mark: tuple[int, int]) -> None:
        """Back to ``mark``: the steps after it are dropped (made again by the caller);
        the GNSS fixes and magnetometer readings stay."""
        n, self._segment = mark
        del self._t[n:], self._dt[n:], self._a[n:], self._a_raw[n:], self._seg[n:]
        del self._q[n:]

    def add_step(self, st: Step, x: Array) -> None:
        """One navigation step ``st`` (its ``u`` = [rate, specific force], its model's
        gravity ``g``) and the filter's state ``x`` after it (q, ..., b_a)."""
        if st.u is None or not np.isfinite(x).all():
            return
        # (on Python floats: numpy's per-call cost on 3- and 4-vectors, once per step)
        u, xs = np.asarray(st.u, float).tolist(), x.tolist()
        h = -0.5 * float(st.dt)
        q_mid = qmul_f(xs[:4], qexp_f([h * (u[i] - xs[10 + i]) for i in range(3)]))
        R = dcm_f(q_mid)
        f, fc = u[3:6], [u[3 + i] - xs[13 + i] for i in range(3)]
        g = float(getattr(st.transition, "g", 0.0))
        a = np.array([r[0] * fc[0] + r[1] * fc[1] + r[2] * fc[2] for r in R])
        a_raw = np.array([r[0] * f[0] + r[1] * f[1] + r[2] * f[2] for r in R])
        a[2] += g
        a_raw[2] += g
        if g > 0 and self._gravity is None:
            self._gravity = g
        self._q.append(np.array(x[:4], float))
        self._t.append(float(st.t))
        self._dt.append(float(st.dt))
        self._a.append(a)
        self._a_raw.append(a_raw)
        self._seg.append(self._segment)

    def add_gnss(self, s: GnssSample) -> None:
        """One GNSS fix (3-D or 2-D: its horizontal velocity; NaN vertical stays NaN)."""
        v = np.asarray(s.vel_ned, float)
        if s.fix_type >= 2 and np.isfinite(v[:2]).all():
            self._gt.append(float(s.t))
            self._gv.append(v)
        h = float(s.lat_lon_alt[2])
        if s.fix_type >= 3 and np.isfinite(h):
            self._ht.append(float(s.t))
            self._hh.append(h)
        lla = np.asarray(s.lat_lon_alt, float)
        if s.fix_type >= 3 and np.isfinite(lla[:2]).all() and np.isfinite(v[:2]).all():
            self._pt.append(float(s.t))
            self._pl.append(lla)
            self._pv.append(v)
            self._pacc.append((float(s.h_acc), float(s.v_acc)))

    def estimate_drift(self, frame: Any) -> DriftEstimate:
        """:class:`DriftEstimate` of the 3-D fixes, their positions in ``frame`` (the run's
        local frame: an ArduPilot SITL's lat/lon read through the wrong geodesy move 0.1-0.2
        % of the displacement against its velocities)."""
        if frame is None or len(self._pt) < 10:
            return DriftEstimate(None, None, 0, "too few 3-D fixes")
        order = np.argsort(self._pt, kind="stable")
        t = np.array(self._pt)[order]
        lla = np.array(self._pl)[order]
        v = np.array(self._pv)[order][:, :2]
        p = np.asarray(frame.geodetic_to_ned(lla[:, 0], lla[:, 1], lla[:, 2]))[:, :2]
        dt = np.diff(t)
        walked = np.r_[[np.zeros(2)], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt[:, None], 0)]
        r = p - walked  # the position less the integrated velocity
        brk = np.r_[0, np.cumsum(dt > 1.0)]  # a gap over 1 s starts a new stretch
        out, n_long = [], 0
        for span in (DRIFT_SHORT_S, DRIFT_LONG_S):
            j = np.searchsorted(t, t + span)
            ok = (j < t.size)
            i = np.nonzero(ok)[0]
            j = j[ok]
            ok = (brk[j] == brk[i]) & (np.abs(t[j] - t[i] - span) <= 0.5 * span)
            d = (r[j] - r[i])[ok]
            n_long = int(ok.sum())
            out.append(float(np.sqrt(np.mean(d**2))) if n_long >= 10 else None)
        acc = np.array(self._pacc, float).reshape(-1, 2)
        ha, va = (float(np.nanmedian(a)) if np.isfinite(a).any() and np.nanmedian(a) > 0
                  else None for a in acc.T)
        if out[1] is None:
            return DriftEstimate(out[0], None, n_long,
                                 f"{n_long} fix pairs {DRIFT_LONG_S:g} s apart", ha, va)
        return DriftEstimate(out[0], out[1], n_long, "", ha, va)

    def add_baro(self, t: float, height: float) -> None:
        """One barometer sample at ``t`` (s, its stamp) of ``height`` (m up, any offset)."""
        if np.isfinite(height):
            self._bt.append(float(t))
            self._bh.append(float(height))

    def estimate_baro(self, gnss_delay: float, max_delay: float = MAX_BARO_DELAY_S,
                      grid_s: float = GRID_S) -> BaroEstimate:
        """The baro's delay (s): the ``L`` of a grid (:data:`MIN_DELAY_S` to ``max_delay``)
        for which the baro heights, each against the GNSS height at its stamp less ``L``
        (the GNSS height of a fix stamped ``t`` is taken at ``t - gnss_delay``, linear
        between fixes), less an offset and a drift (a line in time, fitted), spread least;
        refined as :meth:`estimate`. What fixes ``L`` is the climbs and descents: its
        standard error is at least the spread over the root sum of squares of the
        height's rate at the samples, so a flight at one height gives no estimate. The
        spread there is the baro's noise with the GNSS height's in it (an ArduCopter
        SITL: 4 mm, logs/sitl_copter.tlog)."""
        est = BaroEstimate(None, None, len(self._bt), "")
        if len(self._bt) < 50 or len(self._ht) < 20:
            est.why = f"{len(self._bt)} baro samples, {len(self._ht)} 3-D GNSS fixes"
            return est
        ht = np.array(self._ht) - gnss_delay
        hh = np.array(self._hh)
        order = np.argsort(ht, kind="stable")
        ht, hh = ht[order], hh[order]
        bt, bh = np.array(self._bt), np.array(self._bh)
        keep = (bt - max_delay >= ht[0]) & (bt - MIN_DELAY_S <= ht[-1])
        bt, bh = bt[keep], bh[keep]
        n = bt.size
        est.samples = n
        if n < 50:
            est.why = f"{n} baro samples inside the GNSS fixes"
            return est
        A = np.c_[np.ones(n), bt - bt.mean()]
        grid = np.arange(MIN_DELAY_S, max_delay + 0.5 * grid_s, grid_s)
        cost = np.empty(grid.size)
        for k, L in enumerate(grid):
            r = bh - np.interp(bt - L, ht, hh)
            c, *_ = np.linalg.lstsq(A, r, rcond=None)
            cost[k] = float(np.sum((r - A @ c) ** 2))
        est.grid, est.cost = grid, cost
        k = int(np.argmin(cost))
        est.spread = float(np.sqrt(cost[k] / max(n - 2, 1)))
        if not 0 < k < grid.size - 1:
            est.why = (f"the least spread is at the end of the range searched "
                       f"({grid[k]:.3f} s of {MIN_DELAY_S:g} to {max_delay:g} s)")
            return est
        d, sd = _least(grid, cost, k, n - 1)
        # the lag's information is the height's rate: sd >= spread / sqrt(sum rate^2),
        # the rate over 1 s of GNSS heights (the curvature alone takes the ripple of the
        # GNSS heights' interpolation, with their noise, for a least in a level flight)
        rate = np.interp(bt - d + 0.5, ht, hh) - np.interp(bt - d - 0.5, ht, hh)
        est.sd = max(sd, est.spread / max(float(np.sqrt(np.sum(rate * rate))), 1e-12))
        if est.sd > MAX_SD_S:
            est.why = (f"the least spread is not sharp ({d * 1e3:.0f} ms, standard error "
                       f"{est.sd * 1e3:.0f} ms > {MAX_SD_S * 1e3:.0f} ms: too little "
                       "climbing or descending)")
            return est
        est.delay = d
        r = bh - np.interp(bt - d, ht, hh)
        c, *_ = np.linalg.lstsq(A, r, rcond=None)
        est.offset = float(c[0] + c[1] * (bt[-1] - bt.mean()))
        return est

    def add_mag(self, t: float, field: Array) -> None:
        """One new magnetometer reading at ``t`` (s, its stamp) of ``field`` (body FRD,
        any unit)."""
        f = np.asarray(field, float)
        n = float(np.linalg.norm(f))
        if np.isfinite(n) and n > 0:
            self._mt.append(float(t))
            self._mf.append(f / n)

    def estimate_mag(self, max_delay: float = MAX_MAG_DELAY_S, grid_s: float = GRID_S,
                     gnss_delay: float = 0.0) -> MagEstimate:
        """The magnetometer's age (s) and scatter (rad): the ``L`` of a grid (0 to
        ``max_delay``) with the least spread of the readings turned into NED with the
        filter's attitude at ``t - L`` (the field is the same everywhere in a flight: what
        the rotation of the vehicle during ``L`` adds to the spread, the right ``L`` takes
        out); the spread there, per axis of the direction, is the scatter.

        The inclination: the mean over the readings of ``asin(u . d)``, ``u`` a reading
        turned into NED, ``d`` the true down direction as the filter sees it. A tilt error
        e of the filter turns every ``u`` by e, and ``d = (0, 0, 1)`` would put the
        inclination off by e's component along the field's horizontal direction (0.2-0.5
        deg on the simulator's vibrating flights, where it pulled the tilt after it). The
        same error turns the IMU's acceleration: the specific force turned to NED with the
        filter's attitude, plus gravity (:meth:`add_step`), differs from the GNSS's
        acceleration (velocity changes over the pairs of :meth:`estimate`, taken
        ``gnss_delay`` s earlier) by ``g e x (0, 0, 1)``, so ``d = (0, 0, 1) + (a_gnss -
        a_imu) / g`` (normalised) over each pair's span, taken for the readings inside one
        (the readings outside keep (0, 0, 1)). The specific force is taken without the
        filter's accelerometer bias: a tilt error and a horizontal accelerometer bias look
        alike to the filter, which puts part of its tilt error into its bias estimate,
        where this correction would not see it (with the bias subtracted the estimates
        below stayed up to 0.2 deg off). What the raw force carries instead is the true
        bias turned to NED, which the vehicle's turns average out (a bias the autopilot's
        calibration left, 0.05 m/s^2 along the field's horizontal direction on a flight
        with one heading, would put it 0.3 deg off). Against the inclination the
        simulator's own attitude gives the readings: logs/sitl_copter.tlog 0.06 deg off
        uncorrected, 0.01 corrected; sim_200hz 0.30 -> 0.00 (25 Hz) and 0.14 -> 0.01
        (every sample); the simulator's seed 2 0.24 -> 0.01 and 0.52 -> 0.00."""
        est = MagEstimate(None, None, len(self._mt), "")
        if len(self._mt) < 50 or len(self._t) < 10:
            est.why = f"{len(self._mt)} magnetometer readings"
            return est
        t = np.array(self._t)
        q = np.array(self._q)
        mt = np.array(self._mt)
        mf = np.array(self._mf)
        keep = (mt - max_delay >= t[0]) & (mt <= t[-1])
        mt, mf = mt[keep], mf[keep]
        n = mt.size
        if n < 50:
            est.why = f"{n} magnetometer readings inside the steps"
            return est
        grid = np.arange(0.0, max_delay + 0.5 * grid_s, grid_s)
        cost = np.empty(grid.size)
        for k, lag in enumerate(grid):
            qi, _ = quat_slerp_interp(t, q, mt - lag)
            u = quat_rotate(qi, mf)
            cost[k] = float(np.sum((u - u.mean(axis=0)) ** 2))
        est.grid, est.cost, est.inside = grid, cost, n
        k = int(np.argmin(cost))
        est.scatter = est.scatter_at(grid[k])
        qi, _ = quat_slerp_interp(t, q, mt - grid[k])
        u = quat_rotate(qi, mf)
        um = u.mean(axis=0)
        est.inclination = est.inclination_uncorrected = float(
            np.arcsin(np.clip(um[2] / np.linalg.norm(um), -1.0, 1.0)))
        down, est.tilt_corrected = self._down(mt, gnss_delay)
        if est.tilt_corrected:
            est.inclination = float(np.arcsin(np.clip(np.mean(np.sum(u * down, axis=1)),
                                                      -1.0, 1.0)))
        if k == 0:
            est.delay, est.sd = 0.0, None
            return est
        if k == grid.size - 1:
            est.why = (f"the least spread is at the end of the range searched "
                       f"({max_delay:g} s)")
            return est
        d, est.sd = _least(grid, cost, k, 2 * n)
        if est.sd > MAX_SD_S:
            est.why = (f"the least spread is not sharp ({d * 1e3:.0f} ms, standard error "
                       f"{est.sd * 1e3:.0f} ms)")
            return est
        est.delay = d
        return est

    def estimate(self, max_delay: float = MAX_DELAY_S, grid_s: float = GRID_S,
                 pair_s: float = PAIR_S, delay: float | None = None) -> DelayEstimate:
        """The delay minimising the cost over the grid (module docstring), and the GNSS
        velocity's window at it; with ``delay`` given (s, ``--gnss-delay``) that delay
        (``sd`` None), the searched one beside it (``data_delay``, ``data_sd``) and the
        window at the given one unless the searched one contradicts it."""
        none = DelayEstimate(None, None, 0, 0.0, "")
        if len(self._t) < 10 or len(self._gt) < 10:
            none.why = "too few steps or GNSS fixes"
            return none
        t0, t, V, dv, seg = self._integral()
        gt, gv, i0, i1 = self._pairs(pair_s)
        dz = gv[i1] - gv[i0]  # (n, 3), NaN where a component is missing
        args = (t0, t, V, dv, seg, gt, i0, i1, dz, np.isfinite(dz))
        found = self._search(*args, max_delay, grid_s)
        if delay is None:
            if found.delay is not None:
                self._window(found, *args)
            return found
        est = DelayEstimate(float(delay), None, found.pairs, found.excitation, "given",
                            data_delay=found.delay, data_sd=found.sd)
        if found.delay is not None and found.sd is not None and abs(
                found.delay - delay) > max(GIVEN_DELAY_TOL_S, 3.0 * found.sd):
            est.window_why = (f"the data's own lag, {found.delay:.3f} s, is "
                              f"{abs(found.delay - delay) * 1e3:.0f} ms from the "
                              "delay given: the velocity's timing is not modelled")
        else:
            self._window(est, *args)
        return est

    def _search(self, t0: Array, t: Array, V: Array, dv: Array, seg: Array, gt: Array,
                i0: Array, i1: Array, dz: Array, comp: Array, max_delay: float,
                grid_s: float) -> DelayEstimate:
        """The delay's grid search (:meth:`estimate`), without the window."""
        # the pairs every delay of the grid can use: both shifted ends in one segment
        _, sa = _v_at(t0, t, V, dv, seg, gt[i0] - max_delay)
        _, sb = _v_at(t0, t, V, dv, seg, gt[i1] - MIN_DELAY_S)
        use = (sa >= 0) & (sa == sb)
        n = int(use.sum())
        m = int(comp[use].sum())
        exc = float(np.sum(np.where(comp[use], dz[use], 0.0) ** 2))
        grid = np.arange(MIN_DELAY_S, max_delay + 0.5 * grid_s, grid_s)
        est = DelayEstimate(None, None, n, exc, "", grid, np.zeros(0))
        if n < 10:
            est.why = f"{n} GNSS fix pairs inside the IMU data"
            return est
        cost = np.array([_cost_on(t0, t, V, dv, seg, gt, i0, i1, dz, comp, d, use) for d in grid])
        est.cost = cost
        k = int(np.argmin(cost))
        if not 0 < k < grid.size - 1:
            est.why = (f"the least cost is at the end of the range searched "
                       f"({grid[k]:.3f} s of {MIN_DELAY_S:g} to {max_delay:g} s)")
            return est
        d, sd = _least(grid, cost, k, m)
        est.sd = sd
        if exc < MIN_EXCITATION:
            est.why = (f"too little manoeuvring: the GNSS velocity changes add up to "
                       f"{np.sqrt(exc):.1f} m/s (root sum of squares over {n} fix pairs; "
                       f"needs {np.sqrt(MIN_EXCITATION):.1f})")
        elif sd > MAX_SD_S:
            est.why = (f"the least cost is not sharp ({d * 1e3:.0f} ms, standard error "
                       f"{sd * 1e3:.0f} ms > {MAX_SD_S * 1e3:.0f} ms)")
        else:
            est.delay = d
        return est

    def _window(self, est: DelayEstimate, t0: Array, t: Array, V: Array, dv: Array,
                seg: Array, gt: Array, i0: Array, i1: Array, dz: Array, comp: Array
                ) -> None:
        """The GNSS velocity's window at the estimated delay: the ``L`` of a grid (0 to
        :data:`MAX_WINDOW_S`) whose window means of ``V`` (over ``[t - d - L / 2, t - d +
        L / 2]``) fit the velocity changes best; taken when the cost falls by more than
        the residuals' noise explains (:data:`WINDOW_F`) and to at most
        :data:`WINDOW_GAIN` of the cost at 0, else 0 (an ArduPilot SITL's GPS velocity:
        0.35 s, docs/navigation.md)."""
        assert est.delay is not None
        d = est.delay
        h = 0.5 * MAX_WINDOW_S
        _, sa = _v_at(t0, t, V, dv, seg, gt[i0] - d - h)
        _, sb = _v_at(t0, t, V, dv, seg, gt[i1] - d + h)
        use = (sa >= 0) & (sa == sb)
        if int(use.sum()) < 10:
            est.window_why = f"{int(use.sum())} GNSS fix pairs inside the IMU data"
            return
        grid = np.arange(0.0, MAX_WINDOW_S + 0.5 * WINDOW_GRID_S, WINDOW_GRID_S)
        cost = np.array([_cost_on(t0, t, V, dv, seg, gt, i0, i1, dz, comp, d, use, L)
                         for L in grid])
        k = int(np.argmin(cost))
        est.window_ratio = float(cost[k] / cost[0]) if cost[0] > 0 else 1.0
        m_eff = float(np.sum(comp & use[:, None])) / WINDOW_OVERLAP
        f = (cost[0] - cost[k]) / max(cost[k] / max(m_eff - 1.0, 1.0), 1e-300)
        if k == grid.size - 1:
            est.window_why = (f"the least cost is at the end of the range searched "
                              f"({MAX_WINDOW_S:g} s)")
        elif k == 0 or est.window_ratio > WINDOW_GAIN or f < WINDOW_F:
            est.window = 0.0
            est.window_why = (f"no window lowers the cost more than noise would (least "
                              f"{est.window_ratio:.2f} of the cost without one, at "
                              f"{grid[k]:.3f} s)")
        else:
            est.window = _least(grid, cost, k, 2)[0]

    def _integral(self, raw: bool = False) -> tuple[Array, Array, Array, Array, Array]:
        """(step starts, step ends (s), V (m/s) the integral of ``a_n`` (``raw``: without
        the filter's accelerometer bias) at every step's end from 0 at the start of each
        segment (linear inside a step), the steps' velocity changes, their segments)."""
        t = np.array(self._t)
        dt = np.array(self._dt)
        seg = np.array(self._seg)
        dv = np.array(self._a_raw if raw else self._a) * dt[:, None]
        V = np.cumsum(dv, axis=0)
        V -= _segment_base(V, dv, np.r_[True, seg[1:] != seg[:-1]])
        return t - dt, t, V, dv, seg

    def _pairs(self, pair_s: float) -> tuple[Array, Array, Array, Array]:
        """(fix times (s) and velocities in time order, the pairs (i0, i1): i1 the first
        fix at least ``pair_s`` after i0, if within 1.5 ``pair_s``)."""
        order = np.argsort(self._gt, kind="stable")  # fixes as they arrived: time order
        gt = np.array(self._gt)[order]
        gv = np.array(self._gv)[order]
        j = np.searchsorted(gt, gt + pair_s - 1e-6)
        i0 = np.flatnonzero(j < len(gt))
        i1 = j[i0]
        keep = gt[i1] - gt[i0] <= 1.5 * pair_s
        return gt, gv, i0[keep], i1[keep]

    def _down(self, mt: Array, gnss_delay: float, pair_s: float = PAIR_S
              ) -> tuple[Array, int]:
        """The down direction (NED, unit, per reading at ``mt`` s) as the filter's tilt
        error has it, and how many readings got a correction (:meth:`estimate_mag`)."""
        d = np.tile([0.0, 0.0, 1.0], (len(mt), 1))
        if len(self._t) < 10 or len(self._gt) < 10:
            return d, 0
        t0, t, V, dv, seg = self._integral(raw=True)
        gt, gv, i0, i1 = self._pairs(pair_s)
        wa, wb = gt[i0] - gnss_delay, gt[i1] - gnss_delay  # the spans the pairs measure
        if not len(wa):
            return d, 0
        va, sa = _v_at(t0, t, V, dv, seg, wa)
        vb, sb = _v_at(t0, t, V, dv, seg, wb)
        da = ((gv[i1] - gv[i0]) - (vb - va)) / (wb - wa)[:, None]  # GNSS - IMU, m/s^2
        da[:, 2] = np.where(np.isfinite(da[:, 2]), da[:, 2], 0.0)  # no vertical speed
        ok = (sa >= 0) & (sa == sb) & np.isfinite(da).all(axis=1)
        k = np.clip(np.searchsorted(wa, mt, side="right") - 1, 0, len(wa) - 1)
        use = (mt >= wa[k]) & (mt <= wb[k]) & ok[k]
        d[use] += da[k[use]] / (self._gravity or 9.80665)
        d /= np.linalg.norm(d, axis=1)[:, None]
        return d, int(use.sum())


def _least(grid: Array, cost: Array, k: int, m: int) -> tuple[float, float]:
    """(the least of the parabola through the grid points k-1, k, k+1 of ``cost``, its
    standard error ``sqrt(2 s2 / J'')`` with ``s2 = J_min / (m - 1)``, ``m`` the residual
    components; inf when the cost is not curved there)."""
    h = float(grid[1] - grid[0])
    c0, c1, c2 = float(cost[k - 1]), float(cost[k]), float(cost[k + 1])
    den = c0 - 2.0 * c1 + c2
    if not den > 0:
        return float(grid[k]), float("inf")
    d = float(grid[k]) + 0.5 * h * (c0 - c2) / den
    return d, float(np.sqrt(2.0 * (c1 / max(m - 1, 1)) / (den / h**2)))


def _segment_base(V: Array, dv: Array, first: Array) -> Array:
    """The value to take from the running sum ``V`` so that it starts at 0 at the start
    of every segment (the sum before the segment's first step)."""
    start = np.maximum.accumulate(np.where(first, np.arange(len(V)), 0))
    out: Array = (V - dv)[start]
    return out


def _v_at(t0: Array, t1: Array, V: Array, dv: Array, seg: Array, tq: Array
          ) -> tuple[Array, Array]:
    """V at the times ``tq`` (linear inside the step holding each) and the segment of
    that step (-1: outside every step)."""
    i = np.searchsorted(t1, tq)  # first step ending at or after tq
    inside = (i < len(t1))
    i = np.minimum(i, len(t1) - 1)
    inside &= tq >= t0[i]
    frac = np.clip((tq - t0[i]) / np.maximum(t1[i] - t0[i], 1e-12), 0.0, 1.0)
    v = V[i] - (1.0 - frac)[:, None] * dv[i]
    return v, np.where(inside, seg[i], -1)


def _v_mean(t0: Array, t1: Array, V: Array, dv: Array, seg: Array, tq: Array,
            window: float) -> Array:
    """V at the times ``tq`` (``window`` 0), or its mean over ``[tq - window / 2, tq +
    window / 2]`` (s) from :data:`WINDOW_POINTS` midpoints."""
    if not window:
        return _v_at(t0, t1, V, dv, seg, tq)[0]
    u = (np.arange(WINDOW_POINTS) + 0.5) / WINDOW_POINTS - 0.5  # midpoints in [-1/2, 1/2]
    out: Array = np.mean([_v_at(t0, t1, V, dv, seg, tq + window * x)[0] for x in u], axis=0)
    return out


def _cost_on(t0: Array, t1: Array, V: Array, dv: Array, seg: Array, gt: Array, i0: Array,
             i1: Array, dz: Array, comp: Array, d: float, use: Array,
             window: float = 0.0) -> float:
    """The cost at delay ``d`` (s) of the pairs ``use`` takes, the GNSS velocity the mean
    over ``window`` s (:func:`_v_mean`)."""
    va = _v_mean(t0, t1, V, dv, seg, gt[i0] - d, window)
    vb = _v_mean(t0, t1, V, dv, seg, gt[i1] - d, window)
    r = np.where(comp & use[:, None], dz - (vb - va), 0.0)
    return float(np.sum(r * r))


def estimate_gnss_delay(samples: Iterable[Any], opts: NavOptions, params: dict[str, Any],
                        runner: NavRunner, probe_s: float = PROBE_S, prior: float = 0.0,
                        prior_mag: float = 0.0, given: bool = False
                        ) -> tuple[DelayEstimate, MagEstimate, list[Any], Iterator[Any],
                                   BaroEstimate]:
    """Run ``runner`` (one navigation filter) on a :class:`NavStream` with ``opts`` and
    the delays ``prior`` (GNSS) and ``prior_mag`` (magnetometer, s) over the first
    ``probe_s`` s of IMU data of ``samples``, and estimate both delays from it (and the
    magnetometer's scatter), and the barometer's delay behind the GNSS height; ``given``:
    the GNSS delay ``prior`` is the user's, not estimated (the velocity window and the
    baro delay are estimated at it). Returns
    the GNSS and magnetometer estimates, the samples read (to be replayed in front of
    the rest), the iterator of the rest and the baro estimate."""
    it = iter(samples)
    held: list[Any] = []
    # the probe's inclination is measured with its own attitude from a start on the
    # accelerometer's angle: started on the magnetic model's, it put sitl_copter.tlog's
    # 0.15 deg off the SITL's field, not 0.06 (1.2 deg from the model's on vtol.tlog)
    stream = NavStream(opts=replace(opts, gnss_delay=prior, mag_delay=prior_mag,
                                    inclination_wmm=False), params=params)
    probe = DelayProbe()
    t_imu0: float | None = None
    mag_new = NewReadings()

    def feed(items: Iterable[Start | Step]) -> None:
        for item in items:
            if isinstance(item, Start):
                runner.start(item)
                probe.start()
            else:
                rec = runner.step(item)
                probe.add_step(item, np.asarray(rec.x, float))

    failed: InputError | None = None
    # the reader's own errors are not caught: the run, reading the same samples, would
    # meet them (caught here they ended the reading and the run went on with the probe's)
    for s in it:
        held.append(s)
        if isinstance(s, ImuSample):
            t_imu0 = s.t if t_imu0 is None else t_imu0
            if s.t - t_imu0 > probe_s:
                break
        try:
            feed(stream.push(s))
        except InputError as e:  # the probe's stream refused the data: the run may not
            failed = e
            break
        if isinstance(s, GnssSample) and s.source == stream.gnss_source:
            probe.add_gnss(s)
        elif isinstance(s, MagSample) and s.source == stream.mag_source:
            f = np.asarray(s.field, float)
            if mag_new.new(s.t, f):  # new readings only, as the stream's aiding
                probe.add_mag(s.t, f)
        elif isinstance(s, BaroSample) and s.source == stream.baro_source:
            probe.add_baro(s.t, baro_height(s))
    if failed is None:
        try:
            feed(stream.flush())
        except InputError as e:  # e.g. no start in the probe's span (NavNotStarted)
            failed = e
    if failed is not None:
        why = f"the probe run failed ({failed})"
        return (DelayEstimate(None, None, 0, 0.0, why), MagEstimate(None, None, 0, why), held,
                it, BaroEstimate(None, None, 0, why))
    est = probe.estimate(delay=prior if given else None)
    est.drift = probe.estimate_drift(stream.frame)
    lag = est.lag(prior)
    mest = probe.estimate_mag(gnss_delay=lag)
    mest.noise_default = float(stream.noise.mag_noise)
    est.imu_rate_hz = mest.imu_rate_hz = float(stream.summary.get("align_rate_hz") or 0.0)
    best = probe.estimate_baro(lag)
    best.noise_default = float(stream.noise.baro_noise)
    return est, mest, held, it, best


# ------------------------------------------------------------------ live

#: A live run first tries to estimate after this many seconds (vehicle time) of its
#: navigation steps, then every :data:`LIVE_CHECK_S` until :data:`PROBE_S` (as the
#: replay's probe, it looks at the start of the flight only).
LIVE_FIRST_S = 60.0
LIVE_CHECK_S = 30.0
#: A live run whose start had to choose the magnetometer's inclination between the
#: accelerometer-magnetometer angle and the magnetic model's
#: (:attr:`NavStream.inclination_choice <uavest.engine.navigation.NavStream.inclination_choice>`)
#: judges the choice from this many seconds (vehicle time) after its first step, every
#: :data:`INCL_CHECK_S` s until :data:`INCL_LAST_S` s: the field's inclination estimated
#: from the run's first filter (:meth:`DelayProbe.estimate_mag`, the tilt corrected by the
#: GNSS velocity changes) on at least :data:`INCL_MIN_READINGS` readings, and the model's
#: taken once the estimate has moved :data:`INCL_SHARE` of the way to it. On the
#: simulator's 60-s flights the estimate at 15-20 s is within 0.36 deg of the true field
#: on the seven seeds whose start took the model, and on the eighth (an accelerating
#: start, 1.23 deg off) 0.48 of the way at 20 s (docs/live.md, "The start's inclination,
#: judged live").
INCL_FIRST_S = 20.0
INCL_CHECK_S = 5.0
INCL_LAST_S = 60.0
INCL_MIN_READINGS = 200
#: The model's inclination is taken when the estimate has moved this share of the way
#: from the start's angle towards it: less than half, for the estimate leans towards the
#: field in use (the filter's tilt follows that field, and the GNSS corrects it only as
#: the vehicle manoeuvres).
INCL_SHARE = 0.4


class LiveDelayLearner:
    """The GNSS delay estimated during a live navigation run, from the run's own first
    filter (:class:`DelayProbe` fed through :meth:`tap`) and the fixes of the stream's
    receiver (:meth:`add_gnss`): tried :data:`LIVE_FIRST_S` s after the first step and
    every :data:`LIVE_CHECK_S` s up to :data:`PROBE_S` s; once found it is used from then
    on (:meth:`NavStream.set_gnss_delay`, a decision line), and estimated once more over a
    fresh stretch of the same length with the filter now running on it (the replay's
    refinement: the filter's attitude, fitted to fixes taken at the wrong time, pulls a
    first estimate towards the delay assumed). Unlike the replay's probe it runs on the
    run's own filter and its GNSS floors, not a weakly aided one of its own.

    The delay found is held here, outside the lane's history: a rewind of the stream to
    a checkpoint before it (:mod:`uavest.engine.history`) gets it again from
    :meth:`apply`. ``delay`` (s) is None until found; ``t_decided`` (s) and ``why`` say
    when and why, ``estimates`` every try (:meth:`as_dict`, the result document).

    With the delay ``given`` (s, ``--gnss-delay``) it is not estimated: the velocity
    window and the baro delay are, at the given delay, on the same schedule (decided when
    the window is; no refinement, the run already uses the delay)."""

    def __init__(self, first_s: float = LIVE_FIRST_S, check_s: float = LIVE_CHECK_S,
                 span_s: float = PROBE_S, given: float | None = None,
                 learn_mag_noise: bool = True) -> None:
        self.first_s, self.check_s, self.span_s = first_s, check_s, span_s
        self.given = None if given is None else float(given)
        #: the magnetometer's noise learnt with the delay (rad; None: not estimated), the
        #: scatter it came from and why: the spread of the readings' direction turned to
        #: NED with the filter's attitude, at the age the run takes them, within
        #: [:data:`MAG_NOISE_MIN`, the IMU source's profile], as the replay's probe takes
        #: it (not with ``learn_mag_noise`` False: an option or the vehicle's spec gave it)
        self.learn_mag_noise = bool(learn_mag_noise)
        self.mag_scatter: float | None = None
        self.mag_noise: float | None = None
        self.mag_noise_why = ""
        self._mag_est: MagEstimate | None = None
        self._mag_what = ""
        self.delay: float | None = None
        self.why = ""
        self.t_decided: float | None = None
        #: the GNSS velocity window (s) and the baro delay (s) found with the delay (None:
        #: not estimated), and why
        self.window: float | None = None
        self.window_why = ""
        self.baro_delay: float | None = None
        self.baro_why = ""
        #: the baro's spread against the GNSS height at that delay (m; None: not
        #: estimated), the noise taken from it (within [:data:`BARO_NOISE_MIN`, the IMU
        #: source's profile]: this run's from then on, and what a next run may start with,
        #: ``--aiding-from``), and the baro's offset to the GNSS altitude at that delay (m,
        #: :attr:`BaroEstimate.offset`: the stream's running offset, averaged while the
        #: baro's timing was not known, is off by more than that noise, docs/live.md)
        self.baro_spread: float | None = None
        self.baro_noise: float | None = None
        self.baro_noise_why = ""
        self.baro_offset: float | None = None
        self.estimates: list[dict[str, Any]] = []
        #: GNSS bias states sized from the fixes' drift with the delay (None: none), why,
        #: and the drift (``DriftEstimate`` fields)
        self.bias: dict[str, float] | None = None
        self.bias_why = ""
        self.drift: dict[str, Any] | None = None
        self._frame: Any = None  # the stream's local frame (the fixes' positions in it)
        self.label = ""
        self.done = False
        self._probe = DelayProbe()
        self._gen = 0  # a new probe (the refinement) is a new generation
        self._t0: float | None = None
        self._next = 0.0
        self._refining = False
        #: the magnetometer's inclination judged live (rad; None: the start's kept or not
        #: judged), when (s) and why, and every try; fed by its own probe
        self.inclination: float | None = None
        self.t_inclination: float | None = None
        self.inclination_why = ""
        self.inclination_tries: list[dict[str, Any]] = []
        self._choice: tuple[float, float, str] | None = None
        self._iprobe = DelayProbe()
        self._incl_done = False
        self._it0: float | None = None
        self._inext = 0.0
        self._last_mag: Array | None = None

    # ---------------------------------------------------------------- feeding
    def tap(self, runner: Any) -> _Tap:
        """The estimator to put in the lane in place of ``runner`` (the run's first
        navigation filter): the same records, its steps also fed to the probe."""
        self.label = str(runner.label)
        return _Tap(runner, self)

    def add_gnss(self, s: GnssSample, source: str | None) -> None:
        """A fix as it arrives (each once: the sinks' ``sample``), when it is from the
        stream's receiver ``source`` (None: none chosen yet)."""
        if source is None or s.source != source:
            return
        if not self.done:
            self._probe.add_gnss(s)
        if not self._incl_done:
            self._iprobe.add_gnss(s)

    def add_mag(self, s: MagSample, source: str | None) -> None:
        """A magnetometer sample as it arrives, when it is from the stream's magnetometer
        ``source``: each new reading once (a reading repeated in every IMU message, as a
        RAW_IMU's, is one), to the inclination's probe until the inclination is judged and
        to the delay's probe while it learns (the magnetometer's noise)."""
        to_incl = not self._incl_done
        to_delay = self.learn_mag_noise and not self.done
        if not (to_incl or to_delay) or source is None or s.source != source:
            return
        f = np.asarray(s.field, float)
        if self._last_mag is None or not np.array_equal(f, self._last_mag):
            self._last_mag = f
            if to_incl:
                self._iprobe.add_mag(s.t, f)
            if to_delay:
                self._probe.add_mag(s.t, f)

    def add_baro(self, s: BaroSample, source: str | None) -> None:
        """A baro sample as it arrives, when it is from the stream's barometer ``source``."""
        if not self.done and source is not None and s.source == source:
            self._probe.add_baro(s.t, baro_height(s))

    def _mark(self) -> tuple[int, tuple[int, int], tuple[int, int]]:
        return self._gen, self._probe.mark(), self._iprobe.mark()

    def _rewind(self, mark: tuple[int, tuple[int, int], tuple[int, int]]) -> None:
        """Back to ``mark`` (the history restored the filter): the steps after it are made
        again. GNSS fixes and magnetometer readings come once, from the sinks' side, and
        stay."""
        gen, at, iat = mark
        # a probe made after the mark (the refinement's): all of its steps are re-made
        self._probe.rewind(at if gen == self._gen else (0, 0))
        self._iprobe.rewind(iat)

    def _start(self) -> None:
        if not self.done:
            self._probe.start()
        if not self._incl_done:
            self._iprobe.start()

    def _step(self, st: Step, x: Array) -> None:
        if not self._incl_done:
            self._iprobe.add_step(st, x)
            if self._it0 is None:
                self._it0 = float(st.t)
                self._inext = self._it0 + INCL_FIRST_S
            elif st.t >= self._inext:
                self._judge(float(st.t))
        if self.done:
            return
        self._probe.add_step(st, x)
        if self._t0 is None:
            self._t0 = float(st.t)
            self._next = self._t0 + self.first_s
        if st.t >= self._next:
            self._check(float(st.t))

    # ---------------------------------------------------------------- deciding
    def _check(self, t: float) -> None:
        assert self._t0 is not None
        span = t - self._t0
        est = self._probe.estimate(delay=self.given)
        self.estimates.append({"t": t, "span_s": span, "delay": est.delay, "sd": est.sd,
                               "pairs": est.pairs, "why": est.why,
                               "refinement": self._refining})
        last = span + self.check_s > self.span_s or (self._refining and est.delay is None)
        if self.given is not None:  # the window (and the baro delay) at the given delay
            self.estimates[-1].update(window=est.window, window_why=est.window_why,
                                      data_delay=est.data_delay)
            if est.window is not None:
                self.t_decided, self.done = t, True
                self._aids(est, self.given, span)
                return
        elif est.delay is not None:
            d, neg = delay_used(est.delay)
            assert est.sd is not None
            self.delay, self.t_decided = d, t
            self._aids(est, d, span)
            self.why = (f"estimated live{neg}: the lag of the GNSS velocity behind the IMU "
                        f"({self.label}, {est.pairs} fix pairs over {span:.0f} s of "
                        f"{'the run with the first estimate' if self._refining else 'navigation'},"
                        f" standard error {est.sd * 1e3:.1f} ms"
                        f"{', refined' if self._refining else ''}; --gnss-delay S to set it)")
            if self._refining:
                self.done = True
            else:  # once more, over a fresh stretch as long, with the delay in use
                self._refining = True
                self._gen += 1
                self._probe = DelayProbe()
                self._t0, self._next = t, t + span
            return
        if last:
            self.done = True
        else:
            self._next = t + self.check_s

    def _judge(self, t: float) -> None:
        """Judge the start's inclination choice (:data:`INCL_FIRST_S`)."""
        assert self._it0 is not None
        if self._choice is None:  # the start had none to make
            self._incl_done = True
            return
        start, wmm, wwhy = self._choice
        span = t - self._it0
        d = self.delay if self.delay is not None else (self.given or 0.0)
        est = self._iprobe.estimate_mag(gnss_delay=d)
        inc = est.inclination if est.tilt_corrected >= INCL_MIN_READINGS else None
        self.inclination_tries.append({"t": t, "span_s": span, "inclination": inc,
                                       "readings": est.tilt_corrected})
        if inc is not None and (inc - start) / (wmm - start) > INCL_SHARE:
            self.inclination, self.t_inclination = wmm, t
            self.inclination_why = (
                f"the magnetic model ({wwhy}), judged live: the field estimated from "
                f"{self.label}'s attitude with its tilt corrected by the GNSS velocity "
                f"changes ({est.tilt_corrected} readings over {span:.0f} s) is at "
                f"{np.degrees(inc):.2f} deg, more than {INCL_SHARE:g} of the way to it from the "
                f"start's {np.degrees(start):.2f} deg (an accelerating start)")
            self._incl_done = True
        elif span + INCL_CHECK_S > INCL_LAST_S:
            self._incl_done = True
        else:
            self._inext = t + INCL_CHECK_S

    def _aids(self, est: DelayEstimate, d: float, span: float) -> None:
        """The velocity window and the baro delay that go with a delay ``d`` found."""
        what = (f"{self.label}, over {span:.0f} s of "
                f"{'the run with the first estimate' if self._refining else 'navigation'}"
                + ("" if self.given is None else
                   f", at the given GNSS delay {d:g} s{est.given_note()}"))
        self.estimates[-1]["window"] = est.window  # (each try's: JSON tries[].window)
        if est.window is not None:
            self.window = est.window
            self.window_why = (
                f"estimated live: the GNSS velocity is the mean over this window ({what}, "
                f"{est.window_ratio:.2f} of the cost without one)" if est.window else
                f"estimated live: none ({est.window_why})")
        if self.drift is None and self._frame is not None:
            dr = self._probe.estimate_drift(self._frame)
            self.drift = dr.as_dict()
            bias, why = dr.bias_model()
            if bias is not None:
                self.bias = bias
                self.bias_why = f"estimated live: {why} ({what})"
        if self.learn_mag_noise:
            # (the scatter at the run's own magnetometer age is taken in apply)
            self._mag_est, self.mag_scatter, self.mag_noise = (
                self._probe.estimate_mag(gnss_delay=est.lag(d)), None, None)
            self._mag_what = what
        best = self._probe.estimate_baro(est.lag(d))
        self.estimates[-1]["baro_delay"] = best.delay
        if best.delay is not None:
            assert best.sd is not None
            self.baro_delay, _ = delay_used(best.delay)
            self.baro_why = (f"estimated live: the lag at which the baro heights, against the "
                             f"GNSS heights at the GNSS delay, spread least ({what}, "
                             f"standard error {best.sd * 1e3:.1f} ms)")
            self.baro_spread, self.baro_noise = best.spread, None
            self.baro_offset = best.offset

    def apply(self, stream: Any) -> None:
        """Give ``stream`` (a :class:`NavStream`) the delay found, if it does not have it
        yet (after the decision, or after a rewind or a restart took it back)."""
        if getattr(stream, "_builder", None) is None:
            return
        self._frame = getattr(stream, "frame", None)
        self._choice = getattr(stream, "inclination_choice", None)
        if self.inclination is not None and \
                stream.summary.get("inclination_rad") != self.inclination:
            stream.set_mag_inclination(self.inclination, float(self.t_inclination or 0.0),
                                       self.inclination_why)
        if self.t_decided is None:
            rate = float(stream.summary.get("align_rate_hz") or 0.0)
            if not self.done and 0 < rate < PROBE_MIN_IMU_HZ:
                self.done = self._incl_done = True
                self.estimates.append({"t": None, "why": (
                    f"the IMU at {rate:.1f} Hz is too coarse to time the aiding against "
                    f"(needs {PROBE_MIN_IMU_HZ:g} Hz)")})
            return
        if self.delay is not None and stream.delay != self.delay:
            stream.set_gnss_delay(self.delay, self.t_decided, self.why)
        # (a window or baro delay found equal to the stream's default is news too: the
        # stream then drops the floor it keeps while they are unknown)
        if self.window is not None and (stream.vel_window != self.window
                                        or not stream.window_known):
            stream.set_gnss_window(self.window, self.t_decided, self.window_why)
        if self.baro_delay is not None and (stream.baro_delay != self.baro_delay
                                            or not stream.baro_known):
            stream.set_baro_delay(self.baro_delay, self.t_decided, self.baro_why)
        if self.baro_spread is not None and self.baro_noise is None:
            # at most the source's profile, not the noise this run has: one started with
            # a previous run's (``--aiding-from``) would otherwise never suggest more
            self.baro_noise, self.baro_noise_why = baro_noise_from_spread(
                self.baro_spread, stream.source_noise.baro_noise)
        if self.baro_noise is not None and stream.baro_fit != (self.baro_noise,
                                                               self.baro_offset):
            stream.set_baro_fit(self.baro_noise, self.baro_offset, self.t_decided,
                                f"estimated live: {self.baro_noise_why}")
        if self.bias is not None and not stream.noise.gnss_bias:
            stream.set_gnss_bias(self.bias, self.t_decided, self.bias_why)
        if self._mag_est is not None and self.mag_noise is None:
            age = float(getattr(stream, "mag_delay", 0.0) or 0.0)  # s, the run's own
            sc = self._mag_est.scatter_at(age)
            self._mag_est = None
            if sc is not None:
                self.mag_scatter = sc
                used, why = mag_noise_from_scatter(sc, stream.source_noise.mag_noise)
                self.mag_noise = used
                self.mag_noise_why = (f"estimated live: {why}; {self._mag_what}, the readings "
                                      f"at the run's magnetometer age, {age * 1e3:.0f} ms")
        if self.mag_noise is not None and stream.noise.mag_noise != self.mag_noise:
            stream.set_mag_noise(self.mag_noise, float(self.t_decided), self.mag_noise_why)

    def as_dict(self) -> dict[str, Any]:
        """For the result document: the delay used (None: not estimated) and every try."""
        return {"delay": self.delay, "given": self.given, "t": self.t_decided,
                "why": self.why or None,
                "window": self.window, "baro_delay": self.baro_delay,
                "baro_spread": self.baro_spread, "baro_noise": self.baro_noise,
                "baro_offset": self.baro_offset,
                "mag_scatter": self.mag_scatter, "mag_noise": self.mag_noise,
                "gnss_drift": self.drift, "gnss_bias": self.bias,
                "filter": self.label or None, "tries": self.estimates,
                "inclination": {
                    "choice": None if self._choice is None else list(self._choice[:2]),
                    "value": self.inclination, "t": self.t_inclination,
                    "why": self.inclination_why or None, "tries": self.inclination_tries}}


class _Tap:
    """A navigation filter runner whose steps also feed a :class:`LiveDelayLearner`; its
    history snapshot carries the learner's place (:meth:`LiveDelayLearner._mark`)."""

    def __init__(self, runner: Any, learner: LiveDelayLearner) -> None:
        self.runner = runner
        self.learner = learner

    @property
    def label(self) -> str:
        return str(self.runner.label)

    @property
    def started_from(self) -> Any:
        return getattr(self.runner, "started_from", None)

    def start(self, st: Start) -> None:
        self.runner.start(st)
        if st.augment is None:  # the same run with more states: not a new segment
            self.learner._start()

    def step(self, st: Step) -> Any:
        rec = self.runner.step(st)
        if st.u is not None:
            self.learner._step(st, np.asarray(rec.x, float))
        return rec

    def snapshot(self) -> Any:
        return self.runner.snapshot(), self.learner._mark()

    def restore(self, snap: Any) -> None:
        base, mark = snap
        self.runner.restore(base)
        self.learner._rewind(mark)
