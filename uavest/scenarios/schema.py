"""Typed scenarios: one frozen dataclass per scenario kind and per TOML table.

Every field declares its type, unit, range and a one-line meaning next to it
(``field(default=..., metadata=sp(...))``, the way :mod:`uavest.core.spec` declares filter
parameters), and :func:`parse` turns the TOML dict into the typed scenario once, in
:func:`uavest.scenarios.load_scenario`: a wrong type or a value out of range is a one-line
:class:`ScenarioError` naming the key, its range and unit; a key the schema does not declare
is a :class:`ScenarioError` naming the close matches. ``--set`` keys resolve against the
same declarations (:func:`known_keys`). Frames: radar scenarios ENU (x east, y north),
simulator scenarios NED; angles in the TOML in degrees where the name ends in ``_deg``.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

from ..errors import InputError


class ScenarioError(InputError):
    """A scenario name, file, value or override could not be used."""


def sp(kind: str, doc: str, unit: str = "", lo: float | None = None, hi: float | None = None,
       lo_open: bool = False, hi_open: bool = False, choices: tuple = (),
       table: type | None = None) -> dict:
    """Field metadata declaring a scenario value. ``kind``: ``float``, ``int``, ``bool``,
    ``str``, ``floats`` (list of numbers), ``strs``, ``any`` (checked by its reader),
    ``table`` (a nested dataclass) or ``tables`` (an array of tables)."""
    return {"scen": dict(kind=kind, doc=doc, unit=unit, lo=lo, hi=hi, lo_open=lo_open,
                         hi_open=hi_open, choices=choices, table=table)}


def F(default: Any = None, *a: Any, **kw: Any) -> Any:
    """A declared scenario field (mutable defaults become tuples)."""
    if isinstance(default, list):
        default = tuple(default)
    return field(default=default, metadata=sp(*a, **kw))


def T(cls: type, doc: str) -> Any:
    """A nested table, defaulting to its own defaults."""
    return field(default_factory=cls, metadata=sp("table", doc, table=cls))


def TS(cls: type, doc: str) -> Any:
    """An array of tables (``[[targets]]``)."""
    return field(default=(), metadata=sp("tables", doc, table=cls))


NONNEG = dict(lo=0.0)
PROB = dict(lo=0.0, hi=1.0, lo_open=True)


# ------------------------------------------------------------------ Monte Carlo systems

@dataclass(frozen=True)
class BenchPrior:
    """Gaussian prior of a Monte Carlo benchmark: truth drawn from (truth_mean, truth_var),
    filters started at (filter_mean, filter_var); one entry per state dimension."""
    truth_mean: tuple = F((), "floats", "mean of the true initial state", "state units")
    truth_var: tuple = F((), "floats", "variance of the true initial state", "state units^2",
                         **NONNEG)
    filter_mean: tuple = F((), "floats", "filters' initial mean", "state units")
    filter_var: tuple = F((), "floats", "filters' initial variance", "state units^2", **NONNEG)


@dataclass(frozen=True)
class UngmModel:
    """x' = a x + b x/(1+x^2) + c cos(alpha k) + w, z = x^2 / 20 ... (Gordon, Salmond and
    Smith, 'Novel approach to nonlinear/non-Gaussian Bayesian state estimation')."""
    a: float = F(0.5, "float", "linear coefficient")
    b: float = F(25.0, "float", "growth coefficient")
    c: float = F(20.0, "float", "forcing amplitude")
    alpha: float = F(8.0, "float", "measurement divisor")
    beta: float = F(1.2, "float", "forcing frequency", "rad/step")
    Q: float = F(10.0, "float", "process noise variance", "1", **NONNEG)
    R: float = F(1.0, "float", "measurement noise variance", "1", **NONNEG)


@dataclass(frozen=True)
class Nonlinear2dModel:
    """The 2-D strongly nonlinear system documented in docs/filters.md."""
    nl: float = F(1.0, "float", "strength of the nonlinearity")
    rho: float = F(0.9, "float", "contraction factor")
    th: float = F(0.3, "float", "rotation per step", "rad")
    g: float = F(10.0, "float", "growth coefficient")
    alpha: float = F(4.0, "float", "measurement scale")
    beta: float = F(1.2, "float", "forcing frequency", "rad/step")
    c: float = F(10.0, "float", "forcing amplitude")
    Q: tuple = F((1.0, 1.0), "floats", "process noise variances", "1", **NONNEG)
    R: tuple = F((1.0, 1.0), "floats", "measurement noise variances", "1", **NONNEG)


@dataclass(frozen=True)
class LinearCvModel:
    """1-D constant velocity, position measured."""
    dt: float = F(1.0, "float", "time step", "s", lo=0.0, lo_open=True)
    q: float = F(0.1, "float", "white-noise acceleration intensity", "m^2/s^3", **NONNEG)
    R: float = F(4.0, "float", "position measurement variance", "m^2", **NONNEG)


_FILTERS_DOC = "filter specs compared (e.g. 'ukf', 'hybrid(n_cloud=32)')"


@dataclass(frozen=True)
class _Common:
    kind: str = F("", "str", "scenario kind")
    name: str = F("", "str", "scenario name (the file's stem when absent)")
    description: str = F("", "str", "one-line description")
    source: str = F("", "str", "where the scenario was read from (set by the loader)")


@dataclass(frozen=True)
class _MonteCarlo(_Common):
    runs: int = F(100, "int", "Monte Carlo runs", "", lo=1, hi=1_000_000)
    steps: int = F(100, "int", "time steps per run", "", lo=1, hi=1_000_000)
    divergence_rmse: float = F(math.inf, "float", "a run with a larger RMSE counts as diverged",
                               "state units", lo=0.0, lo_open=True)
    filters: tuple = F((), "strs", _FILTERS_DOC)


@dataclass(frozen=True)
class UngmScenario(_MonteCarlo):
    model: UngmModel = T(UngmModel, "the UNGM's coefficients")
    prior: BenchPrior = T(BenchPrior, "initial-state prior")


@dataclass(frozen=True)
class Nonlinear2dScenario(_MonteCarlo):
    model: Nonlinear2dModel = T(Nonlinear2dModel, "the system's coefficients")
    prior: BenchPrior = T(BenchPrior, "initial-state prior")


@dataclass(frozen=True)
class LinearCvScenario(_MonteCarlo):
    model: LinearCvModel = T(LinearCvModel, "the system's coefficients")
    prior: BenchPrior = T(BenchPrior, "initial-state prior")


# ------------------------------------------------------------------------------ radar

@dataclass(frozen=True)
class Motion:
    """Motion models of the truth and of the filters."""
    model: str = F("ncv", "str", "filters' motion model", choices=("ncv", "ct"))
    q: float = F(0.5, "float", "white-noise acceleration intensity (filters; truth unless "
                 "truth_q)", "m^2/s^3", **NONNEG)
    truth_q: float | None = F(None, "float", "truth's process noise intensity (default q)",
                              "m^2/s^3", **NONNEG)
    q_omega: float = F(1e-4, "float", "turn-rate noise intensity (CT)", "rad^2/s^3",
                       **NONNEG)

    @property
    def truth_noise(self) -> float:
        """The truth's process noise intensity (m^2/s^3): ``truth_q``, else ``q``."""
        return self.q if self.truth_q is None else self.truth_q


@dataclass(frozen=True)
class TrackRadar:
    """The tracking scenario's radar (ground or on the UAV)."""
    platform: str = F("ground", "str", "where the radar is", choices=("ground", "uav"))
    position: tuple | None = F(None, "floats", "ground radar position (ENU)", "m")
    yaw_deg: float = F(0.0, "float", "radar boresight yaw", "deg")
    sigma_range: float = F(10.0, "float", "range noise std", "m", **NONNEG)
    sigma_az_deg: float = F(1.0, "float", "azimuth noise std", "deg", **NONNEG)
    sigma_el_deg: float = F(1.0, "float", "elevation noise std (3-D)", "deg", **NONNEG)
    sigma_rr: float | None = F(None, "float", "range-rate noise std (absent: no range rate)",
                               "m/s", **NONNEG)
    pd: float = F(1.0, "float", "probability of detection per target per scan", "", **PROB)
    clutter_rate: float = F(0.0, "float", "mean false alarms per scan", "1/scan", lo=0.0,
                            hi=1e6)
    r_max: float = F(20000.0, "float", "maximum range: targets beyond are not detected, "
                     "clutter is drawn within", "m", **NONNEG)
    rr_max: float = F(100.0, "float", "maximum |range rate| of clutter", "m/s", **NONNEG)


@dataclass(frozen=True)
class RadarPrior:
    """Initial state [position, velocity] (ENU): truth at the mean, filters from a draw."""
    mean: tuple = F((), "floats", "prior mean [x, y(, z), vx, vy(, vz)]", "m, m/s")
    std: tuple = F((), "floats", "prior standard deviations", "m, m/s", **NONNEG)
    omega_std: float = F(0.05, "float", "turn-rate prior std (CT)", "rad/s", **NONNEG)


@dataclass(frozen=True)
class Tracker:
    """Overrides of :class:`uavest.tracking.tracker.TrackerConfig`."""
    gate_prob: float = F(0.999, "float", "gate probability", "", lo=0.0, hi=1.0, lo_open=True,
                         hi_open=True)
    confirm_m: int = F(4, "int", "hits needed to confirm (M of N)", "", lo=1)
    confirm_n: int = F(5, "int", "scans of the M-of-N confirmation window", "", lo=1)
    delete_misses: int = F(5, "int", "consecutive misses that delete a track", "", lo=1)
    init_vel_std: float = F(100.0, "float", "new track's velocity std per axis", "m/s",
                            **NONNEG)
    init_omega_std: float = F(0.1, "float", "new track's turn-rate std (CT)", "rad/s",
                              **NONNEG)
    max_pos_std: float = F(5000.0, "float", "track deleted above this position std", "m",
                           **NONNEG)
    association: str = F("gnn", "str", "data association", choices=("gnn", "jpda"))
    pd: float | None = F(None, "float", "detection probability assumed by JPDA (default "
                         "radar.pd)", "", **PROB)
    clutter_density: float | None = F(None, "float", "false alarms per scan per unit "
                                      "measurement volume assumed by JPDA (default "
                                      "radar.clutter_rate / the clutter box's volume)",
                                      "1/volume", **NONNEG)
    jpda_max_cluster: int = F(8, "int", "larger clusters: per-track PDA", "", lo=1)


@dataclass(frozen=True)
class Metrics:
    gospa_c: float = F(200.0, "float", "GOSPA cut-off (p = 2, alpha = 2)", "m", **NONNEG)


@dataclass(frozen=True)
class Uav:
    """The radar-carrying UAV's flight (ENU)."""
    start: tuple = F((0.0, 0.0, 500.0), "floats", "start position (ENU)", "m")
    speed: float = F(30.0, "float", "airspeed", "m/s", **NONNEG)
    yaw_deg: float = F(0.0, "float", "course, counter-clockwise from east", "deg")
    turns: tuple = F((), "any", "[[start step, end step, turn rate deg/s], ...]")
    attitude_error_deg: float = F(0.2, "float", "std of the estimated-attitude error per "
                                  "Euler angle", "deg", **NONNEG)


@dataclass(frozen=True)
class RadarTarget:
    """One scripted target: [x, y(, z), vx, vy(, vz)] (ENU) with coordinated turns."""
    start: tuple = F((), "floats", "initial state", "m, m/s")
    turns: tuple = F((), "any", "[[start step, end step, turn rate deg/s], ...]")
    born: int = F(0, "int", "first step alive", "step", lo=0)
    died: int | None = F(None, "int", "step it disappears (default: the end)", "step", lo=0)
    q: float | None = F(None, "float", "this target's process noise (default motion.truth_q)",
                        "m^2/s^3", **NONNEG)


@dataclass(frozen=True)
class RadarScenario(_Common):
    mode: str = F("tracker", "str", "'filter': one target, known association; 'tracker': "
                  "multi-target", choices=("filter", "tracker"))
    runs: int = F(100, "int", "Monte Carlo runs", "", lo=1, hi=1_000_000)
    steps: int = F(100, "int", "scans per run", "", lo=1, hi=1_000_000)
    dt: float = F(1.0, "float", "scan period", "s", lo=0.0, lo_open=True)
    ndim: int = F(2, "int", "2-D or 3-D", "", choices=(2, 3))
    divergence_rmse: float = F(math.inf, "float", "a run with a larger position RMSE counts "
                               "as diverged", "m", lo=0.0, lo_open=True)
    filters: tuple = F(("ekf", "ukf", "hybrid"), "strs", _FILTERS_DOC)
    missed: tuple = F((), "any", "scans with no detection")
    motion: Motion = T(Motion, "motion models")
    radar: TrackRadar = T(TrackRadar, "the radar")
    prior: RadarPrior = T(RadarPrior, "initial-state prior")
    tracker: Tracker = T(Tracker, "tracker settings")
    metrics: Metrics = T(Metrics, "metric settings")
    uav: Uav = T(Uav, "radar platform flight (platform = 'uav')")
    targets: tuple = TS(RadarTarget, "scripted targets (tracker mode)")


# -------------------------------------------------------------------------- simulator

@dataclass(frozen=True)
class Origin:
    lat_deg: float = F(0.0, "float", "latitude of NED (0, 0, 0), WGS84", "deg", lo=-90, hi=90)
    lon_deg: float = F(0.0, "float", "longitude of NED (0, 0, 0), WGS84", "deg", lo=-180,
                       hi=180)
    alt_m: float = F(0.0, "float", "ellipsoidal height of the origin", "m")


@dataclass(frozen=True)
class SimTime:
    epoch: float | None = F(None, "float", "UNIX time of boot (default 2026-01-01)", "s",
                            **NONNEG)


@dataclass(frozen=True)
class Manoeuvre:
    channel: str = F("", "str", "which attitude/climb channel",
                     choices=("roll", "pitch", "yaw", "climb"))
    kind: str = F("hold", "str", "shape", choices=("hold", "sine", "ramp"))
    start: float = F(0.0, "float", "start time", "s", **NONNEG)
    duration: float = F(0.0, "float", "duration", "s", **NONNEG)
    value: float = F(0.0, "float", "amplitude / target (deg, or m/s for climb)", "deg")
    amplitude: float | None = F(None, "float", "alias of value", "deg")
    freq_hz: float = F(0.0, "float", "frequency (sine)", "Hz", **NONNEG)
    ramp: float = F(0.0, "float", "ramp-in/out time", "s", **NONNEG)


@dataclass(frozen=True)
class Vehicle:
    position_ned: tuple = F((0.0, 0.0, 0.0), "floats", "position at t = 0 (NED)", "m")
    velocity_ne: tuple = F((0.0, 0.0), "floats", "initial horizontal velocity (N, E)", "m/s")
    yaw_deg: float = F(0.0, "float", "initial heading, clockwise from north", "deg")
    drag_per_s: float = F(0.3, "float", "linear horizontal drag", "1/s", **NONNEG)
    jitter_deg: float = F(0.0, "float", "per-axis std of the turbulence wobble", "deg",
                          **NONNEG)
    period_s: float | None = F(None, "float", "manoeuvre list repeats every period", "s",
                               lo=0.0, lo_open=True)
    manoeuvres: tuple = TS(Manoeuvre, "scripted manoeuvres")


@dataclass(frozen=True)
class Imu:
    rate_hz: float = F(400.0, "float", "IMU sample = simulation step rate", "Hz", lo=0.0,
                       lo_open=True)
    gyro_noise_density: float = F(1.5e-4, "float", "gyro white noise", "rad/s/sqrt(Hz)",
                                  **NONNEG)
    accel_noise_density: float = F(2.0e-3, "float", "accelerometer white noise",
                                   "m/s^2/sqrt(Hz)", **NONNEG)
    gyro_bias_std: float = F(0.01, "float", "initial gyro bias std per axis", "rad/s",
                             **NONNEG)
    accel_bias_std: float = F(0.05, "float", "initial accelerometer bias std per axis",
                              "m/s^2", **NONNEG)
    gyro_bias: tuple | None = F(None, "floats", "fixed initial gyro bias (FRD)", "rad/s")
    accel_bias: tuple | None = F(None, "floats", "fixed initial accelerometer bias (FRD)",
                                 "m/s^2")
    gyro_bias_walk: float = F(2.0e-5, "float", "gyro bias random walk", "rad/s/sqrt(s)",
                              **NONNEG)
    accel_bias_walk: float = F(1.0e-4, "float", "accelerometer bias random walk",
                               "m/s^2/sqrt(s)", **NONNEG)
    gyro_drift: float = F(0.0, "float", "gyro bias steady rate of change, every body axis "
                          "(a warming MEMS gyro; an ArduPilot SITL's SIM_DRIFT_SPEED, 0.05 "
                          "deg/s per minute = 1.45e-5)", "rad/s^2")
    vibration_hz: float = F(137.0, "float", "motor vibration fundamental", "Hz", **NONNEG)
    vibration_accel: tuple | None = F(None, "floats", "vibration amplitude per body axis",
                                      "m/s^2", **NONNEG)
    vibration_gyro: tuple | None = F(None, "floats", "vibration amplitude per body axis",
                                     "rad/s", **NONNEG)


@dataclass(frozen=True)
class Mag:
    declination_deg: float = F(0.0, "float", "east of true north", "deg", lo=-180, hi=180)
    inclination_deg: float = F(60.0, "float", "positive = field points down", "deg", lo=-90,
                               hi=90)
    intensity_gauss: float = F(0.5, "float", "total intensity", "gauss", **NONNEG)
    noise_gauss: float = F(0.003, "float", "white noise per sample", "gauss", **NONNEG)
    rate_hz: float = F(50.0, "float", "magnetometer update rate", "Hz", lo=0.0, lo_open=True)
    offsets_gauss: tuple | None = F(None, "floats", "hard-iron offset (FRD)", "gauss")


@dataclass(frozen=True)
class Gps:
    rate_hz: float = F(5.0, "float", "fix rate", "Hz", lo=0.0, lo_open=True)
    sigma_h: float = F(0.8, "float", "horizontal error std (Gauss-Markov)", "m", **NONNEG)
    sigma_v: float = F(1.5, "float", "vertical error std", "m", **NONNEG)
    tau_s: float = F(60.0, "float", "error correlation time", "s", lo=0.0, lo_open=True)
    sigma_vel: float = F(0.1, "float", "white velocity noise", "m/s", **NONNEG)
    speed_acc_scale: float = F(1.5, "float", "the speed accuracy the receiver reports "
                               "(GPS_RAW_INT vel_acc) over sigma_vel; its h_acc / v_acc "
                               "are sigma_h / sigma_v", "", **NONNEG)


@dataclass(frozen=True)
class Ahrs:
    roll_err_deg: float = F(1.0, "float", "roll error std", "deg", **NONNEG)
    pitch_err_deg: float = F(1.0, "float", "pitch error std", "deg", **NONNEG)
    yaw_err_deg: float = F(2.0, "float", "yaw error std", "deg", **NONNEG)
    tau_s: float = F(30.0, "float", "error correlation time", "s", lo=0.0, lo_open=True)
    pos_err_m: float = F(0.3, "float", "position error std", "m", **NONNEG)
    vel_err: float = F(0.05, "float", "velocity error std", "m/s", **NONNEG)


@dataclass(frozen=True)
class Baro:
    sigma_m: float = F(0.5, "float", "barometric altitude error std", "m", **NONNEG)


@dataclass(frozen=True)
class SimRadar:
    """Body-fixed radar at the vehicle (axes body FRD) -> OBSTACLE_DISTANCE_3D."""
    enabled: bool = F(True, "bool", "send detections")
    rate_hz: float = F(2.0, "float", "scan rate", "Hz", lo=0.0, lo_open=True)
    r_min: float = F(50.0, "float", "minimum range", "m", **NONNEG)
    r_max: float = F(5000.0, "float", "maximum range", "m", **NONNEG)
    fov_az_deg: float = F(360.0, "float", "full azimuth width", "deg", lo=0.0, hi=360.0)
    fov_el_deg: float = F(90.0, "float", "full elevation width", "deg", lo=0.0, hi=180.0)
    pd: float = F(0.9, "float", "probability of detection", "", lo=0.0, hi=1.0)
    clutter_rate: float = F(2.0, "float", "mean false detections per scan", "1/scan",
                            **NONNEG)
    sigma_range: float = F(5.0, "float", "range noise std", "m", **NONNEG)
    sigma_az_deg: float = F(1.0, "float", "azimuth noise std", "deg", **NONNEG)
    sigma_el_deg: float = F(1.0, "float", "elevation noise std", "deg", **NONNEG)
    report_ids: bool = F(True, "bool", "obstacle_id = target id (false: 65535)")


@dataclass(frozen=True)
class Adsb:
    enabled: bool = F(True, "bool", "send ADSB_VEHICLE")
    rate_hz: float = F(1.0, "float", "rate per aircraft", "Hz", lo=0.0, lo_open=True)
    sigma_h: float = F(3.0, "float", "horizontal position noise std", "m", **NONNEG)
    sigma_v: float = F(5.0, "float", "altitude noise std", "m", **NONNEG)
    sigma_vel: float = F(0.3, "float", "velocity noise std", "m/s", **NONNEG)


@dataclass(frozen=True)
class Mavlink:
    rates: Any = F(None, "any", "{message name: rate Hz} streamed from the start")


@dataclass(frozen=True)
class SimTarget:
    name: str | None = F(None, "str", "callsign (default TGTn)")
    id: int | None = F(None, "int", "obstacle id (default n)", "", lo=0)
    icao: int | None = F(None, "int", "ICAO address", "", lo=0, hi=0xFFFFFF)
    emitter: str = F("light", "str", "ADS-B emitter type")
    adsb: bool = F(True, "bool", "has a transponder")
    position_ned: tuple = F((), "floats", "position at t = 0 (NED)", "m")
    velocity_ned: tuple = F((0.0, 0.0, 0.0), "floats", "velocity (NED)", "m/s")
    turns: tuple = F((), "any", "[[t0 s, t1 s, deg/s], ...] (t1 may be inf)")
    period_s: float | None = F(None, "float", "path repeats every period", "s", lo=0.0,
                               lo_open=True)


@dataclass(frozen=True)
class SimScenario(_Common):
    origin: Origin = T(Origin, "where NED (0, 0, 0) is")
    time: SimTime = T(SimTime, "clock")
    vehicle: Vehicle = T(Vehicle, "the simulated vehicle")
    imu: Imu = T(Imu, "the IMU")
    mag: Mag = T(Mag, "magnetometer and Earth field")
    gps: Gps = T(Gps, "GPS_RAW_INT")
    ahrs: Ahrs = T(Ahrs, "the autopilot's estimate")
    baro: Baro = T(Baro, "barometer")
    radar: SimRadar = T(SimRadar, "body-fixed radar")
    adsb: Adsb = T(Adsb, "ADS-B reports")
    mavlink: Mavlink = T(Mavlink, "MAVLink stream settings")
    targets: tuple = TS(SimTarget, "other aircraft")


KINDS: dict[str, type] = {
    "ungm": UngmScenario, "nonlinear2d": Nonlinear2dScenario, "linear_cv": LinearCvScenario,
    "radar": RadarScenario, "sim": SimScenario,
}


# ------------------------------------------------------------------------------ parse

def _range(m: dict) -> str:
    if m["choices"]:
        return "one of " + ", ".join(repr(c) for c in m["choices"])
    lo, hi = m["lo"], m["hi"]
    what = {"int": "an integer", "bool": "true or false", "str": "a string",
            "floats": "a list of numbers", "strs": "a non-empty list of strings"}.get(
        m["kind"], "a number")
    if lo is not None and hi is not None:
        what += f" in {'(' if m['lo_open'] else '['}{lo:g}, {hi:g}{')' if m['hi_open'] else ']'}"
    elif lo is not None:
        what += f" {'>' if m['lo_open'] else '>='} {lo:g}"
    elif hi is not None:
        what += f" {'<' if m['hi_open'] else '<='} {hi:g}"
    return what + (f" ({m['unit']})" if m["unit"] and m["unit"] != "1" else "")


def _is_num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _in_range(x: float, m: dict, path: str) -> bool:
    if isinstance(x, float) and math.isnan(x):
        return False
    if math.isinf(x) and "divergence" not in path:
        return False
    lo, hi = m["lo"], m["hi"]
    if lo is not None and (x < lo or (m["lo_open"] and x == lo)):
        return False
    return not (hi is not None and (x > hi or (m["hi_open"] and x == hi)))


def _value(v: Any, m: dict, path: str, where: str) -> Any:
    kind = m["kind"]

    def bad():
        raise ScenarioError(f"{where}{path} = {v!r}: must be {_range(m)}")

    if kind == "any":
        return tuple(v) if isinstance(v, list) else v
    if kind == "bool":
        if not isinstance(v, bool):
            bad()
    elif kind == "str":
        if not isinstance(v, str):
            bad()
    elif kind == "int":
        if not isinstance(v, int) or isinstance(v, bool):
            bad()
    elif kind == "float":
        if not _is_num(v) or not _in_range(v, m, path):
            bad()
        return float(v) if not isinstance(v, int) else v
    elif kind == "floats":
        if not isinstance(v, list) or not all(_is_num(x) and _in_range(x, m, path) for x in v):
            bad()
        return tuple(v)
    elif kind == "strs":
        if not isinstance(v, list) or not v or not all(isinstance(x, str) and x.strip()
                                                       for x in v):
            bad()
        return tuple(v)
    if m["choices"] and v not in m["choices"]:
        bad()
    if kind == "int" and not _in_range(v, m, path):
        bad()
    return v


def declared(cls: type) -> dict[str, dict]:
    """{field name: its metadata} of a scenario dataclass."""
    return {f.name: f.metadata["scen"] for f in fields(cls) if "scen" in f.metadata}


def known_keys(cls: type, prefix: str = "") -> list[str]:
    """Every dotted key the schema declares (tables recursed; arrays of tables not)."""
    out = []
    for name, m in declared(cls).items():
        out.append(prefix + name)
        if m["kind"] == "table":
            out += known_keys(m["table"], f"{prefix}{name}.")
    return out


def close_keys(key: str, cands: list[str]) -> list[str]:
    """Up to three of ``cands`` a user who wrote ``key`` may have meant: the same key in
    another case first (``model.q`` for ``model.Q``), then ``difflib``'s close matches,
    then the dotted forms of a bare leaf name (``clutter_rate``: ``radar.clutter_rate``)."""
    close = [c for c in cands if c.lower() == key.lower()]
    close += [c for c in difflib.get_close_matches(key, cands, n=3, cutoff=0.6)
              if c not in close]
    leaf = key.rsplit(".", 1)[-1]
    close += [c for c in cands if c.rsplit(".", 1)[-1] == leaf and c not in close]
    return close[:3]


def _unknown(key: str, cands: list[str], where: str) -> ScenarioError:
    close = close_keys(key, cands)
    if close:
        hint = f"did you mean {', '.join(close)}?"
    else:
        top = sorted(c for c in cands if "." not in c)
        hint = f"known keys: {', '.join(top)}"
    return ScenarioError(f"{where}unknown scenario key {key!r} ({hint})")


def _table(cls: type, d: Any, path: str, where: str) -> Any:
    if not isinstance(d, dict):
        raise ScenarioError(f"{where}{path.rstrip('.') or 'scenario'} = {d!r}: must be a table")
    decl = declared(cls)
    for k in d:
        if k not in decl:
            raise _unknown(path + k, [path + c for c in known_keys(cls)], where)
    kw = {}
    for name, m in decl.items():
        if name not in d:
            continue
        v = d[name]
        if m["kind"] == "table":
            kw[name] = _table(m["table"], v, f"{path}{name}.", where)
        elif m["kind"] == "tables":
            if not isinstance(v, list):
                raise ScenarioError(f"{where}{path}{name} = {v!r}: must be an array of tables")
            kw[name] = tuple(_table(m["table"], x, f"{path}{name}[{i}].", where)
                             for i, x in enumerate(v))
        elif v is None:
            kw[name] = v
        else:
            kw[name] = _value(v, m, path + name, where)
    return cls(**kw)


def schema_for(kind: str) -> type:
    if kind not in KINDS:
        raise ScenarioError(f"unknown scenario kind {kind!r}; known: {', '.join(KINDS)}")
    return KINDS[kind]


def parse(sc: dict) -> Any:
    """The typed scenario of a TOML dict (with ``kind``), every value checked."""
    where = f"{sc['source']}: " if sc.get("source") else ""
    return _table(schema_for(sc.get("kind", "")), sc, "", where)


def default_of(cls: type, name: str) -> Any:
    f = {f.name: f for f in fields(cls)}[name]
    return f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]
