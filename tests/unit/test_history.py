"""Samples on arrival with the engine's bounded history (uavest.engine.history).

The project's own log (logs/sim_200hz.tlog, the first seconds) read in time order is the
"arrived in order" run; moving one sample later in the stream (after IMU samples newer
than it) makes it late. Each run is on arrival with a history: the late one must be
applied at its time, i.e. every estimate made after it arrived equals the in-order run's
(to floating tolerance: the same operations), the estimates made before it arrived do
not (the sample mattered), and a sample older than the history is counted late and
skipped (the estimates equal the run without it)."""

from __future__ import annotations

import dataclasses
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from uavest.apps.live import LiveConfig, TrackLane, _track_runners
from uavest.engine.attitude import AttitudeOptions, AttitudeStream
from uavest.engine.build import build_filters
from uavest.engine.loop import Lane, run_lanes
from uavest.engine.navigation import NavOptions, NavRunner, NavStream
from uavest.engine.runner import FilterRunner
from uavest.ingest import open_source
from uavest.ingest.types import DetectionSample, GnssSample, ImuSample, MagSample, PositionSample
from uavest.presets import resolve_list
from uavest.seeding import filter_stream, rng
from uavest.sinks.base import Collector

LOG = Path(__file__).resolve().parents[2] / "logs" / "sim_200hz.tlog"
SECONDS = 7.0


@pytest.fixture(scope="module")
def log():
    """(samples of the first SECONDS s in time order, as the link releases them on
    arrival: an IMU sample after the magnetometer of its message; the log's params)."""
    src = open_source(LOG)
    out = []
    for s in src:
        if s.t > SECONDS:
            break
        out.append(s)
    out.sort(key=lambda s: (s.t, isinstance(s, ImuSample)))
    return out, dict(src.params)


def _late(samples: list, pick, by: float) -> tuple[list, object, float]:
    """``samples`` with the first sample ``pick`` accepts moved to arrive just after the
    first IMU sample at least ``by`` s newer; returns (stream, the sample, that IMU
    sample's time)."""
    i = next(k for k, s in enumerate(samples) if pick(s))
    s = samples[i]
    rest = samples[:i] + samples[i + 1:]
    j = next(k for k in range(i, len(rest))
             if isinstance(rest[k], ImuSample) and rest[k].t >= s.t + by)
    return rest[:j + 1] + [s] + rest[j + 1:], s, rest[j].t


def _attitude(samples, params, *, nav=False, on_arrival=True, history=0.3,
              labels=("ekf", "hybrid"), late=None):
    specs = build_filters(resolve_list(",".join(labels), "attitude", dim=15 if nav else 6))
    if nav:
        stream = NavStream(opts=NavOptions(on_arrival=on_arrival), params=dict(params))
    else:
        stream = AttitudeStream(opts=AttitudeOptions(on_arrival=on_arrival),
                                params=dict(params))
    cls = NavRunner if nav else FilterRunner
    runners = [cls(sp.label, f, rng(0, 0, filter_stream(sp.label))) for sp, f in specs]
    coll = Collector()
    lane = Lane(stream, runners, history)
    run_lanes(samples, [lane], [coll], None, late)
    return coll, runners, lane


def _check_applied_at_its_time(a, b, t_late: float, t_arrived: float, labels) -> None:
    """``b`` (late run) made the same steps as ``a`` (in order); its estimates after
    ``t_arrived`` equal ``a``'s, and some estimate from ``t_late`` up to then does not."""
    for lab in labels:
        xa, xb = a.arrays(lab), b.arrays(lab)
        np.testing.assert_array_equal(xa["t"], xb["t"])
        after = xa["t"] > t_arrived
        assert after.sum() > 20
        np.testing.assert_allclose(xb["x"][after], xa["x"][after], rtol=0, atol=1e-12,
                                   err_msg=lab)
        before = (xa["t"] >= t_late) & ~after
        d = np.abs(xb["x"][before] - xa["x"][before]).max()
        assert d > 1e-9, (lab, d)  # made before the sample arrived: without it


def test_in_order_on_arrival_equals_the_reorder_window_path(log):
    samples, params = log
    a, _, _ = _attitude(samples, params, on_arrival=False, history=0.0)
    b, _, lane = _attitude(samples, params)
    assert lane.history is not None and lane.history.stats.rewinds == 0
    for lab in ("ekf", "hybrid"):
        xa, xb = a.arrays(lab), b.arrays(lab)
        np.testing.assert_array_equal(xa["t"], xb["t"])
        np.testing.assert_array_equal(xa["x"], xb["x"])


@pytest.mark.parametrize("what,by", [("velocity", 0.1), ("magnetometer", 0.05)])
def test_a_late_aiding_sample_is_applied_at_its_time(log, what, by):
    samples, params = log
    a, ra, _ = _attitude(samples, params)
    if what == "velocity":
        def pick(s):
            return (isinstance(s, PositionSample) and s.source == "GLOBAL_POSITION_INT"
                    and s.t > 3.0)
    else:  # the magnetometer sample at a step's end (a step uses the last one it holds)
        t_end = next(t for t in a.arrays("ekf")["t"] if t > 3.5)

        def pick(s):
            return isinstance(s, MagSample) and s.t == t_end
    stream, s, t_arr = _late(samples, pick, by)
    b, rb, lane = _attitude(stream, params)
    st = lane.history.stats
    assert (st.rewinds, st.late) == (1, 0), st
    assert st.restepped >= 1
    _check_applied_at_its_time(a, b, s.t, t_arr, ("ekf", "hybrid"))
    for x, y in zip(ra, rb, strict=True):  # the running states too (and the generators)
        np.testing.assert_allclose(y.filter.estimate(y.state).x,
                                   x.filter.estimate(x.state).x, rtol=0, atol=1e-12)
        assert x.rng.bit_generator.state == y.rng.bit_generator.state


def test_a_sample_older_than_the_history_is_counted_and_skipped(log):
    samples, params = log
    def pick(s):
        return (isinstance(s, PositionSample) and s.source == "GLOBAL_POSITION_INT"
                and s.t > 3.0)
    stream, s, _ = _late(samples, pick, 0.6)
    seen: list = []
    b, _, lane = _attitude(stream, params, history=0.3, late=seen.append)
    assert seen == [s] and lane.history.stats.late == 1 and lane.history.stats.rewinds == 0
    without = [x for x in samples if x is not s]
    a, _, _ = _attitude(without, params)
    for lab in ("ekf", "hybrid"):
        np.testing.assert_array_equal(a.arrays(lab)["x"], b.arrays(lab)["x"])


def test_a_late_gnss_fix_is_applied_at_its_time_by_the_navigation_lane(log):
    samples, params = log
    a, _, _ = _attitude(samples, params, nav=True, labels=("ekf",))
    # 0.2 s: about the ArduCopter SITL's GPS_RAW_INT lag
    stream, s, t_arr = _late(samples, lambda s: isinstance(s, GnssSample) and s.t > 4.0, 0.2)
    b, _, lane = _attitude(stream, params, nav=True, labels=("ekf",))
    assert lane.history.stats.rewinds == 1
    _check_applied_at_its_time(a, b, s.t, t_arr, ("ekf",))


def _tracks(samples, params, history):
    cfg = LiveConfig(radar_source="obstacle", trackers=("ekf",))
    lane = TrackLane(cfg, 0)
    from uavest.apps.live import TRACKER_DIM

    tspecs = build_filters(resolve_list("ekf", "radar", dim=TRACKER_DIM))
    runners = _track_runners(cfg, lane, tspecs)
    coll = Collector()
    ln = Lane(lane, runners, history)
    run_lanes(samples, [ln], [coll])
    return coll.records["track:ekf"], ln


def test_a_late_detection_of_a_sweep_restarts_the_trackers_before_its_scan(log):
    samples, params = log
    a, _ = _tracks(samples, params, 0.3)
    stream, s, t_arr = _late(samples, lambda s: isinstance(s, DetectionSample) and s.t >= 3.0,
                             0.02)  # after the scan of its sweep was made
    b, ln = _tracks(stream, params, 0.3)
    assert ln.history.stats.rewinds == 1
    assert [r.t for r in a] == [r.t for r in b]
    changed = 0
    for ra, rb in zip(a, b, strict=True):
        same = [t.id for t in ra.tracks] == [t.id for t in rb.tracks] and all(
            np.allclose(x.x, y.x, rtol=0, atol=1e-12)
            for x, y in zip(ra.tracks, rb.tracks, strict=True))
        if ra.t > t_arr:
            assert same, ra.t
        elif ra.t >= s.t:
            changed += not same
    assert changed >= 1  # the scan made before the detection arrived missed it


# ------------------------------------------------------------------ snapshot fidelity

_SHARED = {"samples", "opts", "params", "space", "cfg", "model", "motion", "make"}


def _canon(v, seen=None):
    """A comparable picture of ``v``'s state (containers, arrays, generators, our own
    objects' attributes, recursively; shared objects by identity)."""
    seen = set() if seen is None else seen
    if isinstance(v, float):
        return ("f", repr(v))
    if isinstance(v, np.ndarray):
        return ("a", v.shape, v.tobytes())
    if isinstance(v, np.random.Generator):
        return ("rng", repr(v.bit_generator.state))
    if isinstance(v, list | tuple | deque):
        return (type(v).__name__, [_canon(x, seen) for x in v])
    if isinstance(v, dict):
        return ("d", [(repr(k), _canon(x, seen)) for k, x in v.items()])
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return (type(v).__name__, [(f.name, _canon(getattr(v, f.name), seen))
                                   for f in dataclasses.fields(v)])
    if type(v).__module__.startswith("uavest.") and hasattr(v, "__dict__") \
            and id(v) not in seen:
        seen.add(id(v))
        return (type(v).__name__, [(k, _canon(x, seen)) for k, x in vars(v).items()
                                   if k not in _SHARED])
    return ("o", type(v).__name__, id(v) if hasattr(v, "__dict__") else repr(v))


@pytest.mark.parametrize("kind", ["attitude", "nav", "nav_waiting", "obstacle", "adsb"])
def test_a_builder_restored_is_what_it_was(log, kind):
    samples, params = log
    if kind == "attitude":
        b = AttitudeStream(opts=AttitudeOptions(on_arrival=True), params=dict(params))
    elif kind == "nav":
        b = NavStream(opts=NavOptions(on_arrival=True), params=dict(params))
    elif kind == "nav_waiting":  # no fix ever: the alignment window moves with every step
        samples = [s for s in samples if not isinstance(s, GnssSample)]
        b = NavStream(opts=NavOptions(on_arrival=True, before_fix=False), params=dict(params))
    else:  # the tracking lane on the vehicle's detections or the virtual radar
        b = TrackLane(LiveConfig(radar_source=kind), 0)
    # the parts a stream owns (moved out of it): each must change and be restored too
    parts = {"nav": ("_aids",), "nav_waiting": ("_aids", "_align")}.get(kind, ())
    n = len(samples)
    for s in samples[: n // 2]:
        b.push(s)
    snap = b.snapshot()
    before = _canon(b)
    part_before = {a: _canon(getattr(b, a)) for a in parts}
    for _ in range(2):  # a snapshot can be restored more than once
        for s in samples[n // 2: 3 * n // 4]:
            b.push(s)
        assert _canon(b) != before
        for a in parts:
            assert _canon(getattr(b, a)) != part_before[a], a
        b.restore(snap)
        assert _canon(b) == before
        for a in parts:
            assert _canon(getattr(b, a)) == part_before[a], a

