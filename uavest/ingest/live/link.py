"""The live link itself: :class:`LiveLink` (reader thread, vehicle filter, lifecycle,
status) and :func:`open_live`; see :mod:`uavest.ingest.live`."""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ...link import (  # (sets MAVLINK20 before any pymavlink.mavutil import: signing)
    TlogWriter,
    Transport,
    Writer,
    enable_signing,
    endpoint_key,
    register_vehicle_endpoint,
    signing_key_bytes,
    split_conn,
    unregister_vehicle_endpoint,
)
from ...link.spec import SPEC_PARAMS
from ..mavlink import BURST_END, MavlinkSource
from ..types import IngestError, LinkEvent
from .declination import Declination
from .gaps import GapWatch
from .reader import Reader
from .streams import DEFAULT_STREAMS, StreamStatus, rate_warnings, request_streams

__all__ = ["LiveLink", "open_live", "LinkTimeout"]

log = logging.getLogger("uavest.live")

class LinkTimeout(IngestError):
    """No vehicle heartbeat within the timeout (a one-line message)."""


#: Parameters asked for at the start (not awaited) for the estimators: ArduPilot's IMU
#: low-pass, whose group delay the navigation model takes off the IMU's time stamps
#: (:func:`uavest.engine.navigation.imu_filter_delay`), and the sensors' datasheet
#: (:mod:`uavest.link.spec`; a vehicle without them does not answer).
ASKED_PARAMS = ("INS_GYRO_FILTER", *SPEC_PARAMS)


# ------------------------------------------------------------------ the link


class LiveLink(MavlinkSource):
    """A live MAVLink vehicle link as an iterable sample source (see module docstring).

    Args:
      conn: pymavlink-style connection string: ``udpin:127.0.0.1:14550`` (``udp:`` is the
        same; an empty host binds 127.0.0.1, ``udpin:0.0.0.0:14550`` only when written),
        ``udpout:host:port``, ``tcp:127.0.0.1:5760``, ``tcpin:127.0.0.1:5760``, or a serial
        device ``/dev/ttyACM0`` / ``/dev/ttyUSB0,57600`` (``baud`` otherwise).
      sysid: the vehicle's MAVLink system id; None = the first vehicle heartbeat's.
      streams: message name -> Hz to request (:data:`DEFAULT_STREAMS`); {} = request none.
      heartbeat_timeout: s to wait for the vehicle heartbeat (``LinkTimeout`` after).
      on_wait: called with a one-line status about once a second while waiting.
      gap_timeout: s without any vehicle message that makes a gap (``LinkEvent``).
      signing_key: MAVLink 2 signing key (see :func:`signing_key_bytes`); when set, unsigned
        and wrongly signed packets are rejected (``unsigned`` / ``bad_signature``).
      tlog: path of a tlog to record the accepted frames to (8-byte big-endian receive
        time in us + frame, like MAVProxy), written in whole records every ``flush_s``.
      queue_size: bound of the reader -> consumer queue (excess: ``queue_overflow``).
      reorder_window: s of vehicle time held to order messages (0.2 s; latency).
      read_declination: read COMPASS_DEC / COMPASS_AUTODEC and fall back to the WMM.
      ack_timeout, param_timeout: s to wait for a COMMAND_ACK / PARAM_VALUE.
      source_system, source_component: the identity of our requests (GCS-like, 250/190).
      stop: an event (the CLI's SIGINT / SIGTERM) that, set while :meth:`start` waits for
        the vehicle's heartbeat, ends the wait at once with ``KeyboardInterrupt``.
    """

    def __init__(
        self,
        conn: str,
        *,
        baud: int = 115200,
        sysid: int | None = None,
        imu: str | None = None,
        streams: dict[str, float] | None = None,
        heartbeat_timeout: float = 30.0,
        on_wait: Callable[[str], None] | None = None,
        gap_timeout: float = 2.0,
        signing_key: str | bytes | Path | None = None,
        tlog: str | Path | None = None,
        queue_size: int = 10_000,
        reorder_window: float = 0.2,
        read_declination: bool = True,
        ack_timeout: float = 1.0,
        param_timeout: float = 1.0,
        source_system: int = 250,
        source_component: int = mavlink.MAV_COMP_ID_MISSIONPLANNER,
        flush_s: float = 0.2,
        stop: threading.Event | None = None,
    ) -> None:
        super().__init__(conn, "mavlink-live", imu=imu, reorder_window=reorder_window,
                         sysid=sysid)
        self.conn = conn
        self.baud = baud
        self.streams = dict(DEFAULT_STREAMS if streams is None else streams)
        self.heartbeat_timeout = heartbeat_timeout
        self.on_wait = on_wait
        self.gap_timeout = gap_timeout
        self.queue_size = queue_size
        self.read_declination = read_declination
        self.ack_timeout = ack_timeout
        self.param_timeout = param_timeout
        self.flush_s = flush_s
        self.stop = stop
        self.tlog_path = Path(tlog) if tlog is not None else None
        self._key = signing_key_bytes(signing_key) if signing_key is not None else None
        if split_conn(conn)[0] != "serial":
            endpoint_key(conn)  # a bad host:port raises ValueError here, not in the thread
        self._init_parser(source_system, source_component)
        self._init_reader(queue_size)
        self._init_vehicle()

    def _init_parser(self, source_system: int, source_component: int) -> None:
        """Our MAVLink 2 parser and sender (writing to the current transport), signed and
        strictly checked when a key is given."""
        self._writer = Writer()
        self._mav = mavlink.MAVLink(self._writer, srcSystem=source_system,
                                    srcComponent=source_component)
        self._mav.robust_parsing = True
        if self._key is not None:
            enable_signing(self._mav, self._key, verify=True)

    def _init_reader(self, queue_size: int) -> None:
        """The reader thread (:class:`~uavest.ingest.live.reader.Reader`: the queue to
        the consumer, the replies it hands to the setup steps, the tlog, the connection
        and the link times) and the consumer side's lifecycle flags."""
        self._rx = Reader(self.conn, self.baud, self._writer, self._mav, self._key,
                          lambda: self.stats, self.gap_timeout, queue_size, self.sysid,
                          self._on_vehicle)
        self._q = self._rx.q
        self._hb = self._rx.hb
        self._replies = self._rx.replies
        self._thread: threading.Thread | None = None
        self._last_rx_unix: float | None = None
        self._started = False
        self._closed = False
        self._registered = False
        self._gen: Iterator | None = None

    def _on_vehicle(self, sysid: int, compid: int, vtype: int, autopilot: int) -> None:
        """A vehicle heartbeat (reader thread): its identity."""
        self.sysid = sysid
        self.vehicle_compid = compid
        self.vehicle_type, self.autopilot = vtype, autopilot

    def _init_vehicle(self) -> None:
        """What we learn of the vehicle: identity, streams, events, declination."""
        self.vehicle_compid: int | None = None
        self.vehicle_type: int | None = None
        self.autopilot: int | None = None
        self.stream_status: dict[str, StreamStatus] = {}
        self.events: list[LinkEvent] = []
        self._dec = Declination(self.conn)
        self._rates_checked = False
        self._requested_at: float | None = None

    # ------------------------------------------------------------ lifecycle
    def start(self) -> LiveLink:
        """Open the link, wait for the vehicle, request streams, read the declination."""
        if self._started:
            return self
        self._started = True
        if self.tlog_path is not None:
            self.tlog_path.parent.mkdir(parents=True, exist_ok=True)
            self._rx.tlog = TlogWriter(self.tlog_path, self.flush_s)
        try:
            self._writer.transport = Transport(self.conn, self.baud)
            self._rx.connected_once = True
        except OSError as e:
            if split_conn(self.conn)[0] != "tcp":
                self._rx.close_tlog()
                raise IngestError(f"{self.conn}: cannot open ({e})") from None
            # a SITL not up yet: the reader keeps trying until the heartbeat timeout
            log.info("%s: %s; retrying", self.conn, e)
        except ValueError as e:
            self._rx.close_tlog()
            raise IngestError(f"{self.conn}: cannot open ({e})") from None
        register_vehicle_endpoint(self.conn)
        self._registered = True
        self._thread = threading.Thread(target=self._rx.run, name="uavest-live-reader",
                                        daemon=True)
        self._thread.start()
        try:
            self._wait_heartbeat()
            self.check_signing()
            if self.streams:
                self.request_streams()
            if self.read_declination:
                self._ask_params(ASKED_PARAMS)
                self._read_declination()
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Stop the reader thread (joined), close the transport and the tlog.  Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._rx.stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        with self._writer.lock:
            if self._writer.transport is not None:
                self._writer.transport.close()
        self._rx.reset_parser(count=True)
        self._rx.close_tlog()
        if self._registered:
            unregister_vehicle_endpoint(self.conn)
            self._registered = False

    def __enter__(self) -> LiveLink:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    # ------------------------------------------------------------ status
    @property
    def vehicle_sysid(self) -> int | None:
        """The vehicle's system id (after the heartbeat)."""
        return self.sysid

    @property
    def signing_active(self) -> bool:
        """True if our parser checks signatures and signs what we send."""
        s = self._mav.signing
        return self._key is not None and s.secret_key == self._key and bool(s.sign_outgoing)

    def check_signing(self) -> None:
        """Raise ``IngestError`` if signing was asked for but is not in force on the parser."""
        if self._key is not None and not self.signing_active:
            raise IngestError(f"{self.conn}: MAVLink 2 signing was requested but is not active")
        if mavlink.WIRE_PROTOCOL_VERSION != "2.0":
            raise IngestError(f"{self.conn}: parser is not MAVLink 2")

    def rates(self) -> dict[str, float]:
        """Measured arrival rate (Hz) per message name of the vehicle, over the last 5 s."""
        return self._rx.rates.rates(time.time())

    def check_rates(self, min_fraction: float = 0.8) -> list[str]:
        """Warnings (also logged) for requested streams arriving below ``min_fraction``."""
        return rate_warnings(self.stream_status, self.rates(), min_fraction)

    # ------------------------------------------------------------ setup steps
    def _wait_heartbeat(self) -> None:
        t0 = time.monotonic()
        next_note = t0
        who = f"system {self.sysid}" if self.sysid is not None else "a vehicle"
        while not self._hb.wait(0.05):
            if self.stop is not None and self.stop.is_set():  # Ctrl-C / SIGTERM meanwhile
                raise KeyboardInterrupt
            now = time.monotonic()
            refused = self._rx.connect_error if self._writer.transport is None else None
            if now - t0 > self.heartbeat_timeout:
                if refused:
                    raise LinkTimeout(
                        f"{self.conn}: cannot connect ({refused}) for "
                        f"{self.heartbeat_timeout:g} s (is the vehicle/SITL listening on "
                        "this address and port?)")
                raise LinkTimeout(
                    f"{self.conn}: no HEARTBEAT from {who} within {self.heartbeat_timeout:g} s "
                    f"(is the vehicle/SITL sending to this address?)")
            if now >= next_note:
                msg = (f"{self.conn}: cannot connect ({refused}), retrying "
                       f"({now - t0:.0f} s)" if refused else
                       f"{self.conn}: waiting for a HEARTBEAT from {who} ({now - t0:.0f} s)")
                if self.on_wait is not None:
                    self.on_wait(msg)
                else:
                    log.info(msg)
                next_note += 1.0

    def _target(self) -> tuple[int, int]:
        return int(self.sysid or 1), int(self.vehicle_compid or 1)

    def request_streams(self, wait: bool = True) -> dict[str, StreamStatus]:
        """Ask for :attr:`streams`: SET_MESSAGE_INTERVAL each (ACK awaited if ``wait``),
        REQUEST_DATA_STREAM for those refused or unanswered.  Returns :attr:`stream_status`."""
        request_streams(self._mav, self._target(), self.streams, self.stream_status,
                        self._replies, self.ack_timeout, wait, self.conn)
        self._requested_at = time.monotonic()
        self._rates_checked = False
        return self.stream_status

    def _ask_params(self, names: tuple[str, ...]) -> None:
        """Ask for the parameters ``names`` without waiting: each reply flows through the
        sample stream into :attr:`params` (and the session tlog) like any PARAM_VALUE; an
        autopilot without one does not answer."""
        ts, tc = self._target()
        for name in names:
            self._mav.param_request_read_send(ts, tc, name.encode("ascii"), -1)

    def answered_params(self, names: Iterable[str]) -> dict[str, float]:
        """The parameters among ``names`` the vehicle has answered so far (those asked at
        the start, :data:`ASKED_PARAMS`, are in by the time :meth:`start` returns when
        the vehicle answers in order: the declination, awaited, was asked after them)."""
        with self._replies.cond:
            return {n: self._replies.params[n] for n in names if n in self._replies.params}

    def _read_param(self, name: str, timeout: float) -> float | None:
        self._replies.forget(name)
        self._ask_params((name,))
        return self._replies.wait_param(name, timeout)

    def _read_declination(self) -> None:
        dec = self._read_param("COMPASS_DEC", self.param_timeout)
        auto = self._read_param("COMPASS_AUTODEC", self.param_timeout) if dec is not None \
            else None
        self._dec.from_params(dec, auto)

    @property
    def declination(self) -> float | None:
        """The magnetic declination (rad, east positive), None while unknown."""
        return self._dec.value

    @property
    def declination_source(self) -> str:
        """Where :attr:`declination` comes from (``param:COMPASS_DEC``, ``wmm2025``, or why
        it is unknown)."""
        return self._dec.source

    # ------------------------------------------------------------ consumer side
    def __iter__(self) -> Iterator:
        """The link's one sample stream: iterating again continues it (clock, order kept)."""
        if not self._started:
            self.start()
        if self._closed and self._gen is None:
            raise IngestError(f"{self.conn}: link is closed")
        if self._gen is None:
            self._gen = super().__iter__()
        return self._gen

    def _messages(self) -> Iterator[tuple[object, object]]:
        """(message, receive time) from the queue; (None, LinkEvent) for link events,
        (None, BURST_END) after the messages of one read of the connection."""
        gaps = GapWatch(self.gap_timeout, self.conn)
        st = self.stats
        while not (self._closed and self._q.empty()):
            while self._rx.events:
                ev = self._rx.events.popleft()
                self.events.append(ev)
                yield None, ev
            self._upkeep()
            try:
                m, rx = self._q.get(timeout=0.05)
            except queue.Empty:
                ev = gaps.idle(time.monotonic() - self._rx.last_rx_mono)
                if ev is not None:
                    yield None, self._gap_event(ev)
                continue
            for ev in gaps.message(rx):
                yield None, self._gap_event(ev)
            self._last_rx_unix = rx
            name = m.get_type()
            st.messages[name] += 1
            self._watch(m, name)
            yield m, rx
            if getattr(m, "_burst_end", False):  # the last message of a read
                yield None, BURST_END

    def _upkeep(self) -> None:
        """Between messages: re-request the streams when asked to (reconnect, gap end),
        check the achieved rates once 3 s after a request."""
        if self._rx.need_request and self._hb.is_set() and self.streams:
            self._rx.need_request = False
            self.request_streams(wait=False)
        if (not self._rates_checked and self._requested_at is not None
                and time.monotonic() - self._requested_at > 3.0):
            self._rates_checked = True
            self.check_rates()

    def _gap_event(self, ev: LinkEvent) -> LinkEvent:
        """Record a gap event (counted in the stats; streams asked again at its end)."""
        if ev.kind == "link_lost":
            self.stats.link_gap += 1
        elif self.streams:
            self._rx.need_request = True
        self.events.append(ev)
        return ev

    def _watch(self, m, name: str) -> None:
        """Declination bookkeeping from the messages flowing by."""
        if self._dec.watch(m, name):  # the autopilot computes it after lock: ask again
            ts, tc = self._target()
            self._replies.forget("COMPASS_DEC")
            self._mav.param_request_read_send(ts, tc, b"COMPASS_DEC", -1)


def open_live(conn: str, **kwargs) -> LiveLink:
    """Open and start a :class:`LiveLink` (heartbeat awaited, streams requested).

    Raises :class:`LinkTimeout` (one line) without a vehicle heartbeat, or
    :class:`IngestError` if the connection cannot be opened.  Keyword arguments as
    :class:`LiveLink`.  Use as a context manager or call ``close()``.
    """
    return LiveLink(conn, **kwargs).start()
