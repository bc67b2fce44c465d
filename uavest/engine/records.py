"""The one result model: typed per-step records made by the engine and handed to sinks.

Every estimator the engine runs turns one :class:`Step` into one record:

* :class:`StepRecord` for a single-state filter (attitude, a Monte Carlo trial, one radar
  target with known association): time, posterior mean and covariance, the innovations
  of the step's updates with their NIS, the reset/divergence event of the step, wall time;
* :class:`ScanRecord` for a multi-target tracker: one :class:`TrackEstimate` per live
  track after the scan.

Metrics (:mod:`uavest.eval`) are pure functions of records and truth; sinks
(:mod:`uavest.sinks`) receive every record as it is made. Conventions: ``t`` in seconds
(the source's clock: vehicle time since boot for logs and live links, k dt for
simulations); ``x`` the state in ambient coordinates (attitude: quaternion [w, x, y, z]
body FRD -> NED, then gyro bias rad/s FRD; radar: NED/ENU position m, velocity m/s as the
scenario defines); ``P`` the covariance in the tangent space of ``x`` (attitude: 3
body-frame rotation errors rad, 3 bias errors rad/s).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

Array = np.ndarray

__all__ = [
    "NavAnchor", "RadarScanSample", "RunInfo", "ScanRecord", "Start", "StateSample", "Step",
    "StepRecord", "TrackEstimate", "Update", "package_versions",
]


@dataclass(frozen=True, slots=True)
class Start:
    """(Re)start every estimator at time ``t0`` (s) from ``prior`` (a Gaussian on
    ``space``). A stream begins with one; a live link sends another after a gap it cannot
    bridge. ``reason`` says why (``"start"``, ``"link gap 3.2 s"``...). ``keep_tail``:
    on a restart, the last ``keep_tail`` components of the running estimate (mean and
    their covariance block; the gyro biases of an attitude state) replace the prior's,
    so a re-alignment after an IMU gap keeps what the filter learnt. ``keep_x`` /
    ``keep_P``: the same for any components, by index into the state vector and into
    the tangent covariance (e.g. a navigation state's attitude and biases when the
    first GNSS fix re-anchors velocity and position); their cross-covariance with the
    others is zero. ``augment``: on a restart, the prior is ``augment(estimate)`` of each
    estimator's own running estimate instead (``prior`` then only gives the size: the
    navigation state growing GNSS bias states mid-run)."""

    t0: float
    prior: Any
    space: Any
    reason: str = "start"
    keep_tail: int = 0
    keep_x: tuple[int, ...] = ()
    keep_P: tuple[int, ...] = ()
    augment: Any = None


@dataclass(frozen=True, slots=True)
class Step:
    """One filter step: predict from the previous step's time to ``t`` over ``dt`` s with
    input ``u`` through ``transition``, then update with each ``(z, model)`` of
    ``updates`` in order. ``k`` counts steps from 1. ``info`` is for sinks, never for filters:
    ``info["samples"]``, samples the step builder derived (e.g. a radar scan as a
    :class:`RadarScanSample`), is handed to every sink's
    ``sample`` before the estimators step."""

    k: int
    t: float
    dt: float
    transition: Any
    updates: tuple[tuple[Array, Any], ...] = ()
    u: Array | None = None
    info: dict[str, Any] | None = None


@dataclass(frozen=True, slots=True)
class RadarScanSample:
    """One radar scan as a sample for sinks (the engine hook a radar source hands to
    :meth:`~uavest.sinks.base.Sink.sample`): scan ``k`` at ``t`` (s), detections ``Z``
    (N, m) [range m, azimuth rad, (elevation rad), (range rate m/s)], the radar model at
    the scan's pose (``RadarMeasurement``, world ENU), optional ``origins`` (N,) (target
    index, -1 clutter) and optional ``truths`` (n_targets, state) world ENU [p, v] with NaN
    rows for absent targets (recorded as the truth for the report's GOSPA). Made by the
    radar producers (experiments, the live app, the report's demo), read by the sinks."""

    t: float
    k: int
    Z: Array
    model: Any
    origins: Array | None = None
    truths: Array | None = None


@dataclass(frozen=True, slots=True)
class NavAnchor:
    """Where a navigation run's positions are: from time ``t`` (s) on, in the local NED
    frame whose origin is ``lat``/``lon`` (deg) and ``alt`` (m) (the first raw GNSS fix
    of ``source``), made by :func:`uavest.geometry.geodesy.make_frame` with
    ``geodesy``. A run that starts before the first fix (unaided) has its positions in no
    frame before ``t``. Handed to sinks through ``Step.info["samples"]`` with the first
    step at the anchor, so a recording carries it (``/navigation/anchor``) and its report
    scores what the replay scored."""

    t: float
    lat: float
    lon: float
    alt: float
    source: str
    reason: str
    geodesy: str = "wgs84"  # the frame's: "wgs84" or "sphere" (make_frame)


@dataclass(frozen=True, slots=True)
class StateSample:
    """One step of a generic vector-state run (a Monte Carlo trial of the benchmark
    systems: UNGM, nonlinear2d, linear_cv) as a sample for sinks, handed with the step
    through ``Step.info["samples"]`` before the estimators step: step ``k`` at ``t`` (s),
    the true state ``x`` (n,) (None when unknown) and the step's measurement ``z`` (m,)
    (None without one), in the system's own units. A recorder that sees one records the
    run's :class:`~uavest.engine.records.StepRecord` s on the generic ``/state/<label>/*``
    channels (state = plain vector, covariance in the same coordinates) instead of the
    attitude ones."""

    t: float
    k: int
    x: Array | None = None
    z: Array | None = None


@dataclass(frozen=True, slots=True)
class Update:
    """One measurement update of a step: its kind (the model's class name), residual
    ``nu`` = z - zhat (m,), innovation covariance ``S`` (m, m) and NIS nu^T S^-1 nu."""

    kind: str
    nu: Array
    S: Array
    nis: float


@dataclass(frozen=True, slots=True)
class StepRecord:
    """A single-state estimator's result for one step.

    ``x``/``P``: posterior mean (size,) and tangent covariance (n, n) after the step's
    updates; ``x_pred``/``P_pred``: the prediction before the updates (only when the
    runner was asked to record it); ``C``: the cross-covariance Cov(e_{k-1}, e_k) for RTS
    smoothing (only when asked). ``reset`` is True when the divergence guard
    re-initialised the filter in this step, ``reason`` says why. ``wall_s`` is the wall
    time of the step (predict + updates + estimate)."""

    estimator: str
    k: int
    t: float
    x: Array
    P: Array
    updates: tuple[Update, ...] = ()
    reset: bool = False
    reason: str = ""
    resets: int = 0
    wall_s: float = 0.0
    x_pred: Array | None = None
    P_pred: Array | None = None
    C: Array | None = None

    @property
    def nis(self) -> float | None:
        """Total NIS of the step's updates (None without updates)."""
        return float(sum(u.nis for u in self.updates)) if self.updates else None


@dataclass(frozen=True, slots=True)
class TrackEstimate:
    """One track after a scan: stable ``id``, state ``x``/``P`` (see module doc),
    ``confirmed`` status, ``hit`` (a detection updated it in this scan), the prediction
    ``x_pred`` before the update (None for a track born in this scan)."""

    id: int
    x: Array
    P: Array
    confirmed: bool
    hit: bool
    x_pred: Array | None = None


@dataclass(frozen=True, slots=True)
class ScanRecord:
    """A multi-target tracker's result for one scan: the live tracks after it, the ids
    deleted in it, resets of track filters, and the scan's wall time."""

    estimator: str
    k: int
    t: float
    tracks: tuple[TrackEstimate, ...]
    deleted: tuple[int, ...] = ()
    resets: int = 0
    wall_s: float = 0.0


@dataclass
class RunInfo:
    """What a run is: the command line, the source, the resolved configuration of every
    estimator (``filters``: label -> resolved spec dict), the seed, package versions and,
    for scenario runs, the resolved scenario (``scenario``: every declared field with its
    defaults filled in, :func:`uavest.scenarios.resolved`). Written at the head of every
    result (JSON, recordings)."""

    command: str
    source: str
    seed: int
    filters: dict[str, dict[str, Any]] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=dict)
    scenario: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "command": self.command, "source": self.source, "seed": self.seed,
            "filters": self.filters, "config": self.config, "versions": self.versions,
            "scenario": self.scenario,
        }


def package_versions() -> dict[str, str]:
    """Versions of uavest and the packages its results depend on."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("uavest", "numpy", "scipy", "pymavlink", "pyulog"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out
