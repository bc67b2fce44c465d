"""Issue: decisions made from "the start of the log". The declination is taken when the
log gives it (a parameter that arrives after the alignment), the decision is recorded with
the time it took effect, and the mean of the magnetometer reference follows."""

from __future__ import annotations

import numpy as np

from uavest.engine.attitude import AttitudeOptions, AttitudeStream
from uavest.engine.records import Step
from uavest.ingest.types import ImuSample, MagSample


def _samples(T: float = 10.0, rate: float = 50.0):
    g = np.array([0.0, 0.0, -9.80665])  # level, at rest: specific force up (FRD: -z)
    field = np.array([0.2, 0.0, 0.4])
    for k in range(int(T * rate)):
        t = k / rate
        yield ImuSample(t, np.zeros(3), g.copy(), "RAW_IMU")
        yield MagSample(t, field.copy(), "RAW_IMU")


def test_declination_arriving_after_the_alignment_is_taken_then():
    params: dict = {}
    st = AttitudeStream(opts=AttitudeOptions(), params=params)
    steps = []
    for s in _samples():
        if s.t >= 5.0 and "COMPASS_DEC" not in params:
            params.update(COMPASS_DEC=0.2, COMPASS_AUTODEC=0)  # the GCS fetched them now
        steps += [x for x in st.push(s) if isinstance(x, Step)]
    st.flush()
    dec = [d for d in st.decisions if d["what"] == "declination"]
    assert len(dec) == 2, st.decisions
    assert dec[0]["t"] == 0.0 and dec[0]["why"].startswith("none")
    assert 5.0 <= dec[1]["t"] < 5.2 and "COMPASS_DEC" in dec[1]["why"]
    assert st.declination == 0.2 and st.summary["declination_rad"] == 0.2
    assert abs(st.summary["declination_from_t"] - dec[1]["t"]) < 1e-9
    whats = [d["what"] for d in st.decisions]
    for w in ("IMU", "integration", "acceleration compensation", "alignment"):
        assert w in whats


def test_declination_known_at_the_start_is_not_changed():
    params = {"COMPASS_DEC": 0.1, "COMPASS_AUTODEC": 0}
    st = AttitudeStream(opts=AttitudeOptions(), params=params)
    for s in _samples(6.0):
        st.push(s)
        if s.t >= 4.0:  # after the alignment: the value the stream took stays
            params["COMPASS_DEC"] = 0.3
    st.flush()
    assert [d["t"] for d in st.decisions if d["what"] == "declination"] == [0.0]
    assert st.declination == 0.1


def test_the_magnetic_models_declination_gives_way_to_the_vehicles_own():
    """An autopilot with automatic declination boots with COMPASS_DEC 0 and sets it after
    its GPS lock, some seconds after a ground station has taken the magnetic model's at
    the first fix (a live ArduCopter SITL: 3.66 deg from the model at 10 s, its own 3.19
    at 44 s): the stream takes the vehicle's own when it comes, as a replay of its log
    does, with a decision line; the model's value is not said again while it waits, and
    the vehicle's own is final."""
    from uavest.ingest.types import LogParams

    params = LogParams(COMPASS_DEC=0.0, COMPASS_AUTODEC=1)
    st = AttitudeStream(opts=AttitudeOptions(), params=params)
    for s in _samples():
        if s.t >= 3.0 and params.geo is None:
            params.geo = {"lat": 47.3977, "lon": 8.5456, "alt": 408.0, "utc": 1.79e9}
        if s.t >= 6.0 and params["COMPASS_DEC"] == 0.0:
            params["COMPASS_DEC"] = 0.0556
        if s.t >= 8.0:
            params["COMPASS_DEC"] = 0.0  # (no later value replaces the vehicle's own)
        st.push(s)
    st.flush()
    dec = [d for d in st.decisions if d["what"] == "declination"]
    assert [d["why"].split(" ")[0] for d in dec] == ["none", "World", "log"], dec
    assert "the vehicle's own parameter taken if it comes" in dec[1]["why"]
    assert 3.0 <= dec[1]["t"] < 3.2 and 6.0 <= dec[2]["t"] < 6.2
    assert st.declination == 0.0556 and not st._decl_pending


def test_a_late_declination_turns_the_attitude_filters_yaw_at_once():
    """The attitude model's yaw is the magnetometer's: a declination that comes after the
    alignment restarts every filter from its running estimate with the yaw turned by it
    (one Start, reason "declination"), so the yaw is right from the next step rather than
    after the mag updates have pulled it there (and the gyro bias with it)."""
    from uavest.engine.build import build_filters
    from uavest.engine.loop import Lane, run_lanes
    from uavest.engine.runner import FilterRunner
    from uavest.geometry.rotation import quat_to_euler
    from uavest.presets import resolve_list
    from uavest.sinks.base import Collector

    def params_at(samples, params):
        for s in samples:
            if s.t >= 5.0 and "COMPASS_DEC" not in params:
                params.update(COMPASS_DEC=0.2, COMPASS_AUTODEC=0)
            yield s

    params: dict = {}
    st = AttitudeStream(opts=AttitudeOptions(), params=params)
    (sp, flt), = build_filters(resolve_list(["ekf"], "attitude", dim=6))
    runner = FilterRunner(sp.label, flt, np.random.default_rng(0))
    coll = Collector()
    run_lanes(params_at(_samples(), params), [Lane(st, [runner])], [coll])
    a = coll.arrays("ekf")
    yaw = quat_to_euler(a["x"][:, :4])[:, 2]
    before, after = yaw[(a["t"] > 4.0) & (a["t"] < 4.9)], yaw[(a["t"] > 5.1) & (a["t"] < 6.0)]
    assert np.abs(before).max() < 0.01  # the magnetometer's at 0
    assert np.abs(after - 0.2).max() < 0.01  # turned at once
    reasons = [d for d in st.decisions if d["what"] == "declination"]
    assert "the yaw turned by +11.46 deg" in reasons[-1]["why"]
