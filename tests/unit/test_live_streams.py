"""The achieved-rate lines of the live estimator's stream check and the sink guard that
keeps one failing sink from ending a live run (uavest.apps.streams, uavest.apps.live)."""

from __future__ import annotations

import errno
from types import SimpleNamespace

import pytest

from uavest.apps.live import SinkFailure, _Guarded
from uavest.apps.streams import achieved_rates, mean_rates
from uavest.sinks.base import Sink


def _st(hz: float, method: str = "SET_MESSAGE_INTERVAL", ack: int | None = 0):
    return SimpleNamespace(requested_hz=hz, method=method, ack=ack)


def test_each_requested_stream_gets_a_status_and_one_line():
    status = {"HIGHRES_IMU": _st(100.0), "GPS_RAW_INT": _st(5.0, "REQUEST_DATA_STREAM"),
              "ADSB_VEHICLE": _st(10.0)}
    rates = {"HIGHRES_IMU": 99.6, "GPS_RAW_INT": 2.0, "HEARTBEAT": 1.0}
    out = {r.name: r for r in achieved_rates(status, rates, 5.0)}
    assert list(out) == list(status)  # request order, unrequested messages left out
    assert out["HIGHRES_IMU"].status == "ok"
    assert out["GPS_RAW_INT"].status == "low"  # 2 of 5 Hz < 80 %
    assert out["ADSB_VEHICLE"].status == "missing"
    assert out["HIGHRES_IMU"].line() == ("stream HIGHRES_IMU: 100 Hz requested, 99.6 Hz "
                                         "achieved (SET_MESSAGE_INTERVAL)")
    assert out["GPS_RAW_INT"].line().endswith("2.0 Hz achieved, low (REQUEST_DATA_STREAM)")
    assert out["ADSB_VEHICLE"].line() == ("missing: ADSB_VEHICLE (requested 10 Hz, none "
                                          "received; SET_MESSAGE_INTERVAL)")
    assert out["GPS_RAW_INT"].as_dict()["achieved_hz"] == 2.0


def test_the_low_threshold_is_80_percent():
    out = achieved_rates({"A": _st(10.0), "B": _st(10.0)}, {"A": 8.0, "B": 7.9}, 5.0)
    assert [r.status for r in out] == ["ok", "low"]


def test_mean_rates_over_the_run():
    assert mean_rates({"A": 50, "B": 0}, ["A", "B", "C"], 10.0) == {"A": 5.0, "B": 0.0,
                                                                   "C": 0.0}


class _Boom(Sink):
    def __init__(self, exc: BaseException, after: int) -> None:
        self.exc, self.after, self.n, self.closed = exc, after, 0, 0

    def record(self, rec) -> None:
        self.n += 1
        if self.n > self.after:
            raise self.exc

    def close(self) -> None:
        self.closed += 1


@pytest.mark.parametrize("exc,internal", [
    (OSError(errno.ENOSPC, "No space left on device"), False),
    (ValueError("I/O operation on closed file"), True),
])
def test_a_failing_sink_is_stopped_alone_and_kept(exc, internal):
    failures: list[SinkFailure] = []
    inner = _Boom(exc, after=3)
    g = _Guarded(inner, failures)
    for k in range(10):
        g.record(SimpleNamespace(t=float(k)))
    g.close()
    assert inner.n == 4  # not called again after it raised
    assert inner.closed == 1  # closed once, at the failure (the later close is skipped)
    (f,) = failures
    assert f.call == "record" and f.t == 3.0 and f.error is exc
    assert f.as_dict()["internal"] is internal
    line = f.line()
    assert "\n" not in line and "the run went on without it" in line
    assert ("internal error" in line) is internal


def test_a_refused_simulator_only_stream_is_not_warned_about(caplog):
    """A vehicle (or uavest's own simulator, for SIM_STATE) refuses the simulator's truth
    streams as a matter of course: no warning for those, one for any other stream that
    has no data stream fallback; each is marked ``none`` (said as missing later)."""
    import logging

    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from uavest.ingest.live.streams import request_streams

    sent: list[tuple] = []
    mav = SimpleNamespace(command_long_send=lambda *a: sent.append(a),
                          request_data_stream_send=lambda *a: sent.append(a))
    replies = SimpleNamespace(wait_ack=lambda *a: mavlink.MAV_RESULT_DENIED)
    with caplog.at_level(logging.DEBUG, logger="uavest"):
        st = request_streams(mav, (1, 1), {"SIM_STATE": 10.0, "OBSTACLE_DISTANCE_3D": 10.0},
                             {}, replies, 0.1, conn="udp:x")
    assert st["SIM_STATE"].method == st["OBSTACLE_DISTANCE_3D"].method == "none"
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert any("OBSTACLE_DISTANCE_3D refused" in m for m in warned), warned
    assert not any("SIM_STATE" in m for m in warned), warned
    assert any("SIM_STATE refused" in r.getMessage() for r in caplog.records)  # debug
    assert len(sent) == 2  # two SET_MESSAGE_INTERVAL, no data stream to fall back on
