"""The GNSS delay estimated from the lag of the GNSS velocity behind the IMU
(uavest.engine.gnss_delay; the replay's probe, uavest.apps.replay.probe_gnss_delay)."""

from __future__ import annotations

import dataclasses
import heapq
from pathlib import Path

import numpy as np
import pytest

from uavest.engine.gnss_delay import MAX_SD_S, DelayProbe
from uavest.engine.records import Step
from uavest.ingest.types import GnssSample

G = 9.81
LOG = Path(__file__).resolve().parents[2] / "logs" / "sim_200hz.tlog"


class _Model:
    g = G


def _accel(t: np.ndarray, amp: float) -> np.ndarray:
    """A manoeuvring NED acceleration (m/s^2): sums of sines in north and east."""
    a = np.zeros((t.size, 3))
    a[:, 0] = amp * (np.sin(1.3 * t) + 0.5 * np.sin(3.1 * t + 1.0))
    a[:, 1] = amp * (np.cos(0.7 * t) + 0.4 * np.sin(4.3 * t))
    return a


def _probe(delay: float, amp: float = 2.0, noise: float = 0.02, seed: int = 0,
           hz: float = 25.0, T: float = 120.0, window: float = 0.0) -> DelayProbe:
    """Level flight (identity attitude, so the specific force is a - g) with the GNSS
    velocity (5 Hz, horizontal only, white noise) ``delay`` s behind the IMU, the mean
    over ``window`` s centred there when ``window`` > 0."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / hz
    t = np.arange(dt, T, dt)
    a = _accel(t - 0.5 * dt, amp)  # the step's mean acceleration (midpoint)
    p = DelayProbe()
    p.start()
    x = np.zeros(16)
    x[0] = 1.0
    for k in range(t.size):
        f = a[k] - np.array([0.0, 0.0, G])
        p.add_step(Step(k + 1, float(t[k]), dt, _Model(), (), np.r_[np.zeros(3), f]), x)
    tf = np.arange(1.0, T - 1.0, 0.2)
    ts = np.linspace(0.0, T, 200001)
    v = np.cumsum(_accel(ts, amp), axis=0) * (ts[1] - ts[0])
    for tk in tf:
        if window > 0:
            m = np.abs(ts - (tk - delay)) <= 0.5 * window
            vk = np.r_[v[m, :2].mean(axis=0), np.nan]
        else:
            vk = np.array([np.interp(tk - delay, ts, v[:, i]) for i in range(2)] + [np.nan])
        vk[:2] += noise * rng.standard_normal(2)
        p.add_gnss(GnssSample(float(tk), np.array([47.0, 8.0, 400.0]), vk, 3, np.nan,
                              np.nan, np.nan, np.nan, np.nan, -1, "GPS_RAW_INT"))
    return p


@pytest.mark.parametrize("delay", [0.0, 0.08, 0.23])
def test_a_known_delay_is_found(delay):
    est = _probe(delay).estimate()
    assert est.delay is not None, est.why
    assert abs(est.delay - delay) < 0.005  # 0 too: the grid reaches below it
    assert est.sd is not None and 0 < est.sd < MAX_SD_S


@pytest.mark.parametrize("window", [0.0, 0.2, 0.35])
def test_a_known_velocity_window_is_found(window):
    """A GNSS velocity that is the mean over a window (an ArduPilot SITL's: 0.35 s) gives
    the window, with the delay at its centre; an instantaneous one gives 0."""
    est = _probe(0.08, window=window, noise=0.005).estimate()
    assert est.delay is not None and abs(est.delay - 0.08) < 0.005, est.why
    assert est.window is not None, est.window_why
    assert abs(est.window - window) < 0.03
    if window == 0.0:
        assert "noise" in est.window_why


def test_a_given_delay_is_kept_and_the_window_found_at_it():
    """``--gnss-delay`` given: the delay is not searched (no standard error), the window is
    estimated at it."""
    p = _probe(0.08, window=0.35, noise=0.005)
    est = p.estimate(delay=0.08)
    assert est.delay == 0.08 and est.sd is None and est.why == "given"
    assert est.window is not None and abs(est.window - 0.35) < 0.03, est.window_why
    assert p.estimate(delay=0.08).window == est.window  # estimating changes nothing
    # a wrong delay given: kept, the data's own lag said beside it, and no window at it
    wrong = p.estimate(delay=0.0)
    assert wrong.delay == 0.0 and wrong.data_delay is not None
    assert abs(wrong.data_delay - 0.08) < 0.005 and "own lag 0.08" in wrong.given_note()
    assert wrong.window is None and "not modelled" in wrong.window_why
    assert p.estimate().given_note() == ""


def test_the_standard_error_covers_the_error():
    """Over seeds, the estimate's error is of the size of its standard error."""
    z = []
    for seed in range(5):
        est = _probe(0.1, noise=0.1, seed=seed, T=60.0).estimate()
        assert est.delay is not None, est.why
        z.append((est.delay - 0.1) / est.sd)
    assert np.sqrt(np.mean(np.square(z))) < 3.0


def test_a_hover_gives_no_estimate():
    est = _probe(0.1, amp=0.01, noise=0.05).estimate()
    assert est.delay is None and "too little manoeuvring" in est.why


def test_too_few_fixes_give_no_estimate():
    p = DelayProbe()
    assert p.estimate().delay is None and "too few" in p.estimate().why


def test_a_known_magnetometer_age_is_found():
    """Readings of a fixed field taken ``age`` s before their stamps while the vehicle
    turns (yaw 0.8 rad/s, a roll/pitch wobble): the probe finds the age and the field's
    inclination, and the scatter is the readings' noise."""
    from uavest.geometry.rotation import euler_to_quat, quat_rotate_inv

    rng = np.random.default_rng(3)
    age, incl, noise = 0.06, np.deg2rad(63.0), 0.003
    mref = np.array([np.cos(incl), 0.0, np.sin(incl)])

    def att(t):
        return euler_to_quat(0.2 * np.sin(0.9 * t), 0.15 * np.cos(1.3 * t), 0.8 * t)

    p = DelayProbe()
    p.start()
    dt = 0.04
    for k, t in enumerate(np.arange(dt, 60.0, dt)):
        x = np.zeros(16)
        x[:4] = att(t)
        p.add_step(Step(k + 1, float(t), dt, _Model(), (), np.r_[np.zeros(3), 0, 0, -G]), x)
    for t in np.arange(1.0, 59.0, 0.1):
        b = quat_rotate_inv(att(t - age), mref) + noise * rng.standard_normal(3)
        p.add_mag(float(t), b)
    est = p.estimate_mag()
    assert est.delay is not None, est.why
    assert abs(est.delay - age) < 0.005
    assert abs(est.inclination - incl) < np.deg2rad(0.1)
    assert 0.5 * noise < est.scatter < 2.0 * noise


@pytest.mark.parametrize("absorbed", [False, True])
def test_the_inclination_is_corrected_for_the_filters_tilt_error(absorbed):
    """The filter's attitude carries a constant tilt error (0.5 deg about east, in NED)
    while the vehicle turns and accelerates: the readings turned to NED with it put the
    field's inclination 0.5 deg off; the mismatch between the specific force turned to NED
    with it and the GNSS velocity changes measures that error, and the corrected
    inclination is within 0.05 deg. ``absorbed``: the filter's accelerometer bias
    estimate takes the whole tilt error's acceleration (tilt and bias look alike to it):
    the correction, on the force without that bias, still sees it."""
    from uavest.geometry.rotation import (
        euler_to_quat,
        quat_exp,
        quat_mul,
        quat_rotate,
        quat_rotate_inv,
    )

    incl, err = np.deg2rad(63.0), np.deg2rad(0.5)
    mref = np.array([np.cos(incl), 0.0, np.sin(incl)])
    q_err = quat_exp(np.array([0.0, err, 0.0]))  # about east (NED), left-multiplied
    g_n = np.array([0.0, 0.0, G])
    p = DelayProbe()
    p.start()
    dt, T = 0.04, 120.0
    t = np.arange(dt, T, dt)
    a = _accel(t - 0.5 * dt, 2.0)
    for k, tk in enumerate(t):
        q_true = euler_to_quat(0.1 * np.sin(0.9 * tk), 0.1 * np.cos(1.3 * tk), 0.3 * tk)
        f_b = quat_rotate_inv(q_true, a[k] - g_n)  # the specific force, body FRD
        x = np.zeros(16)
        x[:4] = quat_mul(q_err, q_true)
        if absorbed:  # the bias that makes R(q_filter) (f - b) + g the true acceleration
            x[13:16] = f_b - quat_rotate_inv(x[:4], a[k] - g_n)
        p.add_step(Step(k + 1, float(tk), dt, _Model(), (), np.r_[np.zeros(3), f_b]), x)
        if k % 3 == 0:
            p.add_mag(float(tk), quat_rotate_inv(q_true, mref))
    ts = np.linspace(0.0, T, 200001)
    v = np.cumsum(_accel(ts, 2.0), axis=0) * (ts[1] - ts[0])
    for tk in np.arange(1.0, T - 1.0, 0.2):
        vk = np.array([np.interp(tk, ts, v[:, i]) for i in range(2)] + [np.nan])
        p.add_gnss(GnssSample(float(tk), np.array([47.0, 8.0, 400.0]), vk, 3, np.nan,
                              np.nan, np.nan, np.nan, np.nan, -1, "GPS_RAW_INT"))
    est = p.estimate_mag()
    assert est.inclination_uncorrected is not None and est.tilt_corrected > 900
    off = abs(est.inclination_uncorrected - incl)
    assert 0.8 * err < off < 1.2 * err  # the tilt error, uncorrected
    assert abs(est.inclination - incl) < np.deg2rad(0.05)
    # readings outside every fix pair keep the plain down direction: no GNSS, no change
    q = DelayProbe()
    q._t, q._dt, q._a, q._q, q._seg = p._t, p._dt, p._a, p._q, p._seg
    q._mt, q._mf = p._mt, p._mf
    plain = q.estimate_mag()
    assert plain.tilt_corrected == 0 and plain.inclination == plain.inclination_uncorrected
    assert abs(quat_rotate(q_err, mref)[2] - np.sin(plain.inclination)) < 1e-3


def _shifted(samples, d):
    """The samples with every GNSS fix stamped ``d`` s later (a known added delay)."""
    buf: list = []
    for s in samples:
        if isinstance(s, GnssSample):
            s = dataclasses.replace(s, t=s.t + d)
        heapq.heappush(buf, (s.t, id(s), s))
        while buf and buf[0][0] < s.t - 1.0:
            yield heapq.heappop(buf)[2]
    while buf:
        yield heapq.heappop(buf)[2]


@pytest.mark.slow
def test_replay_probe_finds_an_injected_delay():
    """On the project's simulator log, GNSS stamped 0.15 s late: the probe's estimate
    moves by 0.15 s (within 3 standard errors), and the replay runs with it."""
    from uavest.apps.replay import ReplayConfig, probe_gnss_delay
    from uavest.ingest import open_source

    got = []
    for d in (0.0, 0.15):
        src = open_source(LOG)
        doc, it = probe_gnss_delay(_shifted(src, d), ReplayConfig(model="nav"), src.params)
        assert doc["delay"] is not None, doc["why"]
        assert doc["delay_used"] == doc["delay"] and "estimated" in doc["why_used"]
        assert sum(1 for _ in it) > 10000  # the samples come back whole
        got.append(doc)
    shift = got[1]["delay"] - got[0]["delay"]
    sd = np.hypot(got[0]["sd"], got[1]["sd"])
    assert abs(shift - 0.15) < 3 * sd + 0.002, (shift, sd)


def _first_samples(n: int):
    from uavest.ingest import open_source

    src = open_source(LOG)
    it = iter(src)
    return [next(it) for _ in range(n)], src.params


def test_a_reader_error_inside_the_probe_reaches_the_caller():
    """A reader that fails while the probe reads (a cut log) is not swallowed by the probe
    (the run went on with the probe's samples only, the rest of the log silently lost)."""
    from uavest.apps.replay import ReplayConfig, probe_gnss_delay
    from uavest.ingest.types import IngestError

    head, params = _first_samples(3000)

    def failing():
        yield from head
        raise IngestError("the log is cut here")

    with pytest.raises(IngestError, match="cut here"):
        probe_gnss_delay(failing(), ReplayConfig(model="nav"), params)


def test_a_probe_that_cannot_start_is_reported_and_gives_every_sample_back():
    """Without GNSS fixes and without the magnetometer the probe's navigation stream
    cannot start: the probe says so as its reason and hands every sample back for the
    run."""
    from uavest.apps.replay import ReplayConfig, probe_gnss_delay

    head, params = _first_samples(3000)
    no_fix = [s for s in head if not isinstance(s, GnssSample)]
    doc, it = probe_gnss_delay(iter(no_fix), ReplayConfig(model="nav", use_mag=False),
                               params)
    assert doc["delay"] is None and "the probe run failed" in doc["why"], doc["why"]
    assert "could not start" in doc["why"]
    assert list(it) == no_fix


def _baro_probe(baro_delay: float, climb: float = 2.0, seed: int = 0) -> DelayProbe:
    """GNSS heights at 5 Hz (0.08 s behind their stamps, 2 cm noise) and baro heights at
    10 Hz ``baro_delay`` s behind theirs (3 cm noise, a 400 m offset, a slow drift), of a
    vehicle climbing and descending at up to ``climb`` m/s."""
    rng = np.random.default_rng(seed)
    p = DelayProbe()

    def h(t):
        return 20.0 + climb * 8.0 * np.sin(t / 8.0)

    for tk in np.arange(1.0, 119.0, 0.2):
        p.add_gnss(GnssSample(float(tk), np.array([47.0, 8.0, h(tk - 0.08)
                                                   + 0.02 * rng.standard_normal()]),
                              np.array([1.0, 0.0, np.nan]), 3, np.nan, np.nan, np.nan,
                              np.nan, np.nan, -1, "GPS_RAW_INT"))
    for tk in np.arange(1.0, 119.0, 0.1):
        p.add_baro(float(tk), h(tk - baro_delay) + 400.0 + 0.002 * tk
                   + 0.03 * rng.standard_normal())
    return p


@pytest.mark.parametrize("delay", [0.0, 0.02, 0.09])
def test_a_known_baro_delay_is_found(delay):
    est = _baro_probe(delay).estimate_baro(gnss_delay=0.08)
    assert est.delay is not None, est.why
    assert abs(est.delay - delay) < 0.01
    assert est.spread is not None and 0.02 < est.spread < 0.06  # the two noises
    # the offset at the last baro sample inside the fixes (the GNSS's last height is at
    # 118.8 - 0.08 s): the 400 m and the drift to there, not its mean over the stretch
    # (0.12 m less)
    assert est.offset is not None and abs(est.offset - (400.0 + 0.002 * 118.7)) < 0.01


def test_a_level_flight_gives_no_baro_delay():
    est = _baro_probe(0.05, climb=0.0).estimate_baro(gnss_delay=0.08)
    assert est.delay is None and ("not sharp" in est.why or "end of the range" in est.why)


def test_live_learner_makes_a_window_found_equal_to_the_default_known():
    """A window learned live as 0 s (an instantaneous receiver's) equals the stream's
    default, yet is news: the stream drops its floor for an unknown window."""
    from uavest.engine.gnss_delay import LiveDelayLearner

    class Stream:
        _builder = object()
        delay, vel_window, window_known = 0.08, 0.0, False
        baro_delay, baro_known = 0.0, False
        summary: dict = {}

        def __init__(self):
            self.calls = []

        def set_gnss_delay(self, *a):
            self.calls.append("delay")

        def set_gnss_window(self, w, t, why):
            self.calls.append(("window", w))
            self.window_known = True

        def set_baro_delay(self, d, t, why):
            self.calls.append(("baro", d))
            self.baro_known = True

    learner = LiveDelayLearner(given=0.08)
    learner.window, learner.baro_delay, learner.t_decided = 0.0, 0.0, 60.0
    s = Stream()
    learner.apply(s)
    assert s.calls == [("window", 0.0), ("baro", 0.0)]  # the given delay is not set again
    learner.apply(s)
    assert len(s.calls) == 2  # once known, not again


def _drift_probe(err, T=120.0, seed=0):
    """A probe fed 5-Hz 3-D fixes of a vehicle circling at 8 m/s whose positions carry
    ``err(t, rng)`` (n, 2) m and whose velocities are exact."""
    from uavest.geometry.geodesy import LocalFrame
    from uavest.ingest.types import GnssSample

    frame = LocalFrame(47.4, 8.5, 500.0)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, T, 0.2)
    w = 8.0 / 60.0
    p = np.c_[60 * np.sin(w * t), 60 * (1 - np.cos(w * t)), np.full(t.size, -30.0)]
    v = np.c_[8 * np.cos(w * t), 8 * np.sin(w * t), np.zeros(t.size)]
    p[:, :2] += err(t, rng)
    lat, lon, h = frame.ned_to_geodetic(p)
    probe = DelayProbe()
    for k in range(t.size):
        probe.add_gnss(GnssSample(float(t[k]), np.array([lat[k], lon[k], h[k]]), v[k], 3,
                                  0.8, 1.5, 0.1, 1.0, 1.0, 10, "GPS_RAW_INT", 0))
    return probe.estimate_drift(frame)


def test_the_drift_tells_correlated_fix_errors_from_independent_ones():
    """Independent position errors (0.5 m) move the fixes against their integrated
    velocities by 0.5 sqrt(2) at 1 s and at 10 s; a 60-s Gauss-Markov error (0.8 m, as
    uavest's simulator's receiver) moves them little over 1 s and much more over 10 s;
    exact fixes not at all."""
    from uavest.sim.sensors import GaussMarkov

    white = _drift_probe(lambda t, r: r.normal(0, 0.5, (t.size, 2)))
    assert white.short == pytest.approx(0.5 * np.sqrt(2), rel=0.15)
    assert white.long == pytest.approx(white.short, rel=0.2) and not white.correlated

    def gm(t, r):
        return GaussMarkov([0.8, 0.8], 60.0, 0.2, r).run(t.size)

    slow = _drift_probe(gm)
    assert slow.correlated and slow.long > 2.0 * slow.short, slow
    # sized as GNSS bias states: the receiver's accuracy (0.8 / 1.5 m) and a correlation
    # time from the drift's growth near the process's 60 s
    bias, why = slow.bias_model()
    assert bias is not None and bias["gnss_bias_h"] == 0.8 and bias["gnss_bias_v"] == 1.5
    assert 30.0 < bias["gnss_bias_tau"] < 120.0, (bias, why)
    assert white.bias_model()[0] is None
    assert dataclasses.replace(slow, h_acc=None).bias_model() == (
        None, "the receiver reports no accuracy to size them with")
    exact = _drift_probe(lambda t, r: np.zeros((t.size, 2)))
    assert exact.long < 0.01 and not exact.correlated  # the trapezoid's own error
    few = _drift_probe(lambda t, r: np.zeros((t.size, 2)), T=1.0)
    assert few.long is None and "too few" in few.why


@pytest.mark.parametrize("spread, used", [(0.004, "floor"), (0.1, 0.1), (0.6, 0.2)])
def test_the_baro_noise_taken_is_the_spread_within_the_floor_and_the_default(spread, used):
    """The probe's baro spread against the GNSS height becomes the run's baro noise,
    clipped to [BARO_NOISE_MIN, the source's default]: an ArduPilot SITL's few mm (its
    GNSS height has no noise) go up to the floor, a real receiver's decimetres down to
    the default."""
    from uavest.apps.replay import ReplayConfig, _baro_doc
    from uavest.engine.gnss_delay import BARO_NOISE_MIN, BaroEstimate
    from uavest.models.navigation import NavNoise

    best = BaroEstimate(0.08, 0.001, 500, "", spread=spread, noise_default=0.2)
    doc = _baro_doc(ReplayConfig(model="nav"), best, NavNoise(), "the first 240 s")
    want = BARO_NOISE_MIN if used == "floor" else used
    assert doc["noise_used"] == pytest.approx(want)
    assert 0.005 < BARO_NOISE_MIN <= 0.02  # above a SITL's spread, below a real baro's
    assert "--noise baro_noise=M" in doc["noise_why"]
    given = _baro_doc(ReplayConfig(model="nav", noise={"baro_noise": 0.3}), best, NavNoise(),
                      "the first 240 s")
    assert "noise_used" not in given  # the option wins


def test_a_step_s_ned_acceleration_is_the_numpy_formula():
    """The probe's NED acceleration of a step (Python floats): the mid-step attitude's
    rotation of the specific force less the accelerometer bias, plus gravity, as the numpy
    formula it replaced (to rounding), and of the raw force; the DCM bitwise
    :func:`quat_to_dcm`'s."""
    from uavest.geometry.rotation import dcm_f, quat_exp, quat_mul, quat_rotate, quat_to_dcm

    g = np.random.default_rng(3)
    p = DelayProbe()
    p.start()
    for k in range(50):
        x = g.normal(size=16)
        x[:4] /= np.linalg.norm(x[:4])
        u = np.r_[g.normal(size=3), g.normal(0.0, 5.0, 3)]
        dt = g.uniform(0.002, 0.1)
        p.add_step(Step(k + 1, 0.1 * (k + 1), dt, _Model(), (), u), x)
        q = quat_mul(x[:4], quat_exp(-0.5 * dt * (u[:3] - x[10:13])))
        assert np.array_equal(np.array(dcm_f(tuple(q))), quat_to_dcm(q))
        want, want_raw = quat_rotate(q, np.stack([u[3:6] - x[13:16], u[3:6]]))
        want[2] += G
        want_raw[2] += G
        np.testing.assert_allclose(p._a[-1], want, rtol=0, atol=1e-13)
        np.testing.assert_allclose(p._a_raw[-1], want_raw, rtol=0, atol=1e-13)
