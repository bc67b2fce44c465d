"""The navigation stream (uavest/engine/navigation.py) on seeded synthetic flights:
IMU, GNSS, baro and magnetometer samples in, every registry filter through the engine,
bad aiding data gated and counted."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from uavest.engine import attitude, navigation
from uavest.engine.build import build_filters
from uavest.engine.loop import Lane, run_lanes
from uavest.engine.nav_aiding import _Aid
from uavest.engine.navigation import NavOptions, NavRunner, NavStream
from uavest.errors import InputError
from uavest.geometry.geodesy import LocalFrame
from uavest.geometry.navigation import NavSpace
from uavest.geometry.rotation import euler_to_quat, quat_rotate_inv
from uavest.ingest.types import (
    BaroSample,
    GnssSample,
    ImuSample,
    LogParams,
    MagSample,
    NoSamplesError,
)
from uavest.models.attitude import inclination_from_params, mag_reference
from uavest.models.navigation import ImuTransition, NavNoise
from uavest.presets import resolve_list
from uavest.sinks.base import Collector

SP = NavSpace()
#: the UKF and hybrid cases are in the full suite (seconds each), the EKF in the fast tier
SLOW_SPECS = [pytest.param(s, marks=pytest.mark.slow) for s in ("ukf", "hybrid")]
ORIGIN = (47.4, 8.5, 430.0)
DT = 0.01  # 100 Hz IMU


def flight(seed: int, T: float = 40.0, mag: bool = True, gnss_every: int = 20,
           delay: float = 0.0, v0: float = 6.0, vd: float = 0.0, gnss_from: float = 1.5,
           baro_delay: float = 0.0, heave: float = 0.0, incl: float = np.deg2rad(63.0),
           ba: tuple = (0.1, -0.05, 0.08)):
    """(samples, truth t (K,), truth states (K, 16)): 10 s straight, then a turn (down
    speed ``vd`` m/s throughout), with
    IMU (interval means, 'sensor_combined'), GNSS 5 Hz from ``gnss_from`` s (before it,
    when later than 1.5 s, the receiver's no-fix messages; stamped ``delay`` s after the
    state it measures), baro 10 Hz (stamped ``baro_delay`` s late), magnetometer 10 Hz;
    ``heave`` m/s^2, the amplitude of a down acceleration of period 4 pi s. Biases bg, ba
    constant (``ba`` m/s^2); the field's inclination ``incl`` rad."""
    rng = np.random.default_rng(seed)
    fr = LocalFrame(*ORIGIN)
    tr = ImuTransition(NavNoise(), lat=np.deg2rad(ORIGIN[0]), h=ORIGIN[2])
    bg, ba = np.array([0.01, -0.005, 0.003]), np.array(ba)
    x = np.concatenate([euler_to_quat(0.0, 0.0, 0.3), [v0 * np.cos(0.3), v0 * np.sin(0.3), vd],
                        np.zeros(3), bg, ba])
    mref = mag_reference(np.deg2rad(2.0), incl) * 0.48
    t0 = 100.0
    out, ts, xs = [], [], []
    n = int(T / DT)
    for k in range(n):
        t = t0 + k * DT
        wz = 0.0 if k * DT < 10 else 0.15
        w = np.array([0.02 * np.sin(0.5 * k * DT), 0.01 * np.cos(0.3 * k * DT), wz])
        v_b = quat_rotate_inv(x[:4], x[4:7])
        f = np.cross(w, v_b) - quat_rotate_inv(
            x[:4], np.array([0, 0, tr.g - heave * np.cos(0.5 * k * DT)]))
        if 1 <= k:
            x = tr.f(x[None], t, DT, np.concatenate([w, f]))[0]
        ts.append(t)
        xs.append(x.copy())
        g = w + bg + rng.normal(size=3) * 0.003 / np.sqrt(DT)
        a = f + ba + rng.normal(size=3) * 0.05 / np.sqrt(DT)
        out.append(ImuSample(t, g, a, "sensor_combined"))
        if mag and k % 10 == 0:
            fb = quat_rotate_inv(x[:4], mref) + rng.normal(size=3) * 0.005
            out.append(MagSample(t, fb, "sensor_combined"))
        if k % 10 == 5:
            out.append(BaroSample(t + baro_delay, np.nan, 20.0, -x[9] + 50.0 + rng.normal() * 0.3,
                                  "sensor_baro"))
        if k % gnss_every == 0 and k * DT < gnss_from and gnss_from > 1.5:  # no fix yet
            out.append(GnssSample(t, np.zeros(3), np.full(3, np.nan), 1, np.nan, np.nan,
                                  np.nan, np.nan, np.nan, 0, "vehicle_gps_position"))
        if k % gnss_every == 0 and k * DT >= gnss_from:
            p = x[7:10] + rng.normal(size=3) * [0.4, 0.4, 0.8]
            lat, lon, h = fr.ned_to_geodetic(p)
            v = x[4:7] + rng.normal(size=3) * 0.08
            out.append(GnssSample(t + delay, np.array([float(lat), float(lon), float(h)]), v,
                                  3, 0.5, 1.0, 0.1, 0.8, 1.2, 12, "vehicle_gps_position"))
    out.sort(key=lambda s: s.t)
    return out, np.array(ts), np.array(xs)


def run_nav(samples, specs=("ekf",), opts=None, seed=0, params=None):
    stream = NavStream(opts=opts or NavOptions(integration="hold"), params=params)
    runners = [NavRunner(sp.label, flt, np.random.default_rng(seed))
               for sp, flt in build_filters(resolve_list(list(specs), "attitude", dim=15))]
    coll = Collector()
    run_lanes(iter(samples), [Lane(stream, runners)], [coll])
    return stream, runners, coll


def errors(stream, coll, label, ts, xs, t_from):
    """Tangent errors (estimate -> truth) from ``t_from`` s and the covariances; truth
    positions moved into the stream's frame (its origin is the first fix)."""
    a = coll.arrays(label)
    t, x, P = a["t"], a["x"], a["P"]
    keep = t >= t_from
    xt = xs[np.searchsorted(ts, t[keep])].copy()
    lat, lon, h = LocalFrame(*ORIGIN).ned_to_geodetic(xt[:, 7:10])
    xt[:, 7:10] = stream.frame.geodetic_to_ned(lat, lon, h)
    return SP.local(x[keep], xt), P[keep]


def rms(e):
    return float(np.sqrt(np.mean(e**2)))


@pytest.mark.parametrize("spec", ["ekf", *SLOW_SPECS])
def test_every_filter_converges_on_a_synthetic_flight(spec):
    samples, ts, xs = flight(1)
    stream, runners, coll = run_nav(samples, [spec])
    e, P = errors(stream, coll, runners[0].label, ts, xs, 110.0)
    assert rms(e[:, 3:6]) < 0.3  # velocity m/s
    assert rms(e[:, 6:8]) < 1.0  # horizontal position m
    assert np.degrees(rms(e[:, :2])) < 1.0  # tilt deg
    assert np.degrees(rms(e[:, 2])) < 3.0  # yaw deg
    nees = np.einsum("ki,ki->k", e[:, :9], np.linalg.solve(P[:, :9, :9], e[:, :9, None])[..., 0])
    assert np.mean(nees < 21.67) > 0.8  # 9-dof NEES below its 99 % bound
    assert runners[0].resets == 0
    s = stream.summary
    assert s["gnss_source"] == "vehicle_gps_position" and s["baro_source"] == "sensor_baro"
    assert any(d["what"] == "alignment" and "magnetometer" in d["why"] for d in s["decisions"])


@pytest.mark.parametrize("spec", ["ekf", *SLOW_SPECS])
def test_before_the_first_fix_the_stream_runs_unaided_then_anchors(spec):
    """A flight whose GNSS fix arrives 15 s after the IMU: estimates from 2 s in (attitude
    from the accelerometer and magnetometer, a constant-position hold), velocity and
    position re-anchored at the fix with the attitude and biases kept; positions before
    the fix are not in the frame (``fix_from``). Without ``before_fix`` nothing comes
    before the fix."""
    samples, ts, xs = flight(4, v0=0.0, gnss_from=15.0)
    stream, runners, coll = run_nav(samples, [spec])
    t = coll.arrays(runners[0].label)["t"]
    assert t[0] < 102.5
    assert stream.fix_from is not None and 115.0 <= stream.fix_from < 115.5
    whats = [(d["what"], d["value"]) for d in stream.summary["decisions"]]
    assert ("alignment", "done without a GNSS fix") in whats
    assert ("alignment", "velocity and position from the first fix") in whats
    e0, _ = errors(stream, coll, runners[0].label, ts, xs, 103.0)
    pre = t[t >= 103.0] < 115.0
    # unaided (a 0.57 deg/s gyro bias, unobservable accel bias): bounded, not exact
    assert np.degrees(rms(e0[pre, :2])) < 3.0  # tilt before the fix, deg
    assert rms(e0[pre, 3:6]) < 1.5  # held near rest: velocity m/s
    assert runners[0].resets == 0
    late_opts = NavOptions(integration="hold", before_fix=False)

    def after_fix(run):
        """Tangent errors from 120 s of one ``run_nav`` result."""
        st, ru, co = run
        return errors(st, co, ru[0].label, ts, xs, 120.0)[0]

    late, lr, lc = run_nav(samples, [spec], late_opts)
    # after the fix at least as good as a stream that starts there (what it learnt kept)
    e, el = after_fix((stream, runners, coll)), after_fix((late, lr, lc))
    assert rms(e[:, 3:6]) < 0.3 and rms(e[:, 6:8]) < 1.0
    assert lc.arrays(lr[0].label)["t"][0] >= 115.0 and late.fix_from is None
    # the hybrid's draws alone move one run's yaw RMSE by +-10 % (seeds 0-3: the ratio
    # early / late 0.93-1.12): it is compared over three filter seeds
    errs, lates = [e], [el]
    for seed in (1, 2) if spec == "hybrid" else ():
        errs.append(after_fix(run_nav(samples, [spec], seed=seed)))
        lates.append(after_fix(run_nav(samples, [spec], late_opts, seed=seed)))
    for sl in (slice(0, 2), slice(2, 3)):  # tilt, yaw
        a = np.mean([rms(x[:, sl]) for x in errs])
        b = np.mean([rms(x[:, sl]) for x in lates])
        assert a < 1.1 * b, (sl, a, b)


def test_without_magnetometer_yaw_comes_from_the_gnss_course():
    samples, ts, xs = flight(2, mag=False)
    stream, runners, coll = run_nav(samples)
    al = [d for d in stream.summary["decisions"] if d["what"] == "alignment"]
    assert al and "GNSS course" in al[0]["why"]
    e, _ = errors(stream, coll, runners[0].label, ts, xs, 115.0)
    assert np.degrees(rms(e[:, 2])) < 3.0  # yaw resolved by GNSS velocity in the turn
    assert rms(e[:, 3:6]) < 0.3


def test_no_course_while_slow_and_no_magnetometer_means_no_start():
    samples, _, _ = flight(2, T=6.0, mag=False, v0=0.5)
    with pytest.raises(NoSamplesError, match="course"):
        run_nav(samples)


@pytest.mark.slow
def test_gnss_delay_compensated():
    samples, ts, xs = flight(3, delay=0.2)
    s0, r0, c0 = run_nav(samples)
    s1, r1, c1 = run_nav(samples, opts=NavOptions(integration="hold", gnss_delay=0.2))
    e0, _ = errors(s0, c0, r0[0].label, ts, xs, 110.0)
    e1, _ = errors(s1, c1, r1[0].label, ts, xs, 110.0)
    assert rms(e1[:, 6:8]) < 0.6 * rms(e0[:, 6:8])  # a 0.2 s lag at 6 m/s is 1.2 m


@pytest.mark.slow
def test_an_unknown_gnss_delay_widens_the_velocity_so_a_late_receiver_is_not_gated(
        monkeypatch):
    """Until the GNSS delay is known, a fix's velocity std gains UNKNOWN_GNSS_LAG_S times
    the vehicle's acceleration: the velocity of a receiver 0.4 s late in a manoeuvre is
    taken, not gated away, and the velocity is better for it; with the delay given
    nothing is added."""
    samples, ts, xs = flight(3, delay=0.4, heave=1.5)
    s1, r1, c1 = run_nav(samples)
    given = NavOptions(integration="hold", gnss_delay=0.4)
    g1 = run_nav(samples, opts=given)[2].arrays(r1[0].label)
    monkeypatch.setattr(navigation, "UNKNOWN_GNSS_LAG_S", 0.0)
    s0, r0, c0 = run_nav(samples)
    g0 = run_nav(samples, opts=given)[2].arrays(r0[0].label)
    rej0, rej1 = r0[0].gates["gnss_vel"]["rejected"], r1[0].gates["gnss_vel"]["rejected"]
    assert rej0 >= 10 and rej1 <= 3, (rej0, rej1)
    e0, _ = errors(s0, c0, r0[0].label, ts, xs, 105.0)
    e1, _ = errors(s1, c1, r1[0].label, ts, xs, 105.0)
    assert rms(e1[:, 3:6]) < 0.9 * rms(e0[:, 3:6])
    np.testing.assert_array_equal(g0["x"], g1["x"])  # the delay given: the term is off


def test_the_unknown_delay_widening_takes_bad_fixes_in_its_stride():
    """The widening's acceleration: from consecutive fixes' velocities, NaN axes as none,
    capped at 2 g, none across a gap or when time goes backwards, none once the delay is
    known (NavStream._timing_sd)."""
    st = NavStream(opts=NavOptions(integration="hold"))
    lag, cap = navigation.UNKNOWN_GNSS_LAG_S, navigation.LAG_ACCEL_MAX

    def fix(t, v):
        g = GnssSample(t, np.array([47.4, 8.5, 430.0]), np.array(v, float), 3, 0.5, 1.0,
                       0.1, 0.8, 1.2, 12, "vehicle_gps_position")
        return _Aid(t, "gnss", g, np.zeros(3))

    assert st._timing_sd(fix(10.0, [1.0, 0.0, 0.0])) is None  # no fix before it
    np.testing.assert_allclose(st._timing_sd(fix(10.2, [1.4, -0.2, np.nan])),
                               [lag * 2.0, lag * 1.0, 0.0])
    np.testing.assert_allclose(st._timing_sd(fix(10.4, [101.4, 0.0, 0.0])),
                               [lag * cap, lag * 1.0, 0.0])
    assert st._timing_sd(fix(10.3, [1.0, 0.0, 0.0])) is None  # time went backwards
    assert st._timing_sd(fix(12.0, [3.0, 0.0, 0.0])) is None  # 1.7 s apart
    st.delay_known = True
    assert st._timing_sd(fix(12.2, [9.0, 0.0, 0.0])) is None


@pytest.mark.slow
def test_baro_delay_compensated():
    samples, ts, xs = flight(3, heave=1.5, baro_delay=0.3)  # climbs at up to 3 m/s: 0.9 m
    s0, r0, c0 = run_nav(samples)
    s1, r1, c1 = run_nav(samples, opts=NavOptions(integration="hold", baro_delay=0.3))
    e0, _ = errors(s0, c0, r0[0].label, ts, xs, 110.0)
    e1, _ = errors(s1, c1, r1[0].label, ts, xs, 110.0)
    assert rms(e1[:, 8]) < 0.6 * rms(e0[:, 8])
    assert s1.summary["baro_delay_s"] == 0.3
    assert any(d["what"] == "baro delay" and "option" in d["why"]
               for d in s1.summary["decisions"])
    with pytest.raises(InputError):
        NavOptions(baro_delay=-0.1)


@pytest.mark.slow
def test_bad_aiding_is_gated_and_counted_never_a_reset_storm():
    samples, ts, xs = flight(4, vd=-1.0)  # climbing at 1 m/s
    stuck = None
    fr = LocalFrame(*ORIGIN)
    bad = []
    for s in samples:
        if isinstance(s, GnssSample) and 120.0 <= s.t < 124.0:  # a 100 m jump north
            p = np.array(fr.geodetic_to_ned(*s.lat_lon_alt)) + [100.0, 0.0, 0.0]
            s = GnssSample(s.t, np.array([float(c) for c in fr.ned_to_geodetic(p)]),
                           s.vel_ned, 3, 0.5, 1.0, 0.1, 0.8, 1.2, 12, s.source)
        elif isinstance(s, GnssSample) and 126.0 <= s.t < 128.0:  # NaN fields
            s = GnssSample(s.t, np.array([np.nan, np.nan, np.nan]), s.vel_ned * np.nan, 3,
                           np.nan, np.nan, np.nan, np.nan, np.nan, 12, s.source)
        elif isinstance(s, GnssSample) and 130.0 <= s.t < 133.0:  # the fix drops to 2-D
            s = GnssSample(s.t, s.lat_lon_alt, s.vel_ned, 2, 5.0, 10.0, 0.5, 3.0, 5.0, 4,
                           s.source)
        elif isinstance(s, BaroSample) and s.t >= 115.0:  # the baro sticks in the climb
            stuck = s.alt if stuck is None else stuck
            s = BaroSample(s.t, np.nan, 20.0, stuck, s.source)
        bad.append(s)
    stream, runners, coll = run_nav(bad, ["ekf", "ukf"])
    aid = stream.summary["aiding"]
    assert aid["gnss"]["nan"] == 10 and aid["gnss"]["fix_2d"] == 15
    for r in runners:
        assert r.resets == 0
        assert r.gates["gnss_pos"]["rejected"] >= 18  # the 20 jumped fixes, <= 2 taken
        # the stuck baro: 25 s x 10 Hz, rejected once its error outgrows the gate, and
        # re-anchored at most once per REANCHOR_S
        assert r.gates["baro"]["rejected"] >= 150 and r.gates["baro"]["reanchored"] <= 3
        e, _ = errors(stream, coll, r.label, ts, xs, 110.0)
        assert rms(e[:, 6:8]) < 2.0 and rms(e[:, 3:6]) < 0.5


@pytest.mark.parametrize("spec", ["ekf", *SLOW_SPECS])
def test_a_filter_locked_out_of_the_gnss_velocity_resets_and_comes_back(spec, monkeypatch):
    """A 4 m/s^2 accelerometer fault for 10 s drives the velocity off faster than any
    state explains: the GNSS velocity is rejected at the gate. Once rejected for
    LOCKOUT_S the filter resets (counted, with a reason) from its estimate widened and
    comes back to the GNSS; without it (one update on the gate per REANCHOR_S) the
    velocity error grew to 37 m/s by the end of this flight and never came back."""
    samples, ts, xs = flight(3, mag=False)
    bad = [ImuSample(s.t, s.gyro, s.accel + [4.0, 0.0, 0.0], s.source)
           if isinstance(s, ImuSample) and 115.0 <= s.t < 125.0 else s for s in samples]
    stream, runners, coll = run_nav(bad, [spec])
    r = runners[0]
    assert 1 <= r.resets <= 3 and r.gates["gnss_vel"]["reset"] == r.resets, r.gates
    why = [rec.reason for rec in coll.records[r.label] if rec.reset]
    assert len(why) == r.resets and all("gnss_vel rejected for" in w for w in why), why
    # the runner's log of them (the replay's "resets_why", its "filter resets:" line)
    assert r.reset_log == [(rec.t, rec.reason) for rec in coll.records[r.label]
                           if rec.reset]
    e, _ = errors(stream, coll, r.label, ts, xs, 132.0)
    assert rms(e[:, 3:6]) < 0.5, rms(e[:, 3:6])
    # the same flight without the reset: the GNSS velocity stays locked out
    monkeypatch.setattr(navigation, "LOCKOUT_SENSORS", frozenset())
    stream, runners, coll = run_nav(bad, [spec])
    assert runners[0].resets == 0 and runners[0].gates["gnss_vel"]["reset"] == 0
    e, _ = errors(stream, coll, runners[0].label, ts, xs, 132.0)
    assert rms(e[:, 3:6]) > 10.0


def test_a_receiver_whose_velocity_stays_wrong_is_no_reset_storm():
    """GNSS velocities 5 m/s off from 115 s to the end (80 s of flight): a lock-out
    reset 5 s into it, the filter then follows the receiver (its positions rejected and
    re-anchored): no second within 15 s."""
    samples, _, _ = flight(3, mag=False, T=80.0)
    bad = [replace(s, vel_ned=s.vel_ned + [5.0, 0.0, 0.0])
           if isinstance(s, GnssSample) and s.t >= 115.0 else s for s in samples]
    stream, runners, coll = run_nav(bad, ["ekf"])
    r = runners[0]
    t = [rec.t for rec in coll.records[r.label] if rec.reset]
    assert 1 <= r.resets <= 2 and len(t) == r.resets == r.gates["gnss_vel"]["reset"], t
    assert 119.0 <= t[0] <= 122.0 and bool(np.all(np.diff(t) >= 15.0)), t


def test_lockout_resets_of_a_sensor_that_stays_rejected_back_off():
    """A filter whose GNSS velocity is never accepted (each update's NIS 1e6): the first
    two lock-out resets 5 s apart, then 10, 20 and 40 s (the wait doubles for each reset
    in the last LOCKOUT_MEMORY_S but the first); the other sensors only re-anchor."""
    from uavest.core.gaussian import Gaussian
    from uavest.core.states import Innovation

    class Never:
        def update(self, s, z, m, rng):
            return s, Innovation(np.array([3.0, 0.0, 0.0]), np.eye(3), 1e6)

        def estimate(self, s):
            return Gaussian(np.r_[1.0, np.zeros(15)], np.eye(15))

        def init(self, prior, space, rng):
            return "restarted"

    r = NavRunner("never", Never(), np.random.default_rng(0), guard=False)
    m = SimpleNamespace(R=np.eye(3))
    before = r.snapshot()
    resets, anchors = [], []
    for k in range(int(160 / 0.2)):
        t = 100.0 + k * 0.2
        n = r.gates.get("gnss_vel", {}).get("reset", 0)
        a = r.gates.get("baro", {}).get("reanchored", 0)
        r._gated_update("state", np.zeros(3), m, "gnss_vel", t)
        r._gated_update("state", np.zeros(1), m, "baro", t)
        if r.gates["gnss_vel"]["reset"] > n:
            resets.append(round(t - 100.0, 1))
        if r.gates["baro"]["reanchored"] > a:
            anchors.append(round(t - 100.0, 1))
    assert np.allclose(np.diff(resets), [5.2, 10.2, 20.2, 40.2]), resets
    assert r.gates["baro"]["reset"] == 0 and len(anchors) >= 10, anchors
    assert "gnss_vel rejected for" in r._reset_why
    # a lane's history rewinding to before them takes them back, counts and times
    r.reset_log.append((100.0, "x"))
    r.restore(before)
    assert r.reset_log == [] and r.gates == {} and r._lockouts == {}


def test_bad_noise_option_is_one_line():
    with pytest.raises(InputError, match="not a parameter"):
        NavOptions(noise={"accel_deweight": 1.0})
    with pytest.raises(InputError, match="gnss-delay"):
        NavOptions(gnss_delay=-1.0)


def test_a_re_alignment_keeps_the_imu_biases_and_the_magnetic_reference_states():
    """An IMU gap re-aligns at the next fix (attitude, velocity and position from it); the
    running gyro and accelerometer biases and the magnetic reference's errors are kept,
    whatever other states the state has (here the GNSS bias states too: 20 dimensions)."""
    samples, ts, xs = flight(4, T=40.0)
    samples = [s for s in samples if not (isinstance(s, ImuSample) and 120.0 < s.t < 122.0)]
    noise = {"gnss_bias_h": 0.5, "gnss_bias_v": 1.0, "gnss_bias_tau": 30.0,
             "mag_ref_inc": 0.02, "mag_ref_dec": 0.02}
    stream, runners, coll = run_nav(samples, opts=NavOptions(integration="hold", noise=noise))
    assert stream.space == NavSpace(extra=3, mag=2)
    assert any(d["what"] == "alignment" and d["value"] == "re-aligned"
               for d in stream.summary["decisions"])
    a = coll.arrays(runners[0].label)
    t, x = a["t"], a["x"]
    before, after = np.flatnonzero(t < 120.0)[-1], np.flatnonzero(t > 122.0)[0]
    assert x.shape[1] == 21 and np.all(np.isfinite(x))
    assert np.abs(x[before, 10:13]).max() > 3e-3  # the gyro bias learnt (truth 0.01 rad/s)
    np.testing.assert_allclose(x[after, 10:13], x[before, 10:13], atol=2e-3)
    # the accelerometer bias moves with the new start's tilt in the step after it
    assert np.abs(x[before, 13:16]).max() > 0.05
    np.testing.assert_allclose(x[after, 13:16], x[before, 13:16], atol=0.02)
    np.testing.assert_allclose(x[after, 19:21], x[before, 19:21], atol=1e-3)


def test_a_re_alignment_keeps_the_gyro_drift_states_and_reports_them():
    """With the gyro drift states between the GNSS bias and magnetic reference states (24
    components), a re-alignment after an IMU gap keeps the drift's estimate as it keeps
    the biases', the magnetic reference's errors stay at their places, and the stream
    reports the rate each filter learnt (JSON ``gyro_drift``, the printed line)."""
    from uavest.apps.replay import gyro_drift_line

    samples, ts, xs = flight(4, T=40.0)
    samples = [s for s in samples if not (isinstance(s, ImuSample) and 120.0 < s.t < 122.0)]
    noise = {"gnss_bias_h": 0.5, "gnss_bias_v": 1.0, "gnss_bias_tau": 30.0,
             "mag_ref_inc": 0.02, "mag_ref_dec": 0.02, "gyro_drift_walk": 1e-5,
             "init_gyro_drift": 1e-4}
    stream, runners, coll = run_nav(samples, opts=NavOptions(integration="hold", noise=noise))
    assert stream.space == NavSpace(extra=3, mag=2, drift=3)
    assert any(d["what"] == "gyro drift states" for d in stream.summary["decisions"])
    a = coll.arrays(runners[0].label)
    t, x = a["t"], a["x"]
    before, after = np.flatnonzero(t < 120.0)[-1], np.flatnonzero(t > 122.0)[0]
    assert x.shape[1] == 24 and np.all(np.isfinite(x))
    # the drift learnt (1e-5 rad/s^2 or more on an axis; none in this flight's truth)
    # is kept: one step after the new start it has moved by less than a tenth of that
    assert np.abs(x[before, 19:22]).max() > 1e-5
    np.testing.assert_allclose(x[after, 19:22], x[before, 19:22], atol=2e-6)
    np.testing.assert_allclose(x[after, 22:24], x[before, 22:24], atol=1e-3)
    np.testing.assert_allclose(x[after, 10:13], x[before, 10:13], atol=2e-3)
    got = stream.gyro_drift_learnt(runners[0])
    k = np.degrees(60.0)
    np.testing.assert_allclose(got["deg_s_per_min"], x[-1, 19:22] * k)
    assert len(got["sd_deg_s_per_min"]) == 3 and all(v > 0 for v in got["sd_deg_s_per_min"])
    line = gyro_drift_line({"ekf": {"gyro_drift": got}, "ukf": {}})
    assert line.startswith("gyro drift learnt") and "ekf" in line and "ukf" not in line
    assert gyro_drift_line({"ekf": {}}) is None


def test_gnss_bias_states_inserted_mid_run_keep_the_later_states_in_place():
    """A live run sizes the GNSS bias states mid-run (``add_gnss_bias``): they go after
    the 16 components, and the gyro drift and magnetic reference states that follow keep
    their estimates and covariances (cross terms with the 15 too), at their slices of
    the larger space."""
    from uavest.core import Gaussian
    from uavest.engine.nav_align import add_gnss_bias
    from uavest.models.navigation import NavNoise, nav_space

    rng = np.random.default_rng(3)
    small = NavSpace(mag=2, drift=3)
    x = np.concatenate([[1.0, 0.0, 0.0, 0.0], rng.normal(size=small.size - 4)])
    A = rng.normal(size=(small.dim, small.dim))
    P = A @ A.T + np.eye(small.dim)
    noise = NavNoise(gnss_bias_h=0.8, gnss_bias_v=1.5, gnss_bias_tau=60.0,
                     gyro_drift_walk=1e-6, mag_ref_inc=0.01)
    big = nav_space(noise)
    assert big == NavSpace(extra=3, mag=2, drift=3)
    g = add_gnss_bias(Gaussian(x, P), noise)
    assert g.x.shape == (big.size,) and g.P.shape == (big.dim, big.dim)
    np.testing.assert_array_equal(g.x[:16], x[:16])
    np.testing.assert_array_equal(g.x[16:19], 0.0)
    np.testing.assert_array_equal(g.x[big.drift_slice], x[small.drift_slice])
    np.testing.assert_array_equal(g.x[big.mag_slice], x[small.mag_slice])
    t_small = np.r_[np.arange(15, small.dim)]  # the drift's and the field's, tangent
    t_big = np.r_[np.arange(18, big.dim)]
    np.testing.assert_array_equal(g.P[np.ix_(t_big, t_big)], P[np.ix_(t_small, t_small)])
    np.testing.assert_array_equal(g.P[np.ix_(t_big, np.arange(15))],
                                  P[np.ix_(t_small, np.arange(15))])
    assert np.all(np.linalg.eigvalsh(g.P) > 0)


def test_gyro_bias_trend_tells_a_ramp_from_a_random_walk():
    """:func:`gyro_bias_trend` on seeded series: a ramp of 0.05 deg/s per minute under the
    estimate's noise is found on every axis with its slope; a random walk (the same
    size of change) is not a ramp; a ramp on two axes only is not; too short: None."""
    from uavest.eval.navigation import gyro_bias_trend

    rng = np.random.default_rng(5)
    t = np.arange(0.0, 150.0, 0.04)
    rate = np.radians(0.05) / 60.0  # rad/s^2
    sd = np.full((len(t), 3), 1e-4)
    ramp = np.outer(t, [rate] * 3) + rng.normal(size=(len(t), 3)) * 1e-4
    got = gyro_bias_trend(t, ramp, sd)
    assert got["ramps"] and np.allclose(got["deg_s_per_min"], 0.05, rtol=0.05), got
    walk = np.cumsum(rng.normal(size=(len(t), 3)), axis=0) * 1.2e-5
    assert not gyro_bias_trend(t, walk, sd)["ramps"]
    two = ramp.copy()
    two[:, 2] = rng.normal(size=len(t)) * 1e-4
    assert not gyro_bias_trend(t, two, sd)["ramps"]
    assert gyro_bias_trend(t[:100], ramp[:100], sd[:100]) is None  # 4 s


def test_a_held_magnetometer_reading_is_used_once():
    """The same field repeated in every IMU message (a MAVLink RAW_IMU's compass value,
    held between readings) is one measurement: each distinct reading updates once and
    the repeats are counted as held; the estimate is the run's with only the readings
    (the field's inclination given: estimated at the start it sees the repeats too)."""
    samples, _, _ = flight(4, T=20.0)
    held, last = [], None
    for s in samples:
        if isinstance(s, MagSample):
            last = s.field
        held.append(s)
        if isinstance(s, ImuSample) and last is not None:  # repeated at the IMU's rate
            held.append(MagSample(s.t, last.copy(), s.source))
    runs = []
    opts = NavOptions(integration="hold", mag_inclination=np.deg2rad(63.0))
    for smp in (samples, held):
        stream, runners, coll = run_nav(smp, opts=opts)
        runs.append((stream, coll.arrays("ekf")))
    (s0, a0), (s1, a1) = runs
    n_new = sum(isinstance(s, MagSample) for s in samples)
    assert s1.aiding["mag"]["held"] > 5 * n_new
    assert s1.aiding["mag"]["used"] == s0.aiding["mag"]["used"]
    np.testing.assert_allclose(a1["x"], a0["x"], atol=1e-9)


def _geo_params() -> LogParams:
    p = LogParams()
    p.set_geo(*ORIGIN, 1767225600.0)  # 2026-01-01
    return p


def test_the_start_takes_the_magnetic_models_inclination_over_the_accelerometers():
    """The alignment window's angle between accelerometer and magnetometer is off by the
    level's error (here a hover with the accel bias and noise: 0.3-1 deg); where the field is
    the World Magnetic Model's, the model's inclination is taken, and the tilt after the
    start is better than the same run's with the window's angle (no position known)."""
    params = _geo_params()
    wmm, _ = inclination_from_params(params)
    assert wmm is not None
    samples, ts, xs = flight(2, T=20.0, v0=0.0, incl=wmm, ba=(0.06, -0.03, 0.05))
    got = {}
    for name, prm in (("model", params), ("window", None)):
        stream, _, coll = run_nav(samples, params=prm)
        err, _ = errors(stream, coll, "ekf", ts, xs, 105.0)
        got[name] = (stream.summary["inclination_rad"], rms(err[:, :2]))
    assert got["model"][0] == pytest.approx(wmm, abs=1e-9)
    assert abs(got["window"][0] - wmm) > np.deg2rad(0.1)
    assert got["model"][1] < 0.8 * got["window"][1]


def test_a_field_far_from_the_magnetic_model_keeps_the_accelerometers_inclination():
    """A local field 3 deg from the model's inclination (an anomaly, a simulator's own
    table) is measured at the start, not replaced by the model."""
    params = _geo_params()
    wmm, _ = inclination_from_params(params)
    samples, _, _ = flight(2, T=4.0, incl=wmm + np.deg2rad(3.0))
    stream, _, _ = run_nav(samples, params=params)
    assert abs(stream.summary["inclination_rad"] - wmm) > np.deg2rad(1.0)
    assert "accelerometer" in next(d["why"] for d in stream.decisions
                                   if d["what"] == "inclination")


def _late_declination(samples, params: dict, t_dec: float, dec: float):
    """``samples`` with the declination ``dec`` (rad) put into ``params`` at ``t_dec`` s
    (a ground station that fetched COMPASS_DEC only then)."""
    for s in samples:
        if s.t >= t_dec and "COMPASS_DEC" not in params:
            params.update(COMPASS_DEC=dec, COMPASS_AUTODEC=0)
        yield s


@pytest.mark.parametrize("spec", ["ekf", *SLOW_SPECS])
def test_a_declination_learnt_at_rest_turns_the_yaw_with_it(spec, monkeypatch):
    """A hover whose declination (2 deg, the field's) comes 10 s after the start: the yaw
    so far is the magnetometer's at 0, so the stream restarts every filter with its yaw
    turned by 2 deg, and the yaw error after it is as if the declination had been known
    from the start (EKF, UKF: within 0.05 deg); without the turn the filters take the
    change in through their mag updates and gyro bias, and are further off (EKF 0.63 deg
    RMSE over the next 15 s against 0.42)."""
    samples, ts, xs = flight(3, T=25.0, v0=0.0)
    dec = np.deg2rad(2.0)
    got = {}
    for how in ("known", "turned", "not turned"):
        if how == "not turned":  # the restart keeps the yaw (the stream before the turn)
            monkeypatch.setattr(attitude, "turn_yaw", lambda g, angle: g)
        params: dict = ({"COMPASS_DEC": dec, "COMPASS_AUTODEC": 0} if how == "known"
                        else {})
        src = samples if how == "known" else _late_declination(samples, params, 110.0, dec)
        stream, runners, coll = run_nav(src, [spec], params=params)
        e, _ = errors(stream, coll, runners[0].label, ts, xs, 110.5)
        got[how] = np.degrees(rms(e[:, 2]))
        assert runners[0].resets == 0
        if how != "known":
            d = [d for d in stream.decisions if d["what"] == "declination"]
            assert [x["value"] for x in d] == ["0.00 deg", "2.00 deg"]
            assert "the yaw turned by +2.00 deg" in d[1]["why"]
    assert got["turned"] < 0.75 * got["not turned"], got
    if spec != "hybrid":  # (the hybrid's restart redraws its members: another stream)
        assert got["turned"] == pytest.approx(got["known"], abs=0.05), got


def test_a_declination_learnt_in_flight_does_not_turn_the_yaw():
    """Once a fix has shown the vehicle moving (``yaw_speed``), the GNSS has had a say in
    the yaw: a declination learnt then changes the magnetic reference only."""
    samples, ts, xs = flight(3, T=16.0, v0=6.0)
    params: dict = {}
    stream, runners, coll = run_nav(_late_declination(samples, params, 110.0, 0.03),
                                    params=params)
    d = [d for d in stream.decisions if d["what"] == "declination"]
    assert len(d) == 2 and "turned" not in d[1]["why"]
    assert stream.declination == pytest.approx(0.03)


def test_turn_yaw_turns_the_attitude_about_down_only():
    """``turn_yaw``: yaw + angle, roll and pitch, velocity, position, biases and the
    covariance (the body-frame tangent) as they were."""
    from uavest.core.gaussian import Gaussian
    from uavest.engine.attitude import turn_yaw
    from uavest.geometry.rotation import quat_to_euler

    rng = np.random.default_rng(4)
    x = np.concatenate([euler_to_quat(0.1, -0.2, 0.3), rng.normal(size=12)])
    A = rng.normal(size=(15, 15))
    g = Gaussian(x, A @ A.T)
    out = turn_yaw(g, np.deg2rad(5.0))
    np.testing.assert_allclose(quat_to_euler(out.x[:4]), [0.1, -0.2, 0.3 + np.deg2rad(5.0)],
                               atol=1e-12)
    np.testing.assert_array_equal(out.x[4:], x[4:])
    np.testing.assert_array_equal(out.P, g.P)


@pytest.mark.parametrize("site_km, taken", [(0.0, True), (10.0, True), (100.0, False)])
def test_a_given_inclination_is_taken_only_near_where_it_was_learned(site_km, taken):
    """``--aiding-from``'s inclination (NavOptions.mag_inclination with mag_site): the
    start takes it within MAG_SITE_KM of where it was learned; from farther (another
    site's field) it takes its own (the accelerometer-magnetometer angle) and says why."""
    from uavest.engine.nav_align import MAG_SITE_KM
    from uavest.geometry.geodesy import geodetic_to_ned

    samples, _, _ = flight(1, T=12.0)
    given = np.deg2rad(61.5)  # the flight's field is at 63 deg
    site = (ORIGIN[0] + site_km / 111.2, ORIGIN[1])
    ne = geodetic_to_ned(np.array([*site, ORIGIN[2]]), np.array(ORIGIN))[:2]
    assert abs(np.hypot(*ne) / 1e3 - site_km) < 0.5
    opts = NavOptions(integration="hold", mag_inclination=given, mag_site=site,
                      mag_inclination_why="from --aiding-from: x.json")
    stream, runners, coll = run_nav(samples, opts=opts)
    inc = stream.summary["inclination_rad"]
    said = [d for d in stream.summary["decisions"] if d["what"] == "inclination given"]
    if taken:
        assert inc == given and not said
    else:
        assert abs(inc - given) > np.deg2rad(1.0), np.degrees(inc)
        assert said and said[0]["value"] == "not taken", said
        assert f"more than {MAG_SITE_KM:g} km" in said[0]["why"], said
    assert len(coll.arrays(runners[0].label)["t"]) > 100


@pytest.mark.parametrize("factor", [1, 3, 8])
def test_step_specific_force_is_the_time_weighted_trapezoid_mean(factor):
    """The navigation step builder's specific force (snapshot IMU, ``trapezoid``): the
    time-weighted mean of the force linear between samples, from the edge's sample on,
    over irregular sample times (the numpy formula it replaced, to rounding); the plain
    block mean on an integrated IMU."""
    g = np.random.default_rng(factor)
    for integ in ("trapezoid", "hold"):
        nb = navigation._NavBuilder(integ, factor, close_now=True)
        t, seen = 0.0, 0
        for _ in range(40 * factor):
            t += g.uniform(0.002, 0.008)
            s = ImuSample(t, g.normal(size=3), g.normal(0.0, 3.0, 3), "RAW_IMU")
            edge = (nb.t_edge, nb.a_edge)
            block = list(nb.block) + [s]
            for r in nb.push_nav(s):
                if integ == "trapezoid" and edge[1] is not None:
                    ts = np.array([edge[0]] + [b.t for b in block])
                    acc = np.array([edge[1]] + [b.accel for b in block])
                    dt = np.diff(ts)
                    want = (0.5 * (acc[1:] + acc[:-1]) * dt[:, None]).sum(0) / dt.sum()
                else:
                    want = np.mean([b.accel for b in block], axis=0)
                np.testing.assert_allclose(r.a, want, rtol=1e-13, atol=1e-14)
                seen += 1
        assert seen >= 38  # (the first step has no edge sample yet)
