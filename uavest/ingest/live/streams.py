"""Stream requests of the live link and the check of the rates achieved.

:func:`request_streams` asks a vehicle for messages at given rates (``SET_MESSAGE_INTERVAL``
each, ``REQUEST_DATA_STREAM`` for the refused or unanswered), :class:`RateMeter` measures
the arrival rate (Hz) per message name, :func:`rate_warnings` compares the two. Rates in Hz,
times in seconds (monotonic for the request clock, UNIX receive time for the meter).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ...errors import InputError
from .replies import Replies

log = logging.getLogger("uavest.live")

#: Messages requested by default (name -> Hz).  ArduPilot serves HIGHRES_IMU and
#: ATTITUDE_QUATERNION only through SET_MESSAGE_INTERVAL.
DEFAULT_STREAMS: dict[str, float] = {
    "HIGHRES_IMU": 100.0,
    "RAW_IMU": 50.0,
    "ATTITUDE_QUATERNION": 50.0,
    "ATTITUDE": 10.0,
    "GLOBAL_POSITION_INT": 10.0,
    "GPS_RAW_INT": 5.0,  # raw GNSS fixes (time_usec UNIX on ArduPilot: ingest retimes it)
    "SCALED_PRESSURE": 10.0,  # barometer (navigation height aiding)
    "SYSTEM_TIME": 1.0,
}

#: REQUEST_DATA_STREAM fallback: message -> ArduPilot data stream that carries it (or a
#: substitute: HIGHRES_IMU -> RAW_SENSORS gives RAW_IMU; ATTITUDE_QUATERNION -> EXTRA1 gives
#: ATTITUDE).  ArduPilot caps data streams at 50 Hz.
DATA_STREAM = {
    "HIGHRES_IMU": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "RAW_IMU": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU2": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU3": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "GPS_RAW_INT": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "SCALED_PRESSURE": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "GLOBAL_POSITION_INT": mavlink.MAV_DATA_STREAM_POSITION,
    "LOCAL_POSITION_NED": mavlink.MAV_DATA_STREAM_POSITION,
    "ATTITUDE": mavlink.MAV_DATA_STREAM_EXTRA1,
    "ATTITUDE_QUATERNION": mavlink.MAV_DATA_STREAM_EXTRA1,
    "SIMSTATE": mavlink.MAV_DATA_STREAM_EXTRA1,
    "AHRS2": mavlink.MAV_DATA_STREAM_EXTRA1,
    "SYSTEM_TIME": mavlink.MAV_DATA_STREAM_EXTRA3,
}
DATA_STREAM_MAX_HZ = 50
#: Streams only a simulator sends (ArduPilot SITL's truth SIMSTATE / SIM_STATE; PX4
#: SITL's and uavest's simulator's HIL_STATE_QUATERNION): a vehicle, or the other
#: simulators, refuse them as a matter of course, so the refusal is not warned about (the
#: stream line still says ``missing``).
SIMULATOR_ONLY = frozenset({"SIMSTATE", "SIM_STATE", "HIL_STATE_QUATERNION"})


@dataclass
class StreamStatus:
    """One requested stream: requested Hz, how (``SET_MESSAGE_INTERVAL`` | ``REQUEST_DATA_STREAM``
    | ``none``), the COMMAND_ACK result (MAV_RESULT, None if no ACK) and the measured Hz."""

    name: str
    requested_hz: float
    method: str = "none"
    ack: int | None = None
    measured_hz: float = 0.0

    @property
    def ok(self) -> bool:
        return self.measured_hz >= 0.8 * self.requested_hz


class RateMeter:
    """Arrival rate per message name over the last ``window`` s (bounded memory)."""

    def __init__(self, window: float = 5.0, maxlen: int = 4096) -> None:
        self.window = window
        self.times: dict[str, deque] = {}
        self.first: dict[str, float] = {}
        self.maxlen = maxlen
        self.lock = threading.Lock()

    def add(self, name: str, t: float) -> None:
        with self.lock:
            d = self.times.get(name)
            if d is None:
                if len(self.times) > 512:  # made-up names from a flood: don't grow
                    return
                d = self.times[name] = deque(maxlen=self.maxlen)
                self.first[name] = t
            d.append(t)

    def rates(self, now: float) -> dict[str, float]:
        out = {}
        with self.lock:
            for name, d in self.times.items():
                ts = [t for t in d if t >= now - self.window]
                if len(d) == d.maxlen and ts and len(ts) == len(d):  # saturated: span rate
                    span = ts[-1] - ts[0]
                    out[name] = (len(ts) - 1) / span if span > 0 else 0.0
                else:  # over the window, or since the stream started if that is shorter
                    span = min(self.window, now - self.first[name])
                    out[name] = len(ts) / span if span > 0.2 else 0.0
        return out


def request_streams(mav: Any, target: tuple[int, int], streams: dict[str, float],
                    status: dict[str, StreamStatus], replies: Replies, ack_timeout: float,
                    wait: bool = True, conn: str = "") -> dict[str, StreamStatus]:
    """Ask for ``streams`` (name -> Hz) from ``target`` (system, component) through the
    sender ``mav``: SET_MESSAGE_INTERVAL each (ACK awaited up to ``ack_timeout`` s if
    ``wait``), REQUEST_DATA_STREAM for those refused or unanswered. Updates and returns
    ``status`` (one :class:`StreamStatus` per name)."""
    ts, tc = target
    fallback: dict[int, float] = {}
    answered = False
    for i, (name, hz) in enumerate(streams.items()):
        st = status.setdefault(name, StreamStatus(name, float(hz)))
        msgid = getattr(mavlink, f"MAVLINK_MSG_ID_{name}", None)
        if msgid is None:
            raise InputError(f"unknown MAVLink message {name!r} in streams")
        since = time.monotonic()
        mav.command_long_send(ts, tc, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                              float(msgid), float(1e6 / hz), 0, 0, 0, 0, 0)
        res = None
        if wait and (answered or i == 0):  # no ACK to the first: the vehicle gives none
            res = replies.wait_ack(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, since, ack_timeout)
            answered = answered or res is not None
        st.ack = res
        if res == mavlink.MAV_RESULT_ACCEPTED:
            st.method = "SET_MESSAGE_INTERVAL"
        else:
            ds = DATA_STREAM.get(name)
            if ds is not None:
                fallback[ds] = max(fallback.get(ds, 0.0), float(hz))
                st.method = "REQUEST_DATA_STREAM"
            else:
                st.method = "none"
                (log.debug if name in SIMULATOR_ONLY else log.warning)(
                    "%s: %s refused (result %s) and has no data stream fallback", conn, name,
                    res)
    for ds, hz in fallback.items():
        rate = int(min(max(1, round(hz)), DATA_STREAM_MAX_HZ))
        mav.request_data_stream_send(ts, tc, ds, rate, 1)
    return status


def rate_warnings(status: dict[str, StreamStatus], rates: dict[str, float],
                  min_fraction: float = 0.8) -> list[str]:
    """Warnings (also logged) for requested streams arriving below ``min_fraction`` of the
    requested rate; sets each status's ``measured_hz`` from ``rates`` (Hz)."""
    out = []
    for name, st in status.items():
        st.measured_hz = rates.get(name, 0.0)
        if st.measured_hz <= 0.0:  # never arrived: said as missing, by name
            msg = (f"missing: {name} (requested {st.requested_hz:g} Hz, none received; "
                   f"{st.method})")
            log.warning(msg)
            out.append(msg)
        elif st.measured_hz < min_fraction * st.requested_hz:
            msg = (f"{name}: {st.measured_hz:.1f} Hz arriving, {st.requested_hz:g} Hz "
                   f"requested ({st.method})")
            log.warning(msg)
            out.append(msg)
    return out
