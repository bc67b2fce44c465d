"""The GNSS delay estimated during a live navigation run (``uavest run --model nav``
without ``--gnss-delay``; with it, the velocity window and the baro delay at it:
:class:`uavest.engine.gnss_delay.LiveDelayLearner`), over the
live job run on logs/sitl_copter.tlog (an ArduCopter SITL flight whose GPS_RAW_INT lags
its IMU by about 0.083 s, the replay's estimate): samples on arrival, where each fix comes
after the IMU steps it predates and is applied by a rewind of the lane's history, against
samples held in time order (no rewind), and against no delay. Every run ends at the
log's 130th second (:data:`END_S`)."""

from __future__ import annotations

import functools
import itertools
import math
from pathlib import Path

import pytest

from uavest.apps.live import LiveConfig, run_samples
from uavest.engine.gnss_delay import BARO_NOISE_MIN
from uavest.ingest import open_source
from uavest.sinks.base import Sink

ROOT = Path(__file__).resolve().parents[2]
LOG = ROOT / "logs" / "sitl_copter.tlog"


#: The runs end at the log's samples stamped this many seconds (of its 206): the learner
#: decides at 64.5 s and refines at 124.5 s, and the rest of the flight adds CPU, not
#: checks
END_S = 130.0


#: s, past the learner's first decision (64.5 s): a run that checks only that one ends here
FIRST_S = 70.0


def _run(sinks=(), end: float = END_S, **kw):
    """The live job over the log, to its samples stamped ``end`` s."""
    cfg = LiveConfig(connect=str(LOG), model="nav", filters=("ekf",), trackers=(), **kw)
    src = open_source(LOG, reorder_window=cfg.reorder_window)
    samples = itertools.takewhile(lambda s: s.t < end, src)
    return run_samples(samples, cfg, params=src.params, status=False, sinks=list(sinks),
                       stats=src.stats)


@functools.cache
def _default_run():
    """The live job over the log with the default options, once for this file's three
    tests that need it (a 130-s navigation run), the EKF's and SIM_STATE's heights
    captured (:class:`_Heights`): (result document, sink)."""
    sink = _Heights()
    return _run(sinks=[sink]), sink


@pytest.mark.slow  # three navigation runs over 130 s of a log and one over 70 s
def test_live_run_estimates_the_gnss_delay_window_and_baro_delay_and_uses_them():
    on_arrival = _default_run()[0]
    ordered = _run(reorder_window=1.0, end=FIRST_S)  # held in time order, to 70 s
    none = _run(gnss_delay=0.0)
    given = _run(gnss_delay=0.083)
    learned = on_arrival["gnss_delay_live"]
    assert learned["delay"] is not None, learned
    # the SITL's lag, as the replay's probe puts it (0.083 s) and as the lag of
    # GPS_RAW_INT's velocity behind SIM_STATE's (0.085 s)
    assert 0.075 < learned["delay"] < 0.095, learned
    tries = learned["tries"]
    assert any(t["refinement"] and t["delay"] is not None for t in tries), tries
    said = [d for d in on_arrival["decisions"] if d["what"] == "GNSS delay"]
    assert said[0]["why"].startswith("default; until it is known") and (
        "estimated live" in said[-1]["why"]), said
    assert on_arrival["history"]["lanes"]["attitude"]["rewinds"] > 100  # fixes come late
    # the rewinds re-made the probe's steps, never added them twice: the first decision
    # of the run that held every sample in time order (no rewind) is the same within 2 ms
    # (and its window within 0.02 s, its baro delay within 2 ms)
    assert ordered["history"]["lanes"] == {}
    (first,), (o,) = tries[:1], ordered["gnss_delay_live"]["tries"]
    assert not o["refinement"] and abs(o["t"] - first["t"]) < 0.1, (o, first)
    assert abs(o["delay"] - first["delay"]) < 0.002, (o, first)
    assert abs(o["window"] - first["window"]) < 0.02, (o, first)
    assert abs(o["baro_delay"] - first["baro_delay"]) < 0.002, (o, first)
    # with the delay, the GNSS velocity's window (the replay's probe: 0.347 s) and the
    # baro's delay behind the GNSS height (0.089 s; against SIM_STATE 0.088 s)
    assert 0.3 < learned["window"] < 0.4 and 0.07 < learned["baro_delay"] < 0.11, learned
    for what in ("GNSS velocity window", "baro delay"):
        said = [d for d in on_arrival["decisions"] if d["what"] == what]
        assert "estimated live" in said[-1]["why"], said
    # the delay given, it is not learned; the window and the baro delay are, at it
    for doc, d in ((none, 0.0), (given, 0.083)):
        assert doc["gnss_delay_live"]["delay"] is None
        assert doc["gnss_delay_live"]["given"] == d
        said = [x for x in doc["decisions"] if x["what"] == "GNSS delay"]
        assert [x["why"] for x in said] == ["option --gnss-delay"], said
    g = given["gnss_delay_live"]
    assert 0.3 < g["window"] < 0.4 and 0.07 < g["baro_delay"] < 0.11, g
    for what in ("GNSS velocity window", "baro delay"):
        said = [x for x in given["decisions"] if x["what"] == what]
        assert "at the given GNSS delay 0.083 s" in said[-1]["why"], said
    # a delay the data contradict (0 s against their 0.08): no window at it, the floor
    # for an unknown one stays
    n = none["gnss_delay_live"]
    assert n["window"] is None and n["baro_delay"] is None, n
    assert all("not modelled" in t["window_why"] and 0.07 < t["data_delay"] < 0.095
               for t in n["tries"]), n["tries"]
    said = [x for x in none["decisions"] if x["what"] == "GNSS velocity window"]
    assert [x["value"] for x in said] == ["not known"], said
    # the summary says what was not learned, and names the position reference
    from uavest.cli.run import format_live

    text = format_live(none)
    assert "GNSS velocity window: not estimated live at the given delay (the data's own " \
           "lag" in text, text
    assert "position (m) against SIM_STATE" in text
    assert "not estimated live" not in format_live(given)
    assert "filter resets:" not in format_live(given)
    import copy

    reset = copy.deepcopy(given)
    reset["attitude"]["ekf"].update(resets=1, resets_why=[[12.5, "gnss_vel rejected"]])
    assert "filter resets: ekf 1 (first at t=12.5 s: gnss_vel rejected)" in format_live(reset)
    c = given["attitude"]["ekf"]
    assert abs(c["vel_rmse_ms"] - on_arrival["attitude"]["ekf"]["vel_rmse_ms"]) < 0.01, c
    a, b = on_arrival["attitude"]["ekf"], none["attitude"]["ekf"]
    assert a["vel_rmse_ms"] < 0.5 * b["vel_rmse_ms"], (a, b)
    assert a["hpos_rmse_m"] < 0.5 * b["hpos_rmse_m"], (a, b)
    assert a["roll_rmse_deg"] < b["roll_rmse_deg"] and a["pitch_rmse_deg"] < b["pitch_rmse_deg"]


@pytest.mark.slow  # two navigation runs over 130 s of a log
def test_a_live_run_started_with_a_previous_runs_aiding_has_the_takeoffs_tilt(tmp_path):
    """``--aiding-from``: a run started with the GNSS delay, velocity window and baro noise
    a previous run learned (its JSON result, as written), and the field's inclination its
    filters learnt there, has them from its first step,
    where the previous run had them only 60 s in, after the takeoff: its pitch is that of
    a run that knew them (logs/sitl_copter.tlog to 130 s, airborne EKF: 0.25 -> 0.12 deg), its
    NEES in band, and it still learns its own delay and window."""
    from uavest.apps.aiding import read_aiding
    from uavest.sinks.jsonout import write_json

    first = _default_run()[0]
    path = write_json(tmp_path / "first.json", first)
    aiding, why = read_aiding(path)
    assert set(aiding) == {"gnss_delay", "gnss_vel_window", "baro_noise", "mag_noise",
                           "mag_inclination", "mag_site_lat", "mag_site_lon"}, aiding
    # the field the first run's EKF learnt (its magnetic reference states), where it flew
    assert aiding["mag_inclination"] == pytest.approx(
        math.radians(first["attitude"]["ekf"]["mag_ref"]["inclination_deg"]))
    assert aiding["mag_site_lat"] == first["origin"]["lat"]
    learned = first["gnss_delay_live"]
    assert aiding["gnss_delay"] == pytest.approx(learned["delay"])
    assert aiding["gnss_vel_window"] == pytest.approx(learned["window"])
    # the SITL's baro is a few mm from its noiseless GNSS height: the floor
    assert learned["baro_spread"] < BARO_NOISE_MIN
    assert aiding["baro_noise"] == pytest.approx(BARO_NOISE_MIN)
    assert aiding["mag_noise"] == pytest.approx(learned["mag_noise"])
    second = _run(aiding=aiding, aiding_why=why)
    a, b = (d["attitude"]["ekf"]["airborne"] for d in (first, second))
    assert b["pitch_rmse_deg"] < 0.7 * a["pitch_rmse_deg"], (a, b)
    # issue 19's bar, 0.8, on every block; the velocity's 0.79: on cbff37f (the IMU's
    # counts read as the middle of their unit) this 130-s cut has it at 0.799 (0.813
    # before; above the band on 0.15 of the steps); a whole live session's, started so, 0.838
    # (docs/live.md, "The same two sessions with the IMU's counts ..."). With the density
    # that follows the flight, 0.800 (a fixed 0.003 made it over-confident, 0.778).
    assert min(b["nees"][k]["in_band95"] for k in ("attitude", "position")) > 0.8, b
    assert b["nees"]["velocity"]["in_band95"] > 0.79, b
    # that density, in the result and said: this windy flight's is above its calm base
    from uavest.cli.run import format_live
    from uavest.models.navigation import FAST_MAVLINK_PROFILE

    d = second["accel_density"]
    assert d["mean"] > 1.8 * FAST_MAVLINK_PROFILE.accel_noise and d["max"] > d["mean"], d
    assert "accelerometer density: followed the flight's roughness" in format_live(second)
    said = [d for d in second["decisions"] if d["what"] == "GNSS delay"]
    assert "from --aiding-from: a live run's" in said[0]["why"], said
    assert "estimated live" in said[-1]["why"], said
    noise = [d for d in second["decisions"] if d["what"] == "baro noise"]
    assert noise and "first.json" in noise[0]["why"], noise
    mag = [d for d in second["decisions"] if d["what"] == "magnetometer noise"]
    assert mag and "first.json" in mag[0]["why"], mag
    inc = [d for d in second["decisions"] if d["what"] == "inclination"]
    assert inc and "from --aiding-from" in inc[0]["why"], inc


class _Heights(Sink):
    """The EKF's heights and SIM_STATE's (m above the navigation frame's origin)."""

    def __init__(self) -> None:
        self.est: list[tuple[float, float]] = []
        self.truth: list[tuple[float, float]] = []
        self.alt0: float | None = None

    def sample(self, s) -> None:
        from uavest.engine.records import NavAnchor
        from uavest.ingest.types import PositionSample

        if isinstance(s, NavAnchor):
            self.alt0 = s.alt
        elif (isinstance(s, PositionSample) and s.source == "SIM_STATE"
              and s.lat_lon_alt is not None):
            self.truth.append((s.t, float(s.lat_lon_alt[2])))

    def record(self, r) -> None:
        x = getattr(r, "x", None)
        if r.estimator == "ekf" and x is not None and len(x) >= 16:
            self.est.append((r.t, -float(x[9])))


@pytest.mark.slow  # one navigation run over 130 s of a log
def test_a_live_run_takes_the_baro_noise_and_offset_it_learns():
    """With the baro's delay the run learns its noise (the SITL's baro is a few mm from
    its GNSS height: the floor, 0.01 m, against the 0.2 m of the source's profile) and
    refits its offset to the GNSS height at that delay: the running offset, averaged
    while the baro's timing was not known (the takeoff), is centimetres off, more than the
    noise. After it the height is within a centimetre of SIM_STATE's (RMSE 3.8 mm from
    5 s after the fit to 130 s; over the whole flight 4.2 mm, against 19.3 mm with the
    profile's noise and the running offset, 01f46b5)."""
    import numpy as np

    doc, sink = _default_run()
    learned = doc["gnss_delay_live"]
    assert learned["baro_noise"] == pytest.approx(BARO_NOISE_MIN)
    assert learned["baro_offset"] is not None
    t_fit = learned["tries"][0]["t"]
    noise = [d for d in doc["decisions"] if d["what"] == "baro noise"]
    assert [d["value"] for d in noise] == [f"{BARO_NOISE_MIN:.3f} m"]
    assert "estimated live" in noise[0]["why"]
    assert noise[0]["t"] == pytest.approx(t_fit)
    off = [d for d in doc["decisions"] if d["what"] == "baro offset"]
    assert len(off) == 2 and "refit at the baro's delay" in off[1]["why"], off
    was = float(off[1]["why"].split("was ")[1].split(" m")[0])
    assert abs(was - float(off[1]["value"].split()[0])) >= 0.03, off  # the takeoff's error
    assert sink.alt0 is not None and sink.truth and sink.est
    t, h = np.array(sink.est).T
    tt, ht = np.array(sink.truth).T
    late = t > t_fit + 5.0
    e = h[late] - (np.interp(t[late], tt, ht) - sink.alt0)
    assert np.sqrt(np.mean(e * e)) < 0.01, np.sqrt(np.mean(e * e))



@pytest.mark.slow  # one navigation run over 70 s of a log (and the default run's)
def test_a_live_run_learns_the_magnetometer_noise_unless_it_is_given():
    """With the GNSS delay the run learns the magnetometer's noise as the replay's probe
    does: the spread of its readings' direction turned to NED with the filter's attitude,
    at the age the run takes them (0 here), within [MAG_NOISE_MIN, the source's profile]
    (the SITL's magnetometer spreads by about 2 deg per axis: the floor, 0.05 rad, against
    the profile's 0.08); it is used from then on and recorded for a next run. Not when an
    option (or the vehicle's spec) gives the noise."""
    from uavest.engine.gnss_delay import MAG_NOISE_MIN

    doc = _default_run()[0]
    learned = doc["gnss_delay_live"]
    assert 0.0 < learned["mag_scatter"] < MAG_NOISE_MIN, learned["mag_scatter"]
    assert learned["mag_noise"] == pytest.approx(MAG_NOISE_MIN)
    said = [d for d in doc["decisions"] if d["what"] == "magnetometer noise"]
    assert [d["value"] for d in said] == ["0.080 rad", f"{MAG_NOISE_MIN:.3f} rad"], said
    assert "estimated live" in said[1]["why"]
    assert said[1]["t"] == pytest.approx(learned["tries"][0]["t"])  # (the first decision)
    given = _run(noise={"mag_noise": 0.07}, end=FIRST_S)
    assert given["gnss_delay_live"]["delay"] is not None  # (the rest was learnt)
    assert given["gnss_delay_live"]["mag_noise"] is None
    said = [d for d in given["decisions"] if d["what"] == "magnetometer noise"]
    assert [d["value"] for d in said] == ["0.070 rad"], said


def test_a_declination_given_to_a_live_run_is_kept():
    """``uavest run --declination DEG`` (LiveConfig.declination, rad): the stream takes it
    at its start (said "option") and keeps it when the vehicle's COMPASS_DEC comes (44 s
    into the log: 3.19 deg), where a run without it takes the vehicle's."""
    import numpy as np

    given = _run(declination=np.radians(2.5), end=47.0)
    said = [d for d in given["decisions"] if d["what"] == "declination"]
    assert [(d["value"], d["why"]) for d in said] == [("2.50 deg", "option")], said
    own = _run(end=47.0)
    said = [d for d in own["decisions"] if d["what"] == "declination"]
    assert said[-1]["value"] == "3.19 deg" and "COMPASS_DEC" in said[-1]["why"], said

