"""Attitude replay of a flight log, and of any sample stream, through the streaming engine.

source (:func:`uavest.ingest.open_source`: tlog, DataFlash, ULog, live link) ->
:class:`~uavest.engine.attitude.AttitudeStream` (alignment, pre-integration, grouping)
-> one :class:`~uavest.engine.runner.FilterRunner` per filter -> sinks: the streaming
scorer (:class:`uavest.eval.attitude.AttitudeScorer`, every reference at once), the
caller's sinks (JSON, MCAP, progress...), and with ``smooth`` a collector for the RTS
smoother (:mod:`uavest.engine.smooth`; the only part that holds the whole run).

Every filter's randomness comes from ``uavest.seeding.rng(seed, 0, "filter:<label>")``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..compiled import load_seconds
from ..core.spec import FilterSpec
from ..engine.attitude import AttitudeOptions, AttitudeStream
from ..engine.build import build_filters
from ..engine.gnss_delay import baro_noise_from_spread, mag_noise_from_scatter
from ..engine.loop import Lane, run_lanes
from ..engine.navigation import NavNotStarted, NavOptions, NavRunner, NavStream
from ..engine.records import RunInfo, StepRecord, package_versions
from ..engine.runner import FilterRunner
from ..engine.smooth import smooth_records
from ..errors import InputError
from ..eval.attitude import AttitudeScorer, choose_reference, nees_attitude, rmse_deg
from ..eval.navigation import NavScorer, gyro_bias_trend
from ..geometry.rotation import quat_slerp_interp
from ..ingest.types import (
    AttitudeRef,
    GnssSample,
    ImuSample,
    IngestError,
    MagSample,
    NoSamplesError,
    PositionSample,
)
from ..models.navigation import NavNoise, names_gnss_bias, nav_dim
from ..presets import resolve_list, spec_labels
from ..seeding import filter_stream, rng
from ..sinks.base import Collector, Sink
from .sensor_spec import GNSS_BIAS_KEYS, read_log_spec, with_sensor_spec

if TYPE_CHECKING:
    from ..engine.gnss_delay import BaroEstimate, DelayEstimate, DriftEstimate, MagEstimate

Array = np.ndarray

__all__ = [
    "DEFAULT_FILTERS", "ArrayRun", "ReplayConfig", "model_filters", "replay", "replay_arrays",
    "replay_samples", "samples_from_arrays",
]

DEFAULT_FILTERS = ("ekf", "ukf", "hybrid")
#: ``--model auto`` looks this far into the IMU data (s) for a GNSS fix stream.
MODEL_PEEK_S = 60.0
MODELS = ("auto", "nav", "attitude")
#: ... and wants this many 3-D fixes of one receiver (a fix stream, not a few fixes).
MIN_FIXES = 10


@dataclass
class ReplayConfig:
    """Options of :func:`replay` (see ``uavest replay --help`` for their meanings): the
    filters (spec strings, resolved with the ``attitude`` preset), smoothing, the seed,
    and the :class:`~uavest.engine.attitude.AttitudeOptions` fields."""

    filters: tuple[str | FilterSpec, ...] = DEFAULT_FILTERS  # text or resolved specs
    start: float | None = None
    end: float | None = None
    smooth: bool = False
    seed: int = 0
    rate_hz: float | None = None
    update_hz: float | None = None
    integration: str = "auto"
    declination: float | None = None  # rad; None -> log params, else 0
    noise: dict = field(default_factory=dict)
    imu: str | None = None
    use_mag: bool = True
    accel_comp: str = "auto"
    mag_mode: str = "field"
    mag_delay: float | None = None  # s; None: estimated (navigation), 0 (attitude-only)
    baro_delay: float | None = None  # s; None: estimated (navigation), else as given
    geodesy: str = "auto"  # navigation: the local frame's (NavOptions.geodesy)
    #: the library default stays the attitude model (the one whose results the golden
    #: files and earlier tables hold); ``uavest replay`` defaults to "auto"
    model: str = "attitude"
    gnss_delay: float | None = None  # s; None -> estimated (estimate_delay), else default
    #: with ``gnss_delay`` None: estimate it from the log (:func:`probe_gnss_delay`)
    estimate_delay: bool = True
    model_why: str | None = None  # why a fixed ``model`` (None: "option --model")

    def attitude_options(self) -> AttitudeOptions:
        names = {f.name for f in fields(AttitudeOptions)}
        kw = {k: v for k, v in vars(self).items() if k in names}
        kw["mag_delay"] = kw.get("mag_delay") or 0.0
        return AttitudeOptions(**kw)

    def nav_options(self) -> NavOptions:
        names = {f.name for f in fields(NavOptions)}
        return NavOptions(**{k: v for k, v in vars(self).items() if k in names})


#: The filter of the GNSS delay probe (``attitude`` preset, navigation state).
PROBE_FILTER = "ekf"
#: The probe filter's GNSS floors (m/s, m; at least these): weak aiding, so that its
#: attitude, fitted to GNSS velocities taken at the wrong time, pulls the estimate less
#: away from the delay the probe assumes (about 2-6 % of the difference, against 5-10 %
#: with the run's own floors, on the SITL flight and sim_200hz with 0.15 s injected).
PROBE_FLOORS = {"gnss_vel_floor": 1.0, "gnss_pos_floor": 2.0}
#: A first estimate further than this (s) from the probe's assumed delay is refined by a
#: second probe run assuming it (over the samples the first one held).
PROBE_REFINE_S = 0.03


def probe_gnss_delay(samples: Iterable, cfg: ReplayConfig, params: dict | None
                     ) -> tuple[dict, Iterator]:
    """The GNSS and magnetometer delays and the magnetometer's noise of a log, estimated
    before the run where ``cfg`` leaves them open (``gnss_delay`` / ``mag_delay`` None,
    no ``mag_noise`` in ``cfg.noise``): one navigation EKF over the first
    :data:`~uavest.engine.gnss_delay.PROBE_S` s of IMU data
    (:func:`~uavest.engine.gnss_delay.estimate_gnss_delay`), run again over the samples
    it held when an estimate is far from the delay it assumed. Returns the document
    (``delay``, ``sd`` s or None, ``pairs``, ``excitation`` (m/s)^2, ``why``,
    ``delay_used`` s, ``why_used``; ``mag`` the same for the magnetometer with
    ``scatter`` rad and ``noise_used`` rad / ``noise_why``; ``probe_runs``) and the same
    samples (the held ones in front)."""
    import itertools

    from ..engine.gnss_delay import PROBE_S

    opts = cfg.nav_options()  # checks the --noise names
    noise = NavNoise().with_(**cfg.noise)
    opts = replace(opts, noise={**cfg.noise, **{
        k: max(v, float(getattr(noise, k))) for k, v in PROBE_FLOORS.items()}})
    est, mest, held, rest, runs, best = _run_probes(samples, cfg, params, opts)
    span = f"the first {PROBE_S:g} s of IMU data"
    refined = ", refined once" if runs == 2 else ""
    doc: dict = {"probe_runs": runs}
    if cfg.gnss_delay is None:
        doc.update(_gnss_delay_doc(est, noise, span, refined))
    else:  # the window at the delay given
        doc.update(_window_doc(est, f" at the given GNSS delay {cfg.gnss_delay:g} s"
                                    f"{est.given_note()}"))
        doc.update(data_delay=est.data_delay, data_sd=est.data_sd)
    if est.drift is not None:
        doc["gnss_drift"] = _drift_doc(est.drift, span, names_gnss_bias(cfg.noise))
    doc["mag"] = _mag_doc(cfg, mest, noise, span, refined)
    doc["baro"] = _baro_doc(cfg, best, noise, span)
    return doc, itertools.chain(held, rest)


def _run_probes(samples: Iterable, cfg: ReplayConfig, params: dict | None, opts: NavOptions
                ) -> tuple[DelayEstimate, MagEstimate, list, Iterator, int, BaroEstimate]:
    """The probe (:data:`PROBE_FILTER` on the stream options ``opts``) over the first
    samples, run a second time over the held ones from the estimated delays when either
    is more than :data:`PROBE_REFINE_S` from the one it assumed: (GNSS estimate,
    magnetometer estimate, held samples, the rest, runs). An IMU slower than
    :data:`~uavest.engine.gnss_delay.PROBE_MIN_IMU_HZ` leaves both estimates None."""
    from ..engine.gnss_delay import PROBE_MIN_IMU_HZ, estimate_gnss_delay

    (sp, flt), = model_filters((PROBE_FILTER,), True, cfg.noise)

    def probe(src: Iterable, prior: float, prior_mag: float):
        runner = NavRunner("gnss delay probe", flt, rng(cfg.seed, 0, "probe:gnss_delay"))
        return estimate_gnss_delay(src, opts, params or {}, runner, prior=prior,
                                   prior_mag=prior_mag, given=cfg.gnss_delay is not None)

    prior = 0.0 if cfg.gnss_delay is None else float(cfg.gnss_delay)
    prior_m = 0.0 if cfg.mag_delay is None else float(cfg.mag_delay)
    est, mest, held, rest, best = probe(samples, prior, prior_m)
    runs = 1
    if 0 < est.imu_rate_hz < PROBE_MIN_IMU_HZ:  # (0: the probe run failed, why says why)
        why = (f"the IMU at {est.imu_rate_hz:.1f} Hz is too coarse to time the aiding "
               f"against (the probe needs {PROBE_MIN_IMU_HZ:g} Hz)")
        est.delay = est.window = mest.delay = mest.scatter = mest.inclination = None
        best.delay = None
        est.why = est.window_why = mest.why = best.why = why
    far_g = cfg.gnss_delay is None and est.delay is not None and abs(
        est.delay - prior) > PROBE_REFINE_S
    far_m = cfg.mag_delay is None and mest.delay is not None and abs(
        mest.delay - prior_m) > PROBE_REFINE_S
    if far_g or far_m:
        prior = est.delay if far_g and est.delay is not None else prior
        prior_m = mest.delay if far_m and mest.delay is not None else prior_m
        est2, mest2, _, _, best2 = probe(held, prior, prior_m)
        runs = 2
        est = est2 if est2.delay is not None or est.delay is None else est
        mest = mest2 if mest2.delay is not None or mest.delay is None else mest
        best = best2 if best2.delay is not None or best.delay is None else best
    return est, mest, held, rest, runs, best


def model_filters(filters: str | Sequence[str | FilterSpec], nav: bool, noise: dict
                  ) -> list[tuple[FilterSpec, Any]]:
    """The filters ``filters`` built for the model a run takes (``uavest replay`` and
    ``uavest run``): resolved in the ``nav`` preset at the navigation state's dimension for
    the ``--noise`` overrides ``noise`` (15, or 18 with the GNSS bias states) when ``nav``,
    else in the ``attitude`` preset at 6; (spec, filter) pairs."""
    return build_filters(resolve_list(filters, "nav" if nav else "attitude",
                                      dim=nav_dim(noise) if nav else 6))


def check_attitude_noise(noise: dict, where: str) -> None:
    """A clear error when ``--noise`` names a navigation-only parameter for the attitude
    model (``where`` ends the message: which run)."""
    from ..models.attitude import AttitudeNoise

    bad = sorted(set(noise) - set(AttitudeNoise.__dataclass_fields__))
    if bad:
        raise InputError(f"--noise {bad[0]}: a parameter of the navigation model, not "
                         f"of the attitude-only model {where}")


def _gnss_delay_doc(est: DelayEstimate, noise: NavNoise, span: str, refined: str) -> dict:
    """The GNSS part of the probe's document: the estimate and the delay the run takes
    (the estimate clipped to [0, 2] s, else the model's default) with why."""
    from ..engine.gnss_delay import delay_used

    if est.delay is not None:
        used, neg = delay_used(est.delay)
        why = (f"estimated{neg}: the lag of the GNSS velocity behind the IMU "
               f"({PROBE_FILTER}, {est.pairs} fix pairs in {span}, standard error "
               f"{est.sd * 1e3:.1f} ms{refined}; --gnss-delay S to set it)")
    else:
        used = float(noise.gnss_delay)
        why = f"default (not estimated: {est.why})"
    doc = {"delay": est.delay, "sd": est.sd, "pairs": est.pairs,
           "excitation": est.excitation, "why": est.why, "delay_used": used,
           "why_used": why}
    return {**doc, **_window_doc(est)}


def _drift_doc(d: DriftEstimate, span: str, bias_set: bool) -> dict:
    """The GNSS position drift part of the probe's document, with what it means, and the
    GNSS bias states it sizes (``bias_used``, ``bias_why``) unless ``bias_set`` (by
    ``--noise`` or the vehicle's sensor spec)."""
    from ..engine.gnss_delay import DRIFT_LONG_S, DRIFT_SHORT_S

    doc: dict = {"short_s": DRIFT_SHORT_S, "long_s": DRIFT_LONG_S, **d.as_dict(),
                 "why": d.why or None}
    bias, bwhy = d.bias_model()
    if bias is not None and not bias_set:
        doc["bias_used"] = bias
        doc["bias_why"] = f"estimated: {bwhy} (--noise gnss_bias_tau=0 for none)"
    if d.short is not None and d.long is not None:
        if not d.correlated:
            means = "no error correlated over seconds"
        elif bias_set:
            means = ("errors correlated over seconds; the GNSS bias states as given (--noise "
                     "or the vehicle's sensor spec)")
        elif bias is not None:
            means = f"errors correlated over seconds, carried as GNSS bias states ({bwhy})"
        else:
            means = (f"errors correlated over seconds, which the filters take as independent "
                     f"fixes: their position NEES is optimistic (no GNSS bias states: {bwhy})")
        doc["text"] = (
            f"the fixes' positions less their integrated velocities move {d.short:.3f} m "
            f"over {DRIFT_SHORT_S:g} s and {d.long:.3f} m over {DRIFT_LONG_S:g} s (rms per "
            f"horizontal axis, {d.pairs} pairs in {span}): {means}")
    return doc


def _window_doc(est: DelayEstimate, at: str = "") -> dict:
    """The GNSS velocity window part of the probe's document (estimated at the delay
    ``est.delay``; ``at`` says which, when it was given)."""
    doc: dict = {"window": est.window, "window_ratio": est.window_ratio,
                 "window_why": est.window_why}
    if est.window:
        doc["window_used"] = est.window
        doc["window_why_used"] = (
            f"estimated{at}: the GNSS velocity is the mean over this window, centred on "
            f"the delay (the window's means of the IMU's velocity fit the velocity changes "
            f"with {est.window_ratio:.2f} of the cost without one; "
            f"--noise gnss_vel_window=S to set it)")
    elif est.window is not None:  # (None: not known, the stream keeps its floor)
        doc["window_why_used"] = f"estimated{at}: none ({est.window_why})"
    return doc


def _baro_doc(cfg: ReplayConfig, best: BaroEstimate, noise: NavNoise, span: str) -> dict:
    """The barometer part of the probe's document: the estimate, and what the run takes
    from it where ``cfg`` leaves it open (the delay; the noise, the spread clipped to
    [:data:`~uavest.engine.gnss_delay.BARO_NOISE_MIN`, the IMU source's default]) with
    why."""
    from ..engine.gnss_delay import delay_used

    b: dict = {"delay": best.delay, "sd": best.sd, "samples": best.samples,
               "why": best.why, "spread": best.spread}
    if best.delay is None:  # the run takes 0 and the baro's noise for an unknown delay
        if cfg.baro_delay is None and best.samples:
            b["why_used"] = f"default (not estimated: {best.why})"
        return b
    if cfg.baro_delay is None:
        used, neg = delay_used(best.delay)
        assert best.sd is not None
        b["delay_used"] = used
        b["why_used"] = (f"estimated{neg}: the lag at which the baro heights, against the "
                         f"GNSS heights at the GNSS delay, spread least ({best.samples} "
                         f"samples in {span}, standard error {best.sd * 1e3:.1f} ms; "
                         "--baro-delay S to set it)")
    if "baro_noise" not in cfg.noise and best.spread is not None:
        top = float(best.noise_default or noise.baro_noise)
        b["noise_used"], why = baro_noise_from_spread(best.spread, top)
        b["noise_why"] = f"estimated: {why}"
    return b


def _mag_doc(cfg: ReplayConfig, mest: MagEstimate, noise: NavNoise, span: str, refined: str
             ) -> dict:
    """The magnetometer part of the probe's document: the estimate, and what the run
    takes from it where ``cfg`` leaves it open (the delay, the inclination, the noise
    clipped to [:data:`~uavest.engine.gnss_delay.MAG_NOISE_MIN`, the IMU source's
    default]) with why."""
    m: dict = {"delay": mest.delay, "sd": mest.sd, "readings": mest.readings,
               "why": mest.why, "scatter": mest.scatter}
    if cfg.mag_delay is None and mest.readings:
        if mest.delay is not None:
            m["delay_used"] = float(mest.delay)
            sd = "" if mest.sd is None else f", standard error {mest.sd * 1e3:.1f} ms"
            m["why_used"] = (f"estimated: the age at which the readings, turned to NED with "
                             f"the {PROBE_FILTER}'s attitude, spread least ({mest.readings} "
                             f"new readings in {span}{sd}{refined}; --mag-delay S to set it)")
        else:
            m["delay_used"], m["why_used"] = 0.0, f"default (not estimated: {mest.why})"
    if mest.inclination is not None and mest.delay is not None:
        m["inclination"] = mest.inclination
        m["inclination_uncorrected"] = mest.inclination_uncorrected
        tilt = (f", against the down direction corrected for its tilt error by the GNSS "
                f"velocity changes for {mest.tilt_corrected} of them (uncorrected "
                f"{np.degrees(mest.inclination_uncorrected or 0.0):.2f} deg)"
                if mest.tilt_corrected else "")
        m["inclination_why"] = (f"estimated: the mean direction of the readings turned to "
                                f"NED with the {PROBE_FILTER}'s attitude ({mest.readings} new "
                                f"readings in {span}{tilt})")
    if "mag_noise" not in cfg.noise and mest.scatter is not None and mest.delay is not None:
        used, why = mag_noise_from_scatter(mest.scatter,
                                           float(mest.noise_default or noise.mag_noise))
        m["noise_used"], m["noise_why"] = used, f"estimated: {why}"
    return m


def _good_fix(s) -> bool:
    return (isinstance(s, GnssSample) and s.fix_type >= 3
            and bool(np.isfinite(s.lat_lon_alt[:2]).all()))


def choose_model(samples: Iterable, model: str = "auto", why: str | None = None
                 ) -> tuple[Iterator, dict]:
    """(the same samples, the model decision): ``model`` "nav" / "attitude" as given;
    "auto" looks at the first :data:`MODEL_PEEK_S` s of IMU data for a raw GNSS fix
    stream (:data:`MIN_FIXES` 3-D fixes with a finite position of one receiver):
    navigation if there is one, attitude-only otherwise. The samples looked at are held
    and handed back in front of the rest. The decision is a dict of ``what``, ``value``
    ("nav" | "attitude"), ``t`` (s, None for an option), ``why`` and ``fix_stream``
    (a fix stream was found: a navigation run may start unaided before its first fix,
    ``NavOptions.before_fix``; looked for under ``--model nav`` too)."""
    if model not in MODELS:
        raise InputError(f"--model must be one of {', '.join(MODELS)}, not {model!r}")
    it = iter(samples)
    if model == "attitude":
        return it, {"what": "model", "value": model, "t": None,
                    "why": why or "option --model", "fix_stream": False}
    import itertools

    held: list = []
    t_imu0 = None
    fixes: dict[str, int] = {}
    for s in it:
        held.append(s)
        if _good_fix(s):
            n = fixes[s.source] = fixes.get(s.source, 0) + 1
            if n >= MIN_FIXES:
                return itertools.chain(held, it), {
                    "what": "model", "value": "nav", "t": None if model == "nav" else s.t,
                    "why": why or "option --model" if model == "nav" else
                    f"the log carries a raw GNSS fix stream ({s.source}: "
                    f"{MIN_FIXES} 3-D fixes by t={s.t:.1f} s)", "fix_stream": True}
        if isinstance(s, ImuSample):
            t_imu0 = s.t if t_imu0 is None else t_imu0
            if s.t - t_imu0 > MODEL_PEEK_S:
                break
    if model == "nav":
        return itertools.chain(held, it), {"what": "model", "value": "nav", "t": None,
                                            "why": why or "option --model",
                                            "fix_stream": False}
    t = next((s.t for s in held if isinstance(s, ImuSample)), held[0].t if held else None)
    seen = sorted({s.source for s in held if isinstance(s, GnssSample)})
    if fixes:
        why = (f"no GNSS fix stream: {max(fixes.values())} 3-D fixes in the first "
               f"{MODEL_PEEK_S:g} s of IMU data (a stream needs {MIN_FIXES})")
    else:
        why = (f"no 3-D GNSS fix in the first {MODEL_PEEK_S:g} s of IMU data"
               + (f" ({', '.join(seen)} without one)" if seen else " (no raw GNSS stream)"))
    return itertools.chain(held, it), {"what": "model", "value": "attitude", "t": t,
                                        "why": why, "fix_stream": False}


class _Score(Sink):
    """Feeds the streaming scorer: references from the samples, attitudes from records."""

    def __init__(self, scorer: AttitudeScorer) -> None:
        self.scorer = scorer

    def sample(self, s) -> None:
        if isinstance(s, AttitudeRef):
            self.scorer.add_reference(s.source, s.kind, s.t, s.q)

    def record(self, rec: StepRecord) -> None:
        if isinstance(rec, StepRecord):  # attitude records (trackers make ScanRecords)
            self.scorer.add_estimate(rec.t, rec.estimator, rec.x[:4], rec.P)


class _NavScore(Sink):
    """Feeds the navigation scorer: attitude and position references, estimates."""

    def __init__(self, scorer: NavScorer) -> None:
        self.scorer = scorer

    def sample(self, s) -> None:
        if isinstance(s, AttitudeRef):
            self.scorer.add_attitude(s.source, s.t, s.q)
        elif isinstance(s, PositionSample):
            self.scorer.add_position(s.source, s.t, s.ned, s.vel_ned, s.lat_lon_alt)

    def record(self, rec: StepRecord) -> None:
        if isinstance(rec, StepRecord):
            self.scorer.add_estimate(rec.estimator, rec.t, rec.x, rec.P)


class _GyroBias(Sink):
    """The first navigation filter's gyro bias estimate (rad/s) and std at each step, for
    :func:`~uavest.eval.navigation.gyro_bias_trend`."""

    def __init__(self) -> None:
        self.label: str | None = None
        self.t: list[float] = []
        self.b: list[Array] = []
        self.sd: list[Array] = []

    def record(self, rec: StepRecord) -> None:
        if not isinstance(rec, StepRecord):
            return
        if self.label is None:
            self.label = rec.estimator
        if rec.estimator != self.label or len(rec.x) < 16:
            return
        self.t.append(float(rec.t))
        self.b.append(np.array(rec.x[10:13], float))
        self.sd.append(np.sqrt(np.abs(np.diag(rec.P)[9:12])))

    def trend_of(self, rows: dict[str, dict]) -> dict | None:
        """The trend over the airborne span of the filter's result row in ``rows`` (the
        replay's ``filters``, a live run's ``attitude``), or over the run after its first
        fifth without one (the alignment's transient); None before any step."""
        if self.label is None:
            return None
        return self.trend(((rows.get(self.label) or {}).get("airborne") or {}).get("t"))

    def trend(self, window: list | None) -> dict | None:
        """The trend over ``window`` ([t0, t1] s, the airborne span) or, without one,
        over the run after its first fifth (the alignment's transient)."""
        if not self.t:
            return None
        t = np.array(self.t)
        m = ((t >= window[0]) & (t <= window[1]) if window
             else t >= t[0] + 0.2 * (t[-1] - t[0]))
        got = gyro_bias_trend(t[m], np.array(self.b)[m], np.array(self.sd)[m])
        return None if got is None else {"filter": self.label,
                                         "window": "airborne" if window else "run", **got}


class _Refs(Sink):
    """Keeps the reference series (smoothing scores the whole smoothed run at the end)."""

    def __init__(self) -> None:
        self.t: dict[str, list] = {}
        self.q: dict[str, list] = {}

    def sample(self, s) -> None:
        if isinstance(s, AttitudeRef):
            ts = self.t.setdefault(s.source, [])
            if not ts or s.t > ts[-1]:
                ts.append(s.t)
                self.q.setdefault(s.source, []).append(s.q)


class _ImuGaps(Sink):
    """Time lost in IMU gaps per source (intervals > 3x the median of the first 200), for
    the reliability flags: corruption a format cannot detect (ULog resync) shows as gaps."""

    def __init__(self) -> None:
        self.last: dict[str, float] = {}
        self.first: dict[str, float] = {}
        self.dts: dict[str, list] = {}
        self.med: dict[str, float] = {}
        self.gap: dict[str, float] = {}

    def sample(self, s) -> None:
        if not isinstance(s, ImuSample):
            return
        src, t = s.source, s.t
        prev = self.last.get(src)
        self.last[src] = t
        if prev is None:
            self.first[src] = t
            return
        dt = t - prev
        med = self.med.get(src)
        if med is None:
            d = self.dts.setdefault(src, [])
            d.append(dt)
            if len(d) == 200:  # the median of the first 200 intervals, once
                self.med[src] = float(np.median(d[:200]))
            return
        if dt > 3.0 * med:
            self.gap[src] = self.gap.get(src, 0.0) + dt - med

    def fraction(self, src: str | None) -> float:
        if src is None or src not in self.last:
            return 0.0
        span = self.last[src] - self.first[src]
        return self.gap.get(src, 0.0) / span if span > 0 else 0.0


#: s: a replay stops reading its log at the first sample this far past ``--end`` (the
#: sources deliver their samples in time order within their reorder windows, 1 s at
#: most, and the vehicle clock runs on across reboots); until then the window filters
WINDOW_STOP_S = 10.0


def _windowed(samples: Iterable, window: Callable[[float], bool], end: float | None
              ) -> Iterator:
    """The samples inside the replay's time window, read up to :data:`WINDOW_STOP_S`
    past its ``end`` (s; None: to the log's end). Reading on to the log's end decoded
    what the window drops: ``--end 3`` on logs/sim_200hz.tlog (60 s) took 7.8 s."""
    stop = math.inf if end is None else end + WINDOW_STOP_S
    for s in samples:
        if window(s.t):
            yield s
        elif s.t > stop:
            return


def samples_from_arrays(
    t: Array, gyro: Array, accel: Array, mag_t: Array | None = None,
    mag_field: Array | None = None, source: str = "IMU[0]",
) -> Iterator:
    """A time-ordered sample stream from IMU arrays (t s, gyro rad/s, accel m/s^2, body
    FRD) and optional magnetometer arrays (t s, field gauss, body FRD): the batch form of
    a source, run through the same streaming code."""
    imu = (ImuSample(float(a), g, c, source) for a, g, c in zip(t, gyro, accel, strict=True))
    if mag_t is None or mag_field is None:
        yield from imu
        return
    import heapq

    mag = (MagSample(float(a), f, source) for a, f in zip(mag_t, mag_field, strict=True))
    yield from heapq.merge(mag, imu, key=lambda s: s.t)


def replay_samples(
    samples: Iterable,
    cfg: ReplayConfig,
    *,
    params: dict | None = None,
    sinks: tuple | list = (),
    info: RunInfo | None = None,
    rng_for: Callable[[str], np.random.Generator] | None = None,
) -> tuple[dict, AttitudeStream, list[FilterRunner], AttitudeScorer, Collector | None]:
    """Run ``cfg.filters`` over a sample stream with the model :func:`choose_model`
    picks (``cfg.model``). Returns the per-filter result rows (with ``model``, the
    decision, and ``nav``, the :class:`NavScorer`), and the stream, runners, scorer and
    collector for callers that report more."""
    opts = cfg.attitude_options()
    windowed = (samples if opts.start is None and opts.end is None
                else _windowed(samples, opts.in_window, opts.end))
    windowed, decision = choose_model(windowed, cfg.model, cfg.model_why)
    nav = decision["value"] == "nav"
    if not nav:
        check_attitude_noise(cfg.noise, "that runs here")
    wall0, load0 = time.perf_counter(), load_seconds()
    delay_doc = None
    window_set = "gnss_vel_window" in cfg.noise  # by the option
    spec = with_sensor_spec((params or {}) if nav else {}, cfg.noise, cfg.gnss_delay)
    noise, delay = spec.merged(cfg.noise, cfg.gnss_delay)
    cfg = replace(cfg, noise=noise, gnss_delay=delay)
    if nav and cfg.estimate_delay and (cfg.gnss_delay is None or cfg.mag_delay is None
                                       or cfg.baro_delay is None
                                       or "mag_noise" not in cfg.noise):
        delay_doc, windowed = probe_gnss_delay(windowed, cfg, params)
        md, bd = delay_doc["mag"], delay_doc["baro"]
        bias = (delay_doc.get("gnss_drift") or {}).get("bias_used") or {}
        cfg = replace(cfg, gnss_delay=delay_doc.get("delay_used", cfg.gnss_delay),
                      mag_delay=md.get("delay_used", cfg.mag_delay),
                      baro_delay=bd.get("delay_used", cfg.baro_delay),
                      noise={**cfg.noise, **({"mag_noise": md["noise_used"]}
                                             if "noise_used" in md else {}),
                             **({"baro_noise": bd["noise_used"]}
                                if "noise_used" in bd else {}),
                             **({"gnss_vel_window": delay_doc["window_used"]}
                                if "window_used" in delay_doc
                                and "gnss_vel_window" not in cfg.noise else {}),
                             **bias})
    specs = model_filters(cfg.filters, nav, cfg.noise)
    rng_for = rng_for or (lambda label: rng(cfg.seed, 0, filter_stream(label)))
    runner_cls = NavRunner if nav else FilterRunner
    runners = [
        runner_cls(sp.label, flt, rng_for(sp.label), smooth=cfg.smooth) for sp, flt in specs
    ]
    scorer = AttitudeScorer()
    score = _Score(scorer)
    nav_scorer = NavScorer()
    gaps = _ImuGaps()
    coll = Collector() if cfg.smooth else None
    refs = _Refs() if cfg.smooth else None
    bias = _GyroBias() if nav else None
    probe, probe_mag = delay_doc or {}, (delay_doc or {}).get("mag", {})
    probe_baro = (delay_doc or {}).get("baro", {})
    stream: AttitudeStream | NavStream = (
        NavStream(opts=replace(cfg.nav_options(), before_fix=decision["fix_stream"],
                               gnss_delay_why=spec.why_of("gnss_delay")
                               or probe.get("why_used"),
                               mag_delay_why=probe_mag.get("why_used"),
                               mag_noise_why=spec.why_of("mag_noise")
                               or probe_mag.get("noise_why"),
                               gnss_vel_window_why=None if window_set
                               else probe.get("window_why_used"),
                               baro_delay_why=probe_baro.get("why_used"),
                               baro_noise_why=probe_baro.get("noise_why"),
                               gnss_bias_why=spec.why_of(*GNSS_BIAS_KEYS) or (
                                   probe.get("gnss_drift") or {}).get("bias_why"),
                               mag_inclination=probe_mag.get("inclination"),
                               mag_inclination_why=probe_mag.get("inclination_why")),
                  params=params) if nav
        else AttitudeStream(opts=opts, params=params))
    if delay_doc is not None:
        stream.summary["gnss_delay_estimate"] = delay_doc
    info = info or RunInfo("", "", cfg.seed)
    info.filters = {sp.label: sp.as_dict() for sp, _ in specs}
    all_sinks = ([score, _NavScore(nav_scorer), gaps] + ([refs] if refs else [])
                 + ([coll] if coll else []) + ([bias] if bias else []) + list(sinks))
    run_lanes(windowed, [Lane(stream, runners)], all_sinks, info)
    # (the compiled kernels' first load in this process is not the replay's speed)
    loads = load_seconds() - load0
    wall = time.perf_counter() - wall0 - sum(r.smooth_seconds for r in runners) - loads
    scorer.finish()
    stream.summary["imu_gap_fraction"] = gaps.fraction(stream.summary.get("imu_source"))
    return ({"wall_s": wall, "kernel_load_s": loads, "refs": refs, "model": decision,
             "nav": nav_scorer, "gyro_bias": bias,
             **({"sensor_spec": d} if (d := spec.as_dict()) else {})},
            stream, runners, scorer, coll)


def _score_smoothed(smoothed: tuple[Array, Array, Array], refs: _Refs, ref: str,
                    truth: bool) -> dict:
    """Attitude RMSE (and NEES against truth) of the ``smoothed`` run (step times, means,
    covariances: :func:`smooth_records`) against the reference ``ref``."""
    t, xs, Ps = smoothed
    q_ref, mask = quat_slerp_interp(np.array(refs.t[ref]), np.array(refs.q[ref]), t)
    row = rmse_deg(xs[:, :4], q_ref, mask)
    if truth and mask.any():
        row["nees_mean"] = float(np.mean(nees_attitude(xs[:, :4][mask], Ps[mask], q_ref[mask])))
    return row


def _score_smoothed_nav(smoothed: tuple[Array, Array, Array], nsc: NavScorer, label: str,
                        att_ref: str | None, frame) -> dict:
    """Velocity/position RMSE, the NEES blocks (as the filtered row's ``nees``) and the
    airborne scores (as the filtered row's ``airborne``) of the smoothed navigation run
    of ``label``, scored by the run's own :class:`NavScorer` (its references) under the
    label ``"<label> smoothed"``; ``smoothed`` as for :func:`_score_smoothed`."""
    t, xs, Ps = smoothed
    lab = f"{label} smoothed"
    for k in range(len(t)):
        nsc.add_estimate(lab, float(t[k]), xs[k], Ps[k])
    got = nsc.scores(lab, att_ref, frame)
    return {k: got[k] for k in ("vel_rmse_ms", "hpos_rmse_m", "vpos_rmse_m", "nees",
                                "airborne") if got.get(k)}


@dataclass
class ArrayRun:
    """Filters run over IMU arrays: step end times ``t`` (K,), and per label the
    estimates ``x`` (K, 7), covariances ``P`` (K, 6, 6), ``resets``, the stream's
    ``summary``, and with smoothing the smoothed ``xs``/``Ps``."""

    t: Array
    x: dict
    P: dict
    resets: dict
    summary: dict
    xs: dict = field(default_factory=dict)
    Ps: dict = field(default_factory=dict)


def replay_arrays(
    t: Array, gyro: Array, accel: Array, mag_t: Array | None = None,
    mag_field: Array | None = None, *, filters: tuple | list = DEFAULT_FILTERS,
    noise=None, declination: float = 0.0, seed: int = 0, smooth: bool = False,
    use_mag: bool = True, rate_hz: float | None = None,
) -> ArrayRun:
    """:func:`replay_samples` over arrays (:func:`samples_from_arrays`): the batch form,
    the same streaming code. ``noise`` an :class:`~uavest.models.attitude.AttitudeNoise`
    (all of its values used) or None (the source's defaults)."""
    from dataclasses import asdict

    cfg = ReplayConfig(filters=tuple(filters), seed=seed, smooth=smooth, rate_hz=rate_hz,
                       declination=declination, use_mag=use_mag,
                       noise={} if noise is None else asdict(noise))
    coll = Collector()
    _, stream, runners, _, _ = replay_samples(
        samples_from_arrays(t, gyro, accel, mag_t, mag_field), cfg, sinks=[coll])
    out = ArrayRun(coll.arrays(runners[0].label)["t"], {}, {}, {}, stream.summary)
    for r in runners:
        a = coll.arrays(r.label)
        out.x[r.label], out.P[r.label], out.resets[r.label] = a["x"], a["P"], r.resets
        if smooth:
            _, out.xs[r.label], out.Ps[r.label] = smooth_records(coll, r.label, stream.space)
    return out


def replay(
    path: str | Path,
    cfg: ReplayConfig | None = None,
    *,
    sinks: tuple | list = (),
    command: str = "",
    rng_for: Callable[[str], np.random.Generator] | None = None,
    on_source: Callable | None = None,
) -> dict:
    """Replay the log at ``path`` with ``cfg``; returns the JSON-ready result document
    (strict JSON through :func:`uavest.sinks.jsonout.dumps`). ``on_source(src)`` is
    called with the opened source (progress bars read ``src.bytes_read``)."""
    cfg = cfg or ReplayConfig()
    src = _open_log(path, cfg, on_source)
    info = RunInfo(command, str(path), cfg.seed, config=_config_dict(cfg),
                   versions=package_versions())
    try:
        out, stream, runners, scorer, coll = replay_samples(
            src, cfg, params=src.params, sinks=sinks, info=info, rng_for=rng_for)
    except NavNotStarted as e:
        raise IngestError(f"{path}: {e}") from None
    except NoSamplesError:
        raise _no_samples_error(path, src, cfg) from None
    sm = stream.summary
    refs = scorer.refs
    ref_name, ap_name, rejected = choose_reference(refs, scorer.window)
    truth = ref_name is not None and refs[ref_name].kind == "truth"
    doc = _doc_header(path, cfg, src, stream, info, ref_name, refs, rejected)
    nav = out["model"]["value"] == "nav"
    doc["model"] = out["model"]
    if "sensor_spec" in out:
        doc["sensor_spec"] = out["sensor_spec"]
    nsc: NavScorer = out["nav"]
    doc.update(_position_fields(nsc, src.params, sm, nav))
    frame = getattr(stream, "frame", None)
    for r in runners:
        doc["filters"][r.label] = _filter_row(r, cfg, out, stream, scorer, coll, ref_name,
                                              truth, nav, frame)
    if ref_name is not None:
        _add_autopilot_rows(doc["filters"], scorer, ref_name, ap_name)
        _airborne_autopilot(doc["filters"], nsc, ref_name)
    gb: _GyroBias | None = out["gyro_bias"]
    trend = None if gb is None else gb.trend_of(doc["filters"])
    if trend is not None:
        doc["gyro_bias_trend"] = trend
    _add_run_health(doc, src, runners, sm, out["wall_s"])
    doc["kernel_load_s"] = out["kernel_load_s"]
    return doc


def _open_log(path: str | Path, cfg: ReplayConfig, on_source: Callable | None):
    """The opened source of ``path``; a MAVLink log prescanned for its GPS fix and date
    when the declination must come from the magnetic model."""
    from ..ingest import open_source

    src = open_source(path)
    if on_source is not None:
        on_source(src)
    if cfg.declination is None and src.format in ("tlog", "dataflash", "dataflash-text"):
        src.prescan_geo()  # the GPS fix and date, for the magnetic model if needed
    if cfg.model != "attitude":
        read_log_spec(src)
    return src


def _no_samples_error(path: str | Path, src, cfg: ReplayConfig) -> IngestError:
    """The one-line error for a log (or window) without a usable IMU sample, naming the
    bad data the reader counted and how many records it decoded."""
    st = src.stats.as_dict()
    dmg = ", ".join(f"{k} {st[k]}" for k in st
                    if isinstance(st[k], int) and st[k] and k != "bad_total")
    window = (f" in the window {cfg.start}..{cfg.end} s"
              if cfg.start is not None or cfg.end is not None else "")
    return IngestError(f"{path}: no IMU samples could be read{window} "
                       f"({dmg or 'no bad data counted'}; "
                       f"{sum(st['messages'].values())} records decoded)")


def _doc_header(path: str | Path, cfg: ReplayConfig, src, stream, info: RunInfo,
                ref_name: str | None, refs: dict, rejected: dict) -> dict:
    """The result document up to its (empty) ``filters``: the run, the log, the
    reference chosen, and what the stream decided (rates in Hz, times in s, declination
    in rad, the noise values used)."""
    sm = stream.summary
    return {
        "run": info.as_dict(),
        "log": str(path),
        "format": "dataflash" if src.format == "dataflash-text" else src.format,
        "imu_source": sm.get("imu_source"),
        "imu_switches": list(sm.get("imu_switches") or []),
        "mag_source": sm.get("mag_source"),
        "reference": ref_name,
        "reference_kind": None if ref_name is None else refs[ref_name].kind,
        "references_rejected": rejected,
        "imu_rate_hz": sm.get("imu_rate_hz"),
        "filter_rate_hz": sm.get("filter_rate_hz"),
        "integration": sm.get("integration"),
        "integration_why": sm.get("integration_why"),
        "preintegrated_samples_per_step": sm.get("preintegrated_samples_per_step"),
        "duration_s": sm.get("duration_s"),
        "steps": sm.get("steps"),
        "t_first": sm.get("t_first"),
        "imu_gaps": sm.get("imu_gaps", 0),
        "imu_gap_longest_s": sm.get("imu_gap_longest_s", 0.0),
        "imu_gap_threshold_s": sm.get("imu_gap_threshold_s"),
        "imu_gap_list": sm.get("imu_gap_list", []),
        "imu_split_intervals": sm.get("imu_split_intervals", 0),
        "imu_split_longest_s": sm.get("imu_split_longest_s", 0.0),
        "max_step_s": sm.get("max_step_s"),
        "declination_rad": sm.get("declination_rad"),
        "declination_source": sm.get("declination_source"),
        "accel_compensation": sm.get("accel_compensation"),
        "accel_compensation_from_t": sm.get("accel_compensation_from_t"),
        "decisions": list(sm.get("decisions") or []),
        "mag_mode": cfg.mag_mode if sm.get("mag_source") else None,
        "mag_delay_s": sm.get("mag_delay_s", cfg.mag_delay or 0.0),
        "seed": cfg.seed,
        "noise": {k: float(getattr(stream.noise, k)) for k in stream.noise.__dataclass_fields__},
        "filters": {},
    }


def _position_fields(nsc: NavScorer, params: dict, summary: dict, nav: bool) -> dict:
    """The position reference (name and kind) if the log has one, and for a navigation
    run the stream's GNSS/baro choices, its origin and its aiding, and the accelerometer
    densities its steps took when they followed the flight (``accel_density``)."""
    got: dict = {}
    pref = nsc.position_ref()
    if pref is not None:
        got["position_reference"] = pref
        got["position_reference_kind"] = position_ref_kind(pref, params)
    if nav:
        got.update({k: summary.get(k) for k in ("gnss_source", "gnss_sources", "baro_source",
                                                "gnss_delay_s", "gnss_delay_estimate",
                                                "baro_delay_s", "baro_offset_m", "origin",
                                                "geodesy", "aiding", "fix_from_t")})
        if summary.get("accel_density"):
            got["accel_density"] = summary["accel_density"]
    return got


def _filter_row(r: FilterRunner, cfg: ReplayConfig, out: dict, stream, scorer: AttitudeScorer,
                coll: Collector | None, ref_name: str | None, truth: bool, nav: bool,
                frame) -> dict:
    """One filter's result row: the attitude scores against ``ref_name``, the navigation
    scores, the gates (nav), the cost per step (us, without the warm-up), its guard
    resets, and with smoothing the smoothed run's ``smoothed`` row."""
    nsc: NavScorer = out["nav"]
    nsc.pos_from = getattr(stream, "fix_from", None)  # positions before it: in no frame
    row: dict = scorer.scores(r.label, ref_name, truth) if ref_name else {}
    extra = nsc.scores(r.label, ref_name if truth else None, frame)
    extra.pop("position_reference", None)
    row.update({k: v for k, v in extra.items() if v or k == "airborne"})
    if nav:
        row["gates"] = dict(getattr(r, "gates", {}))
        row.update(stream.learnt(r))
    row["us_per_step"] = r.us_per_step  # without the one-time warm-up
    row["resets"] = r.resets
    if cfg.smooth and coll is not None:
        smoothed = smooth_records(coll, r.label, stream.space)  # (one backward pass)
        srow = _score_smoothed(smoothed, out["refs"], ref_name, truth) if ref_name else {}
        got = _score_smoothed_nav(smoothed, nsc, r.label, ref_name if truth else None, frame)
        if nav:
            srow.update(got)
        elif got.get("airborne"):  # an attitude run: the airborne window's scores only
            srow["airborne"] = got["airborne"]
        steps = max(int(stream.summary.get("steps") or 0), 1)
        srow["us_per_step"] = 1e6 * r.smooth_seconds / steps
        row["smoothed"] = srow
    return row


def _add_autopilot_rows(rows: dict, scorer: AttitudeScorer, ref_name: str,
                        ap_name: str | None) -> None:
    """The autopilot's own estimate and its second AHRS scored against ``ref_name`` as
    rows ``autopilot`` / ``ahrs2`` beside the filters (a filter's row wins a clash)."""
    refs = scorer.refs
    for name, label in ((ap_name, "autopilot"), ("AHRS2", "ahrs2"), ("AHR2", "ahrs2")):
        if name is None or name == ref_name or name not in refs:
            continue
        row = scorer.scores(name, ref_name, False)
        row["source"] = name
        rows.setdefault(label, row)


def _airborne_autopilot(rows: dict, nsc: NavScorer, ref_name: str) -> None:
    """The ``airborne`` attitude RMSE (deg) of the autopilot's rows over the filters'
    airborne span (the first filter's), against the same reference as the filters."""
    from ..eval.attitude import rmse_deg

    span = next((r["airborne"]["t"] for r in rows.values()
                 if isinstance(r.get("airborne"), dict) and "t" in r["airborne"]), None)
    if span is None or ref_name not in nsc.att:
        return
    tr, qr = (np.array(v) for v in nsc.att[ref_name])
    for row in rows.values():
        src = row.get("source")
        if src is None or src not in nsc.att:
            continue
        t, q = (np.array(v) for v in nsc.att[src])
        keep = (t >= span[0]) & (t <= span[1])
        if keep.sum() < 2:
            continue
        qi, ok = quat_slerp_interp(tr, qr, t[keep])
        if ok.any():
            row["airborne"] = {"t": [float(span[0]), float(span[1])],
                               **rmse_deg(q[keep][ok], qi[ok])}


def _add_run_health(doc: dict, src, runners: list[FilterRunner], summary: dict,
                    wall: float) -> None:
    """The bad data the reader counted and repaired, the guard resets, the reliability
    flags, the wall time (s) and the realtime factor (log duration / wall)."""
    bad = src.stats.as_dict()
    doc["bad_data"] = bad
    doc["repaired"] = {k: bad[k] for k in ("time_outlier",) if bad.get(k)}
    doc["guard_resets"] = {r.label: r.resets for r in runners}
    # when and why each filter reset (its guard, or a GNSS lock-out: docs/navigation.md)
    why = {r.label: [[t, w] for t, w in r.reset_log] for r in runners
           if getattr(r, "reset_log", None)}
    if why:
        doc["resets_why"] = why
    doc["unreliable"] = reliability(doc, summary)
    doc["wall_s"] = wall
    dur = float(summary.get("duration_s") or 0.0)
    doc["realtime_factor"] = dur / wall if wall > 0 else None


def position_ref_kind(name: str, params: dict) -> str:
    """"truth" for a simulator's position, else "autopilot" (its fused estimate), with
    the note that an ArduPilot SITL run with ``AHRS_EKF_TYPE=10`` reports the
    simulator's own state as its estimate."""
    from ..eval.attitude import TRUTH_SOURCES

    if name in TRUTH_SOURCES:
        return "truth"
    if params.get("AHRS_EKF_TYPE") == 10:
        return "autopilot (AHRS_EKF_TYPE=10: the simulator's state)"
    return "autopilot"


#: Fraction of the log's records that may be bad before a result is flagged unreliable
#: (0.1 %: at the 4 Hz of a telemetry IMU one lost record is a 0.5 s gap in the gyro; a
#: 1e-4 byte-flip rate loses ~0.3 % of tlog frames and moved an RMSE by 17 %).
MAX_BAD_FRACTION = 0.001
#: Share of the IMU time in gaps (high-rate IMUs) beyond which a result is flagged.
MAX_IMU_GAP = 0.02
#: Mean NEES against truth beyond which the filter is flagged inconsistent (3 is ideal).
MAX_NEES = 30.0


def resets_line(counts: dict[str, int], why: dict[str, list]) -> str | None:
    """"filter resets: ekf 1 (first at t=29.4 s: why), ..." from each filter's reset
    count and its ``[[t, why], ...]`` (a runner's ``reset_log``); None without a reset."""
    resets = {k: v for k, v in counts.items() if v}
    if not resets:
        return None
    return "filter resets: " + ", ".join(
        f"{k} {v}" + (f" (first at t={why[k][0][0]:.1f} s: {why[k][0][1]})"
                      if why.get(k) else "") for k, v in resets.items())


def mag_ref_line(rows: dict[str, dict]) -> str | None:
    """"magnetic field learnt (the reference: inclination 63.52 deg, declination 3.00
    deg): ekf inclination 64.51 +- 0.01 deg, declination 3.10 +- 0.17 deg; ..." from the
    filters' result ``rows`` with a ``mag_ref`` (the magnetic reference states); None
    without one."""
    got = [(k, r["mag_ref"]) for k, r in rows.items() if r.get("mag_ref")]
    if not got:
        return None
    m0 = got[0][1]
    return ("magnetic field learnt (the reference: inclination "
            f"{m0['reference_inclination_deg']:.2f} deg, declination "
            f"{m0['reference_declination_deg']:.2f} deg): " + "; ".join(
                f"{k} inclination {m['inclination_deg']:.2f} +- "
                f"{m['inclination_sd_deg']:.2f} deg, declination {m['declination_deg']:.2f}"
                f" +- {m['declination_sd_deg']:.2f} deg" for k, m in got))


def gyro_ramp_line(trend: dict | None, rows: dict[str, dict]) -> str | None:
    """A hint when the first navigation filter's gyro bias ramped (``trend``, a result's
    ``gyro_bias_trend``: :func:`~uavest.eval.navigation.gyro_bias_trend`) and none of the
    filters' result ``rows`` had the gyro drift states; None otherwise (a replay's and a
    live run's alike)."""
    tr = trend or {}
    if not tr.get("ramps") or any(r.get("gyro_drift") for r in rows.values()):
        return None
    rate = " / ".join(f"{v:.3f}" for v in tr["deg_s_per_min"])
    return (f"gyro bias: ramps at {rate} deg/s per minute (body x / y / z; {tr['filter']}'s "
            f"estimate, {tr['window']}: a line explains {min(tr['r2']):.2f} or more of it, "
            f"{min(tr['sigmas']):.0f} std or more): a random-walk bias follows it with a lag; "
            "--noise gyro_drift_walk=1e-6 models it: compare the two runs, a slow ramp the "
            "random walk keeps up with does not pay for the states (docs/navigation.md, "
            "\"The gyro drift states\")")


def learnt_lines(rows: dict[str, dict], doc: dict) -> list[str]:
    """What the filters' extra states learnt and what their biases did, from the filters'
    result ``rows`` (a replay's ``filters``, a live run's ``attitude``) and the result
    document ``doc`` (its ``gyro_bias_trend`` and ``accel_density``): :func:`mag_ref_line`,
    :func:`gyro_drift_line`, :func:`gyro_ramp_line` and :func:`accel_density_line`, those
    that have something to say, in that order."""
    got = (mag_ref_line(rows), gyro_drift_line(rows),
           gyro_ramp_line(doc.get("gyro_bias_trend"), rows),
           accel_density_line(doc.get("accel_density")))
    return [ln for ln in got if ln]


def accel_density_line(d: dict | None) -> str | None:
    """"accelerometer density: followed the flight, 0.0021-0.0062 m/s^2/sqrt(Hz) ..." from
    a result's ``accel_density`` (:meth:`~uavest.engine.navigation.NavStream.accel_density`);
    None without one."""
    if not d:
        return None
    return (f"accelerometer density: followed the flight's roughness, {d['min']:.4f}-"
            f"{d['max']:.4f} m/s^2/sqrt(Hz), mean {d['mean']:.4f} (the specific force's "
            f"change between 40-ms means {d['roughness_ms2']:.3f} m/s^2 RMS on average; "
            "--noise accel_noise=Q fixes it)")


def gyro_drift_line(rows: dict[str, dict]) -> str | None:
    """"gyro drift learnt (deg/s per minute, body x / y / z): ekf 0.047 / 0.046 / 0.041
    +- 0.004; ..." from the filters' result ``rows`` with a ``gyro_drift`` (the gyro drift
    states); None without one."""
    got = [(k, r["gyro_drift"]) for k, r in rows.items() if r.get("gyro_drift")]
    if not got:
        return None
    return "gyro drift learnt (deg/s per minute, body x / y / z): " + "; ".join(
        f"{k} " + " / ".join(f"{v:.3f}" for v in d["deg_s_per_min"])
        + f" +- {max(d['sd_deg_s_per_min']):.3f}" for k, d in got)


def reliability(doc: dict, summary: dict) -> list[str]:
    """Reasons the result ``doc`` should not be trusted as it stands (empty: none):
    nothing to score against, a large share of bad data, filters reset by their guard,
    dropped IMU samples, steps left unscored, inconsistent NEES against truth."""
    out: list[str] = []
    if doc["reference"] is None:
        why = "; ".join(f"{k}: {v}" for k, v in doc["references_rejected"].items())
        out.append("no usable reference: nothing scored" + (f" ({why})" if why else ""))
    bad = doc["bad_data"]
    total = sum(bad["messages"].values()) + bad["corrupt"] + bad["unknown_message"]
    # bad items other than the re-sent/duplicate messages every log has and the cut end
    damage = bad["bad_total"] - bad["duplicate"] - bad["time_backwards"] - bad["truncated"]
    if total and damage / total > MAX_BAD_FRACTION:
        out.append(f"{100 * damage / total:.2g} % of the log's records were bad "
                   f"(> {100 * MAX_BAD_FRACTION:g} %): the numbers may be off")
    line = resets_line(doc["guard_resets"], doc.get("resets_why") or {})
    if line:
        out.append(line)
    gapf = float(summary.get("imu_gap_fraction") or 0.0)
    if gapf > MAX_IMU_GAP and float(summary.get("imu_rate_hz") or 0.0) >= 20.0:
        out.append(f"{100 * gapf:.1f} % of the IMU time is in gaps (> {100 * MAX_IMU_GAP:g} %): "
                   "records were lost")
    dropped = int(summary.get("imu_dropped") or 0)
    if dropped:
        out.append(f"{dropped} IMU samples dropped by the step builder")
    steps = int(summary.get("steps") or 0)
    if doc["reference"] is not None and steps:
        for label, row in doc["filters"].items():
            if label in doc["guard_resets"] and row.get("n", 0) < 0.5 * steps:
                out.append(f"{label}: only {row.get('n', 0)} of {steps} steps scored")
            nees = row.get("nees_mean")
            if nees is not None and label in doc["guard_resets"] and nees > MAX_NEES:
                out.append(f"{label}: NEES {nees:.3g} against truth (consistent: 3)")
    return out


def _config_dict(cfg: ReplayConfig) -> dict:
    d = {k: v for k, v in vars(cfg).items() if k != "filters"}
    d["filters"] = spec_labels(cfg.filters)
    return d
