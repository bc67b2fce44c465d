"""The live estimator (``uavest run``): a MAVLink vehicle in, estimates out, in real time.

live link (:class:`uavest.ingest.live.LiveLink`: heartbeat, stream requests, signing,
declination, tlog of what it accepted) -> the streaming engine with two lanes:

* **attitude**: :class:`~uavest.engine.attitude.AttitudeStream` -> one
  :class:`~uavest.engine.runner.FilterRunner` per filter (``attitude`` preset);
* **tracking**: :class:`TrackLane`, scans of radar-like detections -> one
  :class:`~uavest.engine.runner.TrackerRunner` per filter (``radar`` preset). The scans
  come from the **virtual radar** over the vehicle's ADS-B traffic
  (:class:`uavest.ingest.adsb_radar.AdsbRadar`, seeded from ``rng(seed, 0, "radar")``) or
  from the vehicle's own ``OBSTACLE_DISTANCE_3D`` detections (``radar_source``).

-> sinks: the streaming attitude scorer (against SIMSTATE truth when the vehicle sends
it, else its own estimate), the track scorer (against the ADS-B positions, per ICAO
address), the one-line status, the MAVLink publisher on a ground-station-side link, and
the caller's (MCAP, JSON...).

Link gaps: a gap up to ``bridge_s`` is bridged (the next step predicts over it); a
longer one restarts the attitude alignment (a new :class:`~uavest.engine.records.Start`)
and is reported. Every estimate is made from samples that are also in the tlog
(``tlog``), so ``uavest replay`` of that tlog gives the same attitude estimates.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from ..core.spec import FilterSpec
from ..engine.attitude import AttitudeOptions, AttitudeStream
from ..engine.build import build_filters
from ..engine.gnss_delay import LiveDelayLearner
from ..engine.history import restore_vars, snapshot_vars
from ..engine.loop import Lane, run_lanes
from ..engine.navigation import NavOptions, NavRunner, NavStream
from ..engine.records import (
    RadarScanSample,
    RunInfo,
    ScanRecord,
    Start,
    Step,
    StepRecord,
    package_versions,
)
from ..engine.runner import FilterRunner, TrackerRunner
from ..errors import InputError
from ..eval.attitude import AttitudeScorer, select_reference
from ..eval.metrics import nees
from ..eval.navigation import NavScorer
from ..eval.tracking import track_quality
from ..ingest.adsb_radar import AdsbRadar, RadarConfig, geodetic_to_ned
from ..ingest.mavlink import sample_key
from ..ingest.types import (
    AdsbSample,
    AttitudeRef,
    BaroSample,
    DetectionSample,
    GnssSample,
    ImuSample,
    LinkEvent,
    MagSample,
    NoSamplesError,
    PositionSample,
)
from ..link.spec import SPEC_PARAMS
from ..models.motion import NearlyConstantVelocity
from ..models.navigation import names_gnss_bias
from ..models.radar import RadarMeasurement, SensorPose
from ..presets import resolve_list, spec_labels
from ..seeding import filter_stream, rng
from ..sinks.base import Sink
from ..tracking.tracker import Tracker, TrackerConfig
from .replay import _GyroBias, _NavScore, _Score, check_attitude_noise, model_filters
from .sensor_spec import GNSS_BIAS_KEYS, SpecStart, read_log_spec, with_sensor_spec

Array = np.ndarray

__all__ = ["LIVE_STREAMS", "LiveConfig", "PublishSink", "TrackLane", "run_live", "run_samples"]

log = logging.getLogger("uavest.live")

_T = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # NED <-> ENU (own inverse)

#: What the live estimator asks the vehicle for (name -> Hz): the IMU, the autopilot's
#: attitude (the radar's pose and the fallback reference), position (ownship of the
#: virtual radar), SIMSTATE and SIM_STATE (an ArduPilot SITL's truth: SIMSTATE the attitude,
#: SIM_STATE also the position and velocity the navigation model is scored against, and
#: the evidence that puts its frame on ArduPilot's sphere; a real vehicle ignores both),
#: HIL_STATE_QUATERNION (the true state PX4 SITL and uavest's simulator send: attitude,
#: position and velocity), time, and the
#: radar lanes' inputs: ADSB_VEHICLE (ArduPilot sends traffic only when asked on that link,
#: about 1 Hz per aircraft at most) and OBSTACLE_DISTANCE_3D, and barometric pressure.
#: The achieved rate of each is said on one line ``rate_window_s`` after the start, a
#: stream the vehicle does not serve as ``missing: X`` (:mod:`uavest.apps.streams`).
LIVE_STREAMS = {
    "HIGHRES_IMU": 100.0, "RAW_IMU": 50.0, "ATTITUDE": 10.0, "GLOBAL_POSITION_INT": 10.0,
    "GPS_RAW_INT": 5.0, "SIMSTATE": 10.0, "SIM_STATE": 10.0,
    "HIL_STATE_QUATERNION": 10.0, "SYSTEM_TIME": 1.0,
    "ADSB_VEHICLE": 10.0, "OBSTACLE_DISTANCE_3D": 10.0, "SCALED_PRESSURE": 10.0,
}

#: The tangent dimension of the live tracks' state (:class:`NearlyConstantVelocity` in
#: 3-D: position and velocity, m and m/s), which the tracker specs are resolved for.
TRACKER_DIM = 6

#: The prior std (rad) of the inclination state a live navigation run gives its filters
#: when ``--noise`` names neither ``mag_ref_inc`` nor ``mag_ref_dec`` (the magnetic
#: reference states, docs/navigation.md): 0.25 deg, about the magnetic model's own
#: accuracy. A replay's probe estimates the field's inclination from the whole log before
#: the run; a live run has only its start's angle, and a site's field is often a degree or
#: more off the model. With the state every filter learns the field after the first turn
#: (on a field 1 deg off the model: 0.05 deg of pitch after it, 0.55 without), and the
#: attitude NEES comes into its band (docs/live.md, "The inclination state, on by default
#: live"). ``--noise mag_ref_inc=0`` runs without it.
LIVE_MAG_REF_INC = float(np.radians(0.25))
LIVE_MAG_REF_WHY = ("default for a live run (no probe estimates the field before it; "
                    "--noise mag_ref_inc=0 for none)")


@dataclass
class LiveConfig:
    """Options of :func:`run_live` (see ``uavest run --help``)."""

    connect: str = "udpin:127.0.0.1:14550"
    # spec text, or specs the CLI resolved (attitude / radar preset)
    filters: tuple[str | FilterSpec, ...] = ("ekf", "ukf", "hybrid")
    trackers: tuple[str | FilterSpec, ...] = ("ekf", "ukf", "hybrid")
    seed: int = 0
    sysid: int | None = None
    signing_key: str | None = None
    tlog: str | None = None
    heartbeat_timeout: float = 30.0
    #: s of vehicle time the link holds samples to order them; 0 (default): on arrival,
    #: each lane taking its samples as they come and applying a late one at its time
    #: within ``history_s`` (:mod:`uavest.engine.history`)
    reorder_window: float = 0.0
    #: s of vehicle time a lane keeps to apply late samples (on arrival): the ArduCopter
    #: SITL's GPS_RAW_INT arrives 0.21 s after its time, the built-in simulator's
    #: GLOBAL_POSITION_INT up to 0.04 s after newer IMU samples (docs/live.md, "Latency")
    history_s: float = 0.3
    duration: float | None = None  # wall seconds; None: until stopped
    rate_hz: float | None = None
    update_hz: float | None = None  # above 25 Hz: update rate cap (AttitudeOptions)
    radar_source: str = "adsb"  # adsb (virtual radar) | obstacle (OBSTACLE_DISTANCE_3D)
    radar: RadarConfig = field(default_factory=RadarConfig)
    motion_q: float = 1.0  # NCV noise intensity of the tracks (m^2/s^3)
    gospa_c: float = 200.0
    bridge_s: float = 2.0
    rate_window_s: float = 5.0  # s after the start when the achieved stream rates are said
    streams: dict = field(default_factory=lambda: dict(LIVE_STREAMS))
    #: "attitude" (attitude + gyro bias) or "nav" (GNSS-aided navigation: attitude,
    #: velocity, position, both IMU biases; :mod:`uavest.engine.navigation`). A live run
    #: cannot look ahead for a fix stream, so the model is an option, not a decision.
    model: str = "attitude"
    gnss_delay: float | None = None  # s; None: the navigation model's default
    #: where ``gnss_delay`` came from (None: the option --gnss-delay; ``uavest demo``: its
    #: simulator's receiver)
    gnss_delay_why: str | None = None
    #: s, the magnetometer sample's age (``--mag-delay``; None: 0, not learnt live: the
    #: age a replay's probe finds costs the yaw RMSE, docs/live.md)
    mag_delay: float | None = None
    #: rad, east positive (``--declination``, given in degrees): the stream's declination
    #: whatever the vehicle's parameters or the magnetic model say (None: theirs)
    declination: float | None = None
    geodesy: str = "auto"  # navigation: the local frame's (NavOptions.geodesy)
    #: overrides of the model's noise parameters (``--noise``; the navigation model's
    #: :class:`~uavest.models.navigation.NavNoise` or the attitude model's
    #: :class:`~uavest.models.attitude.AttitudeNoise` names), and where they came from
    #: (None: the option; ``uavest demo``: its simulator's sensor spec)
    noise: dict = field(default_factory=dict)
    noise_why: str | None = None
    #: navigation: what a previous result of the vehicle learned (``--aiding-from``,
    #: :func:`~uavest.apps.aiding.read_aiding`: the GNSS delay and velocity window, the
    #: baro noise, the field's inclination and where it was learned) to start with where
    #: the options leave it open (the run still learns its own), and where it came from
    aiding: dict = field(default_factory=dict)
    aiding_why: str | None = None
    #: navigation: the vehicle's sensor spec as taken (:meth:`SpecStart.as_dict
    #: <uavest.apps.sensor_spec.SpecStart.as_dict>`; None: it states none)
    sensor_spec: dict | None = None
    #: s after each estimator's first step from which its ``settled`` scores count
    #: (:meth:`NavScorer.scores <uavest.eval.navigation.NavScorer.scores>`, attitude-only:
    #: :class:`~uavest.eval.attitude.AttitudeScorer`'s): a start in flight aligns on a
    #: moving vehicle and takes some seconds to converge, which a short run's whole-run
    #: figure is mostly made of (docs/live.md, "Settled"); 0: none
    settle_s: float = 10.0

    @property
    def on_arrival(self) -> bool:
        """Samples on arrival (no reorder window), late ones applied by the history."""
        return not self.reorder_window > 0


# ----------------------------------------------------------------------- tracking lane


class _AdsbTruth:
    """Latest ADS-B position per ICAO address in the local NED frame of ``origin``."""

    def __init__(self, max_age: float) -> None:
        self.max_age = max_age
        self.origin: Array | None = None
        self.air: dict[int, tuple[float, Array, Array]] = {}
        self.own: tuple[float, Array] | None = None

    def push(self, s) -> None:
        if isinstance(s, PositionSample) and s.lat_lon_alt is not None and \
                s.source in ("GLOBAL_POSITION_INT", "GPS_RAW_INT"):
            lla = np.asarray(s.lat_lon_alt, float)
            if self.origin is None:
                self.origin = lla.copy()
            if s.source == "GLOBAL_POSITION_INT" or self.own is None:
                self.own = (s.t, geodetic_to_ned(lla, self.origin))
        elif isinstance(s, AdsbSample) and self.origin is not None:
            v = np.zeros(3) if s.vel_ned is None else np.asarray(s.vel_ned, float)
            self.air[s.icao] = (s.t - s.tslc, geodetic_to_ned(s.lat_lon_alt, self.origin), v)

    def snapshot(self) -> dict:
        return snapshot_vars(self)

    def restore(self, snap: dict) -> None:
        restore_vars(self, snap)

    def at(self, t: float, max_range: float) -> dict[int, Array]:
        """ICAO -> ENU [e, n, u, ve, vn, vu] of every fresh aircraft within range."""
        out = {}
        own = None if self.own is None else self.own[1]
        for icao, (t0, p, v) in self.air.items():
            if t - t0 > self.max_age:
                continue
            q = p + v * (t - t0)
            if own is not None and np.linalg.norm(q - own) > max_range:
                continue
            out[icao] = np.concatenate([_T @ q, _T @ v])
        return out


class TrackLane:
    """Step builder of the tracking lane: samples in, one :class:`Step` per radar scan out
    (``updates`` = ((Z (N, 3) range/azimuth/elevation, radar model at the scan's pose),)).
    Tracks live in the local ENU frame of the first ownship fix (m, m/s). ``truth`` keeps
    the ADS-B truth at every scan (ENU), for the track scorer."""

    def __init__(self, cfg: LiveConfig, seed: int) -> None:
        self.cfg = cfg
        r = cfg.radar
        self.model = RadarMeasurement(3, 6, r.sigma_r, r.sigma_az, r.sigma_el)
        self.motion = NearlyConstantVelocity(3, cfg.motion_q)
        self.virtual = (AdsbRadar(rng(seed, 0, "radar"), r) if cfg.radar_source == "adsb"
                        else None)
        self.truth_src = _AdsbTruth(r.max_age)
        self.truth: list[tuple[float, dict]] = []
        self.q_auto: Array | None = None
        self.pending: list[DetectionSample] = []
        self.t_last: float | None = None
        self.k = 0
        self.pose = SensorPose(np.zeros(3), np.eye(3), np.zeros(3))

    # the engine's history (:mod:`uavest.engine.history`), samples on arrival: a detection
    # of an OBSTACLE_DISTANCE_3D sweep already made into a scan is applied at its time
    # (the trackers re-step from before that scan). The virtual radar's inputs are used as
    # they arrive: an ADS-B report is timed by its arrival (never older than what came
    # before it) and carried to each scan time with its own velocity, and the ownship fix
    # is carried to the scan time with its velocity, so a fix that comes after a scan it
    # is older than moves that scan's ownship by at most a dt^2 / 2 (a few cm at 5 m/s^2
    # and 0.1 s, against 10 m of range noise); the sensor attitude and the scorer's truth
    # are held as they arrive.
    @property
    def committed(self) -> float:
        """Time (s) of the last scan made."""
        return -np.inf if self.t_last is None else self.t_last

    def order_sensitive(self, s) -> bool:
        """The vehicle's own detections (``--radar-source obstacle``) only."""
        return (self.virtual is None and isinstance(s, DetectionSample)
                and s.source == "OBSTACLE_DISTANCE_3D")

    def snapshot(self) -> dict:
        return snapshot_vars(self, skip=("cfg", "model", "motion"), appended=("truth",))

    def restore(self, snap: dict) -> None:
        restore_vars(self, snap)

    def push(self, s) -> list:
        out: list = []
        if self.virtual is not None:
            for scan in self.virtual.push(s):
                out += self._scan(scan.t, list(scan.detections))
        else:
            if isinstance(s, DetectionSample) and s.source == "OBSTACLE_DISTANCE_3D":
                if self.pending and s.t != self.pending[0].t:
                    out += self._flush_obstacles()
                self.pending.append(s)
            elif self.pending and s.t > self.pending[0].t:
                out += self._flush_obstacles()
        self.truth_src.push(s)
        if isinstance(s, AttitudeRef) and s.kind == "autopilot":
            self.q_auto = np.asarray(s.q, float)
        return out

    def flush(self) -> list:
        return self._flush_obstacles() if self.pending else []

    def _flush_obstacles(self) -> list:
        dets, self.pending = self.pending, []
        if self.q_auto is None or self.truth_src.own is None:
            return []  # no pose yet for the body-frame detections
        dets = [d for d in dets if d.frame == "BODY_FRD" and d.rae is not None]
        pose = SensorPose.from_ned_frd(self.q_auto, self.truth_src.own[1])
        return self._scan(dets[0].t if dets else self.t_last, dets, pose)

    def _scan(self, t: float, dets: list, pose: SensorPose | None = None) -> list:
        out: list = []
        if self.t_last is None:
            out.append(Start(t, None, self.motion.space, "first scan"))
        if dets and pose is None:
            d = dets[0]
            pose = SensorPose.from_ned_frd(d.q, d.sensor_ned)
        self.pose = pose or self.pose
        dt = 1.0 if self.t_last is None else max(t - self.t_last, 1e-3)
        self.t_last = t
        self.k += 1
        Z = np.array([d.rae for d in dets]).reshape(-1, 3)
        truth = self.truth_src.at(t, self.cfg.radar.max_range)
        self.truth.append((t, truth))
        model = self.model.with_pose(self.pose)
        X = np.array([truth[i] for i in sorted(truth)]).reshape(-1, 6)
        smp = RadarScanSample(t, self.k, Z, model, None, X)
        out.append(Step(self.k, t, dt, self.motion, ((Z, model),), info={"samples": (smp,)}))
        return out


class _TrackScore(Sink):
    """Collects every tracker's confirmed tracks per scan; :meth:`result` scores them
    against the lane's ADS-B truth (GOSPA, breaks, swaps, position RMSE, NEES)."""

    def __init__(self, lane: TrackLane) -> None:
        self.lane = lane
        self.tracks: dict[str, dict[int, dict]] = {}
        self.wall: dict[str, float] = {}

    def record(self, rec) -> None:
        if isinstance(rec, ScanRecord):
            self.tracks.setdefault(rec.estimator, {})[rec.k] = {
                t.id: (t.x, t.P) for t in rec.tracks if t.confirmed}
            self.wall[rec.estimator] = self.wall.get(rec.estimator, 0.0) + rec.wall_s

    def result(self, c: float) -> dict[str, dict]:
        truth = [tr for _, tr in self.lane.truth]
        times = [t for t, _ in self.lane.truth]
        dt = float(np.median(np.diff(times))) if len(times) > 1 else 1.0
        out = {}
        for label, per in self.tracks.items():
            ks = sorted(per)
            tsteps = [{j: x[:3] for j, (x, _) in per[k].items()} for k in ks]
            gsteps = [{i: s[:3] for i, s in truth[k - 1].items()} for k in ks]
            q = track_quality(gsteps, tsteps, c=c, dt=dt)
            e2, ne = [], []
            for tid, lst in q.assigned.items():
                for k0, j in lst:
                    x, P = per[ks[k0]][j]
                    e = x[:6] - truth[ks[k0] - 1][tid]
                    e2.append(float(e[:3] @ e[:3]))
                    ne.append(float(nees(e, P[:6, :6])))
            out[label.removeprefix("track:")] = {
                "gospa": q.gospa, "pos_rmse": float(np.sqrt(np.mean(e2))) if e2 else None,
                "nees_mean": float(np.mean(ne)) if ne else None,
                "track_breaks": q.track_breaks, "id_swaps": q.id_swaps,
                "false_tracks": q.false_tracks, "tracks_confirmed_total": q.confirmed_tracks,
                "scans": len(ks),
                "us_per_scan": 1e6 * self.wall.get(label, 0.0) / max(len(ks), 1),
            }
        return out


# ----------------------------------------------------------------------- status, gaps


#: Columns the live status line may use (it is rewritten in place with \\r: a longer line
#: wraps and the next rewrite scrolls the terminal).
STATUS_WIDTH = 100


def status_line(rates: dict, bad: int, nis: dict, resets: dict, p99_ms: float,
                width: int = STATUS_WIDTH) -> str:
    """The one-line status, padded to and never longer than ``width - 1`` columns:
    message rates (per s), bad data, each filter's NIS/resets, p99 latency (ms). What does
    not fit is shortened in order: message names, then the rates as one total, then the
    filters' NIS (resets kept), then the line is cut with "~"."""
    w = width - 1
    pairs = [(k, v) for k, v in sorted(rates.items()) if v >= 1]

    def filt(with_nis: bool) -> str:
        if with_nis:
            return " ".join(f"{k}:{nis.get(k, float('nan')):.1f}/{resets.get(k, 0)}"
                            for k in resets)
        return " ".join(f"{k}:{resets.get(k, 0)}" for k in resets)

    def short(name: str) -> str:
        return "".join(p[:1] for p in name.split("_")) if len(name) > 6 else name

    tail = f" | p99 {p99_ms:.1f} ms"
    rate_forms = [" ".join(f"{k} {v:.0f}" for k, v in pairs),
                  " ".join(f"{short(k)} {v:.0f}" for k, v in pairs),
                  f"{sum(v for _, v in pairs):.0f} msg/s in {len(pairs)} types"]
    line = ""
    for with_nis, head in ((True, "NIS/resets"), (False, "resets")):
        for r in rate_forms:
            line = f"[{r}] bad {bad} | {head} {filt(with_nis)}{tail}"
            if len(line) <= w:
                return line.ljust(w)
    return (line[:w - 1] + "~") if len(line) > w else line.ljust(w)


class _Status(Sink):
    """The one-line live status on stderr (once a second, only on a terminal unless
    ``force``): link rates per message, drops, filter resets and NIS, latency."""

    def __init__(self, link, enabled: bool | None = None, settle_s: float = 3.0) -> None:
        self.link = link
        self.on = sys.stderr.isatty() if enabled is None else enabled
        self.next = 0.0
        self.settle = time.monotonic() + settle_s  # the alignment's burst is not latency
        self.resets: dict[str, int] = {}
        self.nis: dict[str, float] = {}
        self.lat: list[float] = []
        self.t_sample = time.monotonic()
        self.imu_samples = 0

    def sample(self, s) -> None:
        self.t_sample = time.monotonic()
        if isinstance(s, ImuSample):
            self.imu_samples += 1

    def record(self, rec) -> None:
        now = time.monotonic()
        if now >= self.settle:
            self.lat.append(now - self.t_sample)
        if isinstance(rec, StepRecord):
            self.resets[rec.estimator] = rec.resets
            if rec.nis is not None:
                self.nis[rec.estimator] = rec.nis
        if self.on and now >= self.next:
            self.next = now + 1.0
            rates = self.link.rates() if hasattr(self.link, "rates") else {}
            lat = 1e3 * float(np.percentile(self.lat[-500:], 99)) if self.lat else 0.0
            bad = getattr(getattr(self.link, "stats", None), "bad_total", 0)
            line = status_line(rates, bad, self.nis, self.resets, lat)
            sys.stderr.write(f"\r{line}")
            sys.stderr.flush()

    def close(self) -> None:
        if self.on:
            sys.stderr.write("\n")


class _StreamCheck:
    """Checks, once ``window_s`` s after the samples start (or at the end of a shorter
    run), the achieved rate of every requested stream (:mod:`uavest.apps.streams`) and
    says it on one line per stream through ``note`` (default: logged, a warning for a
    missing or low stream)."""

    def __init__(self, link, window_s: float, note: Callable[[str], None] | None) -> None:
        self.link = link
        self.window_s = window_s
        self.note = note
        self.t0 = time.monotonic()
        self.result: list = []
        self.done = False
        if hasattr(link, "_rates_checked"):
            link._rates_checked = True  # the link's own 3-s check: said here, once

    def due(self, now: float) -> bool:
        return not self.done and now - self.t0 >= self.window_s

    def check(self) -> None:
        from .streams import achieved_rates

        self.done = True
        span = min(self.window_s, time.monotonic() - self.t0)
        self.result = achieved_rates(self._status(), self.link.rates(), span)
        for r in self.result:
            self._say(r.line(), r.status == "ok")

    def _status(self) -> dict:
        return getattr(self.link, "stream_status", {}) or {}

    def _say(self, line: str, ok: bool) -> None:
        if self.note is not None:
            self.note(line)
        elif ok:
            log.info("%s", line)
        else:
            log.warning("%s", line)

    def final(self, wall_s: float) -> dict:
        """Per stream: the check's result, the rate at the end (the link's last 5 s) and
        the mean over the run (messages accepted / ``wall_s``); a stream whose status
        changed since the check (ADS-B traffic that starts late) is said once more."""
        from .streams import achieved_rates, mean_rates

        now = achieved_rates(self._status(), self.link.rates(), 5.0)
        end = {r.name: r for r in now}
        counts = dict(getattr(getattr(self.link, "stats", None), "messages", {}) or {})
        mean = mean_rates(counts, [r.name for r in self.result], wall_s)
        out = {}
        for r in self.result:
            e = end.get(r.name, r)
            if e.status != r.status:
                self._say(f"stream {r.name}: {r.status} at {r.window_s:.0f} s, {e.status} at "
                          f"the end ({e.achieved_hz:.1f} Hz; mean {mean[r.name]:.1f} Hz over "
                          f"the run)", e.status == "ok")
            out[r.name] = {**r.as_dict(), "end_hz": e.achieved_hz, "end_status": e.status,
                           "mean_hz": mean[r.name]}
        return out


def _live_samples(link, stop: threading.Event | None, duration: float | None,
                  events: list, check: _StreamCheck | None = None) -> Iterator:
    t0 = time.monotonic()
    t_end = None if duration is None else t0 + duration
    try:
        for s in link:
            now = time.monotonic()
            if (stop is not None and stop.is_set()) or (t_end and now >= t_end):
                return
            if check is not None and check.due(now):  # what actually arrives, once
                check.check()
            if isinstance(s, LinkEvent):
                events.append(s)
                if s.kind == "link_lost":
                    log.warning("link lost at t = %.1f s (no message for the gap timeout)",
                                s.t)
                elif s.kind == "link_restored":
                    log.warning("link restored after %.1f s", s.duration or float("nan"))
            yield s
    finally:
        if check is not None and not check.done:  # a run shorter than the window
            check.check()


class _GapAware:
    """The step builder (attitude or navigation stream), restarted (a new alignment and
    Start) after a link gap longer than ``bridge_s``; shorter gaps are bridged by the next
    step's prediction."""

    def __init__(self, make: Callable[[], AttitudeStream | NavStream], bridge_s: float,
                 learner: LiveDelayLearner | None = None) -> None:
        self.make = make
        self.bridge_s = bridge_s
        self.learner = learner  # the live GNSS delay (navigation), kept out of snapshots
        self.stream = make()
        self.restarts = 0
        self._past: list[dict] = []  # the decisions of the streams before a restart

    @property
    def decisions(self) -> list[dict]:
        """Every stream's decisions in order, each restart one of them (``what``,
        ``value``, ``t`` s vehicle clock, ``why``)."""
        return self._past + self.stream.decisions

    @property
    def t_first(self) -> float | None:
        """Vehicle time (s) of the first IMU sample of the run, None before one."""
        ts = [d["t"] for d in self.decisions if d["what"] == "IMU"]
        return ts[0] if ts else None

    @property
    def committed(self) -> float:
        return float(self.stream.committed)

    def order_sensitive(self, s) -> bool:
        return not isinstance(s, LinkEvent) and self.stream.order_sensitive(s)

    def snapshot(self) -> dict:
        return snapshot_vars(self, skip=("make", "learner"), appended=("_past",))

    def restore(self, snap: dict) -> None:
        restore_vars(self, snap)

    def push(self, s) -> list:
        if isinstance(s, LinkEvent):
            if s.kind == "link_restored" and (s.duration or 0.0) > self.bridge_s:
                out = self.stream.flush() if self.stream._builder is not None else []
                self._past += self.stream.decisions
                self._past.append({"what": "restart", "value": "new alignment", "t": s.t,
                                   "why": f"link gap of {s.duration:.1f} s "
                                          f"(> bridge {self.bridge_s:g} s)"})
                self.stream = self.make()
                self.restarts += 1
                return out
            return []
        if self.learner is not None:
            self.learner.apply(self.stream)
        return self.stream.push(s)

    def flush(self) -> list:
        try:
            return self.stream.flush()
        except NoSamplesError:  # a stream stopped before any IMU sample
            return []


class _LearnGnss(Sink):
    """Hands each GNSS fix, baro and magnetometer sample, once as it arrives, to the live
    learner (the GNSS delay, the inclination) when it is from the navigation stream's
    sensor of that kind."""

    def __init__(self, learner: LiveDelayLearner, att: _GapAware) -> None:
        self.learner = learner
        self.att = att

    def sample(self, s) -> None:
        if isinstance(s, GnssSample):
            self.learner.add_gnss(s, getattr(self.att.stream, "gnss_source", None))
        elif isinstance(s, BaroSample):
            self.learner.add_baro(s, getattr(self.att.stream, "baro_source", None))
        elif isinstance(s, MagSample):
            self.learner.add_mag(s, getattr(self.att.stream, "mag_source", None))


class _NoEvents:
    """A lane builder that never sees link events."""

    def __init__(self, b) -> None:
        self.b = b

    @property
    def committed(self) -> float:
        return float(self.b.committed)

    def order_sensitive(self, s) -> bool:
        return not isinstance(s, LinkEvent) and self.b.order_sensitive(s)

    def snapshot(self):
        return self.b.snapshot()

    def restore(self, snap) -> None:
        self.b.restore(snap)

    def push(self, s) -> list:
        return [] if isinstance(s, LinkEvent) else self.b.push(s)

    def flush(self) -> list:
        return self.b.flush()


class PublishSink(Sink):
    """Publishes every estimate on a ground-station-side link under the estimator's own
    identity (:class:`uavest.sinks.mavlink_pub.MavlinkPublisher`): attitude per filter as
    ATTITUDE plus named values, NIS and resets as NAMED_VALUE_FLOAT, confirmed tracks as
    ADSB_VEHICLE with the SIMULATED flag (their positions from the lane's ENU frame)."""

    def __init__(self, publisher, lane: TrackLane) -> None:
        self.pub = publisher
        self.lane = lane

    def record(self, rec) -> None:
        if isinstance(rec, StepRecord):
            self.pub.attitude(rec.estimator, rec.t, rec.x[:4])
            if rec.nis is not None:
                self.pub.value(f"{rec.estimator[:6]}_nis", rec.t, rec.nis)
            if rec.reset:
                self.pub.value(f"{rec.estimator[:6]}_rst", rec.t, rec.resets)
        elif isinstance(rec, ScanRecord) and self.lane.truth_src.origin is not None:
            for tr in rec.tracks:
                if tr.confirmed:
                    ned, v = _T @ tr.x[:3], _T @ tr.x[3:6]
                    lat, lon, alt = ned_to_lla(ned, self.lane.truth_src.origin)
                    self.pub.track(rec.estimator, tr.id, rec.t, lat, lon, alt, v)

    def close(self) -> None:
        self.pub.close()


class SinkFailure(NamedTuple):
    """A sink that raised: its name, the call (open, sample, start, record, close), the
    vehicle time of the last record (s, None before any) and the exception."""

    sink: str
    call: str
    t: float | None
    error: BaseException

    def line(self) -> str:
        at = "" if self.t is None else f" at t = {self.t:.1f} s"
        kind = "" if isinstance(self.error, OSError | InputError) else "internal error: "
        return (f"{self.sink} failed in {self.call}{at} ({kind}{type(self.error).__name__}: "
                f"{self.error}); the run went on without it")

    def as_dict(self) -> dict:
        return {"sink": self.sink, "call": self.call, "t": self.t,
                "error": type(self.error).__name__, "message": str(self.error),
                "internal": not isinstance(self.error, OSError | InputError)}


class _Guarded(Sink):
    """A caller's sink (a recorder, the publisher) whose failure stops only that sink: the
    first exception it raises (a full disk, a closed file, a bug) is said on one line,
    kept in ``failures`` and the sink is not called again (but closed); the estimates and
    every other output go on. A live run does not end because its recording did."""

    def __init__(self, sink, failures: list) -> None:
        self.sink = sink
        path = getattr(sink, "path", None)
        self.name = type(sink).__name__ + ("" if path is None else f" ({path})")
        self.failures = failures
        self.dead = False
        self.t: float | None = None

    def _call(self, call: str, *a) -> None:
        if self.dead:
            return
        try:
            getattr(self.sink, call)(*a)
        except Exception as e:  # noqa: BLE001 - kept and said; the caller decides the exit
            self.dead = True
            f = SinkFailure(self.name, call, self.t, e)
            self.failures.append(f)
            log.error("%s", f.line())
            if call != "close":
                with contextlib.suppress(Exception):
                    self.sink.close()

    def open(self, info) -> None:
        self._call("open", info)

    def sample(self, s) -> None:
        self._call("sample", s)

    def start(self, label, t0, x0, P0) -> None:
        self._call("start", label, t0, x0, P0)

    def record(self, rec) -> None:
        self.t = rec.t
        self._call("record", rec)

    def close(self) -> None:
        self._call("close")


# ----------------------------------------------------------------------- the job


def check_live_config(cfg: LiveConfig) -> None:
    """A clear one-line error for a bad option of ``cfg`` (:func:`run_live` calls it
    before it opens the link, :func:`run_samples` again for its other callers)."""
    if cfg.model not in ("attitude", "nav"):
        raise InputError(f"--model must be attitude or nav for a live run, not {cfg.model!r}")
    if not (math.isfinite(cfg.reorder_window) and 0 <= cfg.reorder_window <= 5):
        raise InputError(f"--reorder-window must be from 0 to 5 s, got {cfg.reorder_window}")
    if cfg.on_arrival and not (math.isfinite(cfg.history_s) and 0 < cfg.history_s <= 5):
        raise InputError(f"--history must be more than 0 and at most 5 s, got {cfg.history_s}")
    if not (math.isfinite(cfg.settle_s) and 0 <= cfg.settle_s <= 3600):
        raise InputError(f"--settle must be from 0 to 3600 s, got {cfg.settle_s}")
    if cfg.model == "nav":
        NavOptions(noise=cfg.noise)  # checks the --noise names
    else:
        check_attitude_noise(cfg.noise, "(--model nav to use it)")


def with_vehicle_spec(cfg: LiveConfig, params: dict) -> LiveConfig:
    """``cfg`` with what the vehicle's sensor spec (``params``' ``SPEC_*``,
    :func:`~uavest.apps.sensor_spec.with_sensor_spec`) gives a navigation run where the
    options leave it open; ``cfg`` itself for the attitude model or no spec."""
    if cfg.model != "nav":
        return cfg
    # a delay from --aiding-from counts as given: an option, over the spec
    sp = with_sensor_spec(params, cfg.noise, cfg.gnss_delay if cfg.gnss_delay is not None
                          else cfg.aiding.get("gnss_delay"))
    doc = sp.as_dict()
    if doc is None:
        return cfg
    noise, delay = sp.merged(cfg.noise, cfg.gnss_delay)
    given, why = sorted(cfg.noise), sp.why
    return replace(
        cfg, noise=noise, gnss_delay=delay, sensor_spec=doc,
        noise_why=cfg.noise_why if why is None else why + (
            f"; option --noise: {', '.join(given)}" if given else ""),
        gnss_delay_why=sp.why_of("gnss_delay") or cfg.gnss_delay_why)


def live_mag_ref(cfg: LiveConfig) -> dict[str, float]:
    """The magnetic reference state a live navigation run adds to ``cfg.noise``:
    ``{"mag_ref_inc": LIVE_MAG_REF_INC}``, or nothing for the attitude model or when
    ``cfg.noise`` names either reference state (an option, or the vehicle's sensor spec)."""
    if cfg.model != "nav" or {"mag_ref_inc", "mag_ref_dec"} & set(cfg.noise):
        return {}
    return {"mag_ref_inc": LIVE_MAG_REF_INC}


def nav_options(cfg: LiveConfig, declination: float | None) -> NavOptions:
    """The navigation stream's options of a live run: ``cfg``'s, with ``declination``
    (rad; None: the source's parameters), and what ``cfg.aiding`` gives where the options
    leave it open (:func:`~uavest.apps.aiding.read_aiding`; each with ``cfg.aiding_why``);
    the values the vehicle's sensor spec gave (:func:`with_vehicle_spec`) say so."""
    a, noise = cfg.aiding, dict(cfg.noise)
    spec = SpecStart(**cfg.sensor_spec) if cfg.sensor_spec else SpecStart()
    kept = f"from --aiding-from: {cfg.aiding_why}"
    why = f"{kept}; this run's own estimate replaces it once learnt"
    gnss_delay, gnss_why = cfg.gnss_delay, cfg.gnss_delay_why
    if gnss_delay is None and "gnss_delay" in a:
        gnss_delay, gnss_why = a["gnss_delay"], why
    from_file = {k: a[k] for k in ("gnss_vel_window", "baro_noise", "mag_noise")
                 if k in a and k not in noise}
    noise.update(from_file)
    mag_ref = live_mag_ref(cfg)
    noise.update(mag_ref)
    inc, site, inc_why = a.get("mag_inclination"), None, None
    if inc is not None:
        site = (a["mag_site_lat"], a["mag_site_lon"])
        inc_why = f"{kept}, learned at {site[0]:.5f}, {site[1]:.5f}"
    return NavOptions(rate_hz=cfg.rate_hz, declination=declination, gnss_delay=gnss_delay,
                      mag_inclination=inc, mag_inclination_why=inc_why, mag_site=site,
                      gnss_delay_why=gnss_why, mag_delay=cfg.mag_delay,
                      on_arrival=cfg.on_arrival,
                      geodesy=cfg.geodesy, noise=noise,
                      mag_noise_why=spec.why_of("mag_noise") or (
                          cfg.noise_why if "mag_noise" in cfg.noise else
                          why if "mag_noise" in from_file else None),
                      baro_noise_why=kept if "baro_noise" in from_file else None,
                      gnss_vel_window_why=why if "gnss_vel_window" in from_file else None,
                      gnss_bias_why=spec.why_of(*GNSS_BIAS_KEYS) or (
                          cfg.noise_why if names_gnss_bias(cfg.noise) else None),
                      mag_ref_why=LIVE_MAG_REF_WHY if mag_ref else cfg.noise_why)


def run_samples(samples, cfg: LiveConfig, *, params: dict | None = None,
                declination: Callable[[], float | None] | None = None, sinks=(),
                info: RunInfo | None = None, link=None, status: bool | None = None,
                failures: list | None = None, stats=None) -> dict:
    """The live job over any sample stream (a live link, or a tlog for tests): both
    lanes, scorers, ``sinks``. Returns the result document. A sink that raises is
    stopped alone (:class:`_Guarded`); its :class:`SinkFailure` is appended to
    ``failures`` and described in the document's ``sink_failures``. With
    ``cfg.on_arrival`` the lanes run with the engine's history (``cfg.history_s``); a
    sample late beyond it is counted ``late`` (per source) in ``stats`` (default the
    source's or the link's :class:`~uavest.ingest.types.IngestStats`)."""
    check_live_config(cfg)
    if cfg.declination is not None:  # the option wins over the link's and the model's
        given = float(cfg.declination)
        declination = lambda: given  # noqa: E731
    nav = cfg.model == "nav"
    specs = model_filters(cfg.filters, nav, {**cfg.noise, **live_mag_ref(cfg)}
                          ) if cfg.filters else []
    tspecs = (build_filters(resolve_list(cfg.trackers, "radar", dim=TRACKER_DIM))
              if cfg.trackers else [])
    runner_cls = NavRunner if nav else FilterRunner
    runners = [runner_cls(sp.label, f, rng(cfg.seed, 0, filter_stream(sp.label)))
               for sp, f in specs]
    # with --gnss-delay it learns the velocity window and the baro delay at that delay; the
    # magnetometer's noise unless an option or the vehicle's spec gave it
    learner = (LiveDelayLearner(given=cfg.gnss_delay,
                                learn_mag_noise="mag_noise" not in cfg.noise)
               if nav and runners else None)
    att = _GapAware(_stream_factory(cfg, params, declination), cfg.bridge_s, learner)
    nav_scorer = NavScorer()
    lane = TrackLane(cfg, cfg.seed)
    trackers = _track_runners(cfg, lane, tspecs)
    # settled scores: the navigation scorer's (with velocity and position), else these
    scorer = AttitudeScorer(settle_s=None if nav else cfg.settle_s)
    tscore = _TrackScore(lane)
    st = _Status(link, status)
    info = info or RunInfo("", cfg.connect, cfg.seed)
    info.filters = {sp.label: sp.as_dict() for sp, _ in specs}
    info.filters.update({f"track:{sp.label}": sp.as_dict() for sp, _ in tspecs})
    hist = cfg.history_s if cfg.on_arrival else 0.0
    estimators = runners if learner is None else [learner.tap(runners[0]), *runners[1:]]
    lanes = [Lane(att, estimators, hist)] + (
        [Lane(_NoEvents(lane), trackers, hist if lane.virtual is None else 0.0)]
        if trackers else [])
    stats = stats if stats is not None else getattr(samples, "stats", None)
    if stats is None and link is not None:
        stats = getattr(link, "stats", None)
    failures = [] if failures is None else failures
    sinks = [_Guarded(s.bind(lane) if isinstance(s, _LazyPublish) else s, failures)
             for s in sinks]
    wall0 = time.perf_counter()
    late = None if stats is None else (lambda s: stats.bad("late", sample_key(s)))
    learn = [] if learner is None else [_LearnGnss(learner, att)]
    bias = _GyroBias() if nav else None
    steps = run_lanes(samples, lanes, [_Score(scorer), *([_NavScore(nav_scorer)] if nav else []),
                                       *([bias] if bias is not None else []),
                                       *learn, tscore, st, *sinks], info, late)
    wall = time.perf_counter() - wall0
    scorer.finish()
    nav_scorer.pos_from = getattr(att.stream, "fix_from", None)
    result = _attitude_result(cfg, att, runners, scorer, nav_scorer if nav else None)
    # the first filter's gyro bias: a ramp, as a replay finds it (and its hint)
    trend = None if bias is None else bias.trend_of(result["attitude"])
    doc = {"run": info.as_dict(), "steps": steps, "wall_s": wall, **result,
           **({"gyro_bias_trend": trend} if trend is not None else {}),
           "tracks": tscore.result(cfg.gospa_c),
           "scans": len(lane.truth),
           "attitude_steps": steps - len(lane.truth),
           "imu_samples": st.imu_samples,
           "targets_seen": len({i for _, tr in lane.truth for i in tr}),
           "attitude_restarts": att.restarts,
           "decisions": att.decisions, "t_first": att.t_first,
           # s the navigation steps are stamped before the IMU sample ending them
           "imu_delay_s": att.stream.summary.get("imu_delay_s"),
           # the navigation frame's origin (the first fix; deg, deg, m), as a replay's:
           # where a field learnt here was learnt (--aiding-from)
           **({"origin": att.stream.summary.get("origin")} if nav else {}),
           **({"gnss_delay_live": learner.as_dict()} if learner is not None else {}),
           "sink_failures": [f.as_dict() for f in failures],
           "history": _history_doc(cfg, lanes),
           "latency_ms": ({"p50": 1e3 * float(np.percentile(st.lat, 50)),
                           "p99": 1e3 * float(np.percentile(st.lat, 99))} if st.lat else None)}
    return doc


def _history_doc(cfg: LiveConfig, lanes: list[Lane]) -> dict:
    """The result document's ``history``: how the samples were ordered and, per lane run
    with a history, what it did (:class:`~uavest.engine.history.HistoryStats`)."""
    names = ("attitude", "tracking")
    return {"on_arrival": cfg.on_arrival, "reorder_window_s": cfg.reorder_window,
            "history_s": cfg.history_s if cfg.on_arrival else None,
            "lanes": {n: ln.history.stats.as_dict()
                      for n, ln in zip(names, lanes, strict=False) if ln.history is not None}}


def _stream_factory(cfg: LiveConfig, params: dict | None,
                    declination: Callable[[], float | None] | None
                    ) -> Callable[[], AttitudeStream | NavStream]:
    """A maker of the attitude lane's stream (:class:`NavStream` for ``--model nav``), for
    :class:`_GapAware` to call again after a gap: the declination (rad) asked each time."""
    def make_stream() -> AttitudeStream | NavStream:
        d = declination() if declination is not None else None
        if cfg.model == "nav":
            return NavStream(opts=nav_options(cfg, d), params=params)
        return AttitudeStream(opts=AttitudeOptions(rate_hz=cfg.rate_hz, update_hz=cfg.update_hz,
                                                     declination=d, noise=dict(cfg.noise),
                                                     on_arrival=cfg.on_arrival),
                              params=params)
    return make_stream


def _track_runners(cfg: LiveConfig, lane: TrackLane, tspecs: list) -> list[TrackerRunner]:
    """One tracker runner per tracker spec on the radar lane's motion model, labelled
    "track:<spec>" (an attitude ekf and a tracking ekf are two)."""
    tcfg = TrackerConfig(pd=cfg.radar.pd, clutter_density=max(cfg.radar.clutter_density, 1e-12))
    return [
        TrackerRunner(f"track:{sp.label}", lambda f=f, lab=sp.label: Tracker(
            f, lane.motion, tcfg, rng(cfg.seed, 0, filter_stream(lab))))
        for sp, f in tspecs
    ]


def _learnt_row(stream: Any, runner: Any) -> dict:
    """What a navigation filter's extra states learnt
    (:meth:`~uavest.engine.navigation.NavStream.learnt`: ``mag_ref``, ``gyro_drift``);
    empty for an attitude stream or without them."""
    learnt = getattr(stream, "learnt", None)
    return learnt(runner) if learnt is not None else {}


def _attitude_result(cfg: LiveConfig, att: _GapAware, runners: list,
                     scorer: AttitudeScorer, nav_scorer: NavScorer | None) -> dict:
    """The result document's reference, model and per-filter ``attitude`` scores (with the
    navigation scores when ``nav_scorer`` is given, and the autopilot's own estimate
    scored against a truth reference when the log has both)."""
    refs = scorer.refs
    ref, _ = select_reference(refs)
    truth = ref is not None and refs[ref].kind == "truth"
    doc: dict = {
        "reference": ref,
        "reference_kind": None if ref is None else refs[ref].kind,
        "model": cfg.model,
        "noise": {"overrides": dict(cfg.noise), "why": cfg.noise_why or (
            "option --noise" if cfg.noise else None)},
        **({"sensor_spec": cfg.sensor_spec} if cfg.sensor_spec is not None else {}),
        **({"accel_density": d} if (d := getattr(att.stream, "accel_density", None)) else {}),
        "attitude": {r.label: {**(scorer.scores(r.label, ref, truth) if ref else {}),
                               **(nav_scorer.scores(r.label, ref if truth else None,
                                                    getattr(att.stream, "frame", None),
                                                    settle_s=cfg.settle_s)
                                  if nav_scorer is not None else {}),
                               **({"gates": {k: dict(v) for k, v in r.gates.items()}}
                                  if getattr(r, "gates", None) else {}),
                               **_learnt_row(att.stream, r),
                               "resets": r.resets,
                               # when and why (the guard's, a GNSS lock-out's)
                               **({"resets_why": [[t, w] for t, w in r.reset_log]}
                                  if getattr(r, "reset_log", None) else {}),
                               "us_per_step": r.us_per_step}
                     for r in runners},
    }
    if ref is not None:
        for name in refs:
            if name != ref and refs[name].kind == "autopilot":
                doc["attitude"]["autopilot"] = {**scorer.scores(name, ref, False),
                                                "source": name}
                break
    return doc


#: A live run says it is compiling its kernels when loading them takes longer than this
#: (s): a first run after an install compiles them (52 s on a 2-core machine), later runs
#: load them from numba's disk cache (about 1 s).
KERNELS_SAY_S = 2.0


def load_kernels(say: Callable[[str], None], names: Iterable[str] | None = None) -> None:
    """Decide every registered compiled kernel module (:mod:`uavest.compiled`) now, before
    a live run opens its link, and ``say`` so if that takes more than
    :data:`KERNELS_SAY_S` s. Left to the first estimate that needs them, a first run's
    compilation held the estimator while the link's samples queued: ``uavest demo`` on a
    fresh install estimated 25 s behind the simulator and counted 2,517 bad packets.
    ``names``: only these registry entries (the test suite compiles the registry in two
    processes at once before its workers start)."""
    from ..compiled import REGISTRY

    todo = [REGISTRY[n] for n in names] if names is not None else list(REGISTRY.values())

    timer = threading.Timer(KERNELS_SAY_S, say, args=(
        "compiling the numba kernels (the first run after an install; numba caches them "
        "on disk) ...",))
    timer.daemon = True
    timer.start()
    try:
        for k in todo:
            k.get()
    finally:
        timer.cancel()


def run_live(cfg: LiveConfig, *, sinks=(), stop: threading.Event | None = None,
             command: str = "", status: bool | None = None,
             on_wait: Callable[[str], None] | None = None, publish: str | None = None,
             publish_sysid: int = 250, allow_vehicle_link: bool = False,
             on_note: Callable[[str], None] | None = None,
             failures: list | None = None) -> dict:
    """Attach to the vehicle at ``cfg.connect`` and run until ``cfg.duration`` s of wall
    time, ``stop`` or Ctrl-C; every output is complete when it returns or raises.
    ``on_note`` gets the one-line notes of the run (the achieved rate of every requested
    stream, ``cfg.rate_window_s`` s after the start); default: logged.

    ``cfg.connect`` naming a tlog file (a session ``--tlog`` recorded) runs the same job
    over it (:func:`replay_session`) instead: the live run's estimates again."""
    from pathlib import Path

    check_live_config(cfg)
    if Path(cfg.connect).is_file():
        return replay_session(cfg, sinks=sinks, command=command, failures=failures)
    from ..ingest.live import open_live

    load_kernels(on_wait or log.info)

    link = open_live(cfg.connect, sysid=cfg.sysid, signing_key=cfg.signing_key,
                     tlog=cfg.tlog, heartbeat_timeout=cfg.heartbeat_timeout,
                     reorder_window=cfg.reorder_window, streams=cfg.streams,
                     on_wait=on_wait, stop=stop)
    events: list = []
    try:
        link.start()
        cfg = with_vehicle_spec(cfg, link.answered_params(SPEC_PARAMS))
        info = RunInfo(command, cfg.connect, cfg.seed, config=_config(cfg),
                       versions=package_versions())
        sinks = list(sinks)
        if publish:
            from ..sinks.mavlink_pub import MavlinkPublisher

            pub = MavlinkPublisher(publish, sysid=publish_sysid, vehicle_conn=cfg.connect,
                            allow_vehicle_link=allow_vehicle_link)
            sinks.append(_LazyPublish(pub))
        check = _StreamCheck(link, cfg.rate_window_s, on_note)
        doc = run_samples(_live_samples(link, stop, cfg.duration, events, check), cfg,
                          params=link.params, declination=lambda: link.declination,
                          sinks=sinks, info=info, link=link, status=status,
                          failures=failures)
        streams = check.final(doc["wall_s"])
    finally:
        link.close()
    doc["link"] = {
        "connect": cfg.connect, "vehicle_sysid": link.vehicle_sysid,
        "declination_rad": link.declination, "declination_source": link.declination_source,
        "rates_hz": link.rates(), "bad_data": link.stats.as_dict(),
        "gaps": [{"t": e.t, "duration_s": e.duration} for e in events
                 if e.kind == "link_restored"],
        "signing": link.signing_active, "tlog": cfg.tlog,
        "streams": streams,
        "missing_streams": [k for k, v in streams.items() if v["end_status"] == "missing"],
    }
    return doc


def replay_session(cfg: LiveConfig, *, sinks=(), command: str = "",
                   failures: list | None = None) -> dict:
    """The live job over the tlog of a live session (``cfg.connect`` = its path): the same
    lanes, seeds, ordering (``cfg.reorder_window`` and ``cfg.history_s``, which must be
    the session's: ``uavest run``'s defaults, on arrival with a 0.3 s history; the tlog
    holds the messages in the order they arrived, so every late sample is late again and
    applied the same way) and causal decisions (declination taken when the stream gives
    it), so the attitude estimates are the live run's step by step; only the
    last step differs (the live run closed it when it stopped; the tlog also holds what
    the link had accepted but the engine not yet used). ``uavest replay`` of the same tlog
    is a file replay: it looks ahead for the GNSS fix (the magnetic model's declination at
    the alignment) and orders with a 1 s window, so its yaw can differ."""
    from ..ingest import open_source

    src = open_source(cfg.connect, sysid=cfg.sysid, reorder_window=cfg.reorder_window)
    if cfg.model == "nav":
        read_log_spec(src)  # what the vehicle answered at the session's start
    cfg = with_vehicle_spec(cfg, src.params)
    info = RunInfo(command, cfg.connect, cfg.seed, config=_config(cfg),
                   versions=package_versions())
    doc = run_samples(src, cfg, params=src.params, sinks=list(sinks), info=info,
                      status=False, failures=failures)
    doc["link"] = {
        "connect": cfg.connect, "replay_of_session": True, "vehicle_sysid": cfg.sysid,
        "declination_rad": None, "declination_source": "the log's parameters",
        "rates_hz": {}, "bad_data": src.stats.as_dict(), "gaps": [], "signing": False,
        "tlog": None, "streams": {}, "missing_streams": [],
    }
    return doc


class _LazyPublish:
    """A publisher waiting for the tracking lane it takes positions from."""

    def __init__(self, pub) -> None:
        self.pub = pub

    def bind(self, lane: TrackLane) -> PublishSink:
        return PublishSink(self.pub, lane)


def _config(cfg: LiveConfig) -> dict:
    d = {k: v for k, v in vars(cfg).items() if k not in ("radar", "signing_key")}
    d["radar"] = {k: v for k, v in vars(cfg.radar).items()}
    d["signing"] = cfg.signing_key is not None
    d["filters"], d["trackers"] = spec_labels(cfg.filters), spec_labels(cfg.trackers)
    return d


def ned_to_lla(ned: Array, origin: Array) -> tuple[float, float, float]:
    """Geodetic (deg, deg, m) of a local NED point (m) near ``origin`` (deg, deg, m):
    a local spherical approximation (metres-level within a few km), for publishing."""
    R = 6378137.0
    lat0 = math.radians(origin[0])
    lat = origin[0] + math.degrees(ned[0] / R)
    lon = origin[1] + math.degrees(ned[1] / (R * math.cos(lat0)))
    return lat, lon, float(origin[2] - ned[2])
