"""The live link's reader thread: (re)connects the transport, parses the bytes with the
link's MAVLink 2 parser, keeps one vehicle's messages (counting what it drops in the link
stats), hands ACKs and parameters to the setup steps, records the tlog and fills the
bounded queue to the consumer. Times: ``rx`` UNIX receive time s (``rx_us`` us, low 2 bits
cleared as MAVProxy does), link times monotonic s."""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ...link import (
    Disconnected,
    TlogWriter,
    Transport,
    Writer,
    bad_data_kind,
    param_name,
    reset_parser,
)
from ..types import LinkEvent
from .replies import Replies
from .streams import RateMeter

TCP_SILENCE = 3.0  # s, min silence before a TCP link is reconnected (SITL heartbeat: 1 Hz)

_NOT_VEHICLE_TYPES = {
    mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_GIMBAL, mavlink.MAV_TYPE_ADSB,
    mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_TYPE_CAMERA,
}


def is_vehicle(m: Any) -> bool:
    """A HEARTBEAT of a vehicle (not a GCS, gimbal, camera... nor an invalid autopilot)."""
    return (int(m.type) not in _NOT_VEHICLE_TYPES
            and int(m.autopilot) != mavlink.MAV_AUTOPILOT_INVALID)


class Reader:
    """The reader thread's state and loop (:meth:`run`).

    Args:
      conn, baud: the connection string and serial baud rate.
      writer: the link's writer (its ``transport`` is the current connection).
      mav: the link's MAVLink 2 parser / sender. key: the signing key (None: unsigned).
      stats: gives the link's current stats (``IngestStats``; counters updated here).
      gap_timeout: s of silence that makes a gap (a silent TCP peer is reconnected).
      queue_size: bound of the queue to the consumer (excess: ``queue_overflow``).
      sysid: the vehicle's system id; None = the first vehicle heartbeat's.
      on_vehicle: called (sysid, compid, type, autopilot) at each vehicle heartbeat.
    """

    def __init__(self, conn: str, baud: int, writer: Writer, mav: Any, key: bytes | None,
                 stats: Callable[[], Any], gap_timeout: float, queue_size: int, sysid: int | None,
                 on_vehicle: Callable[[int, int, int, int], None]) -> None:
        self.conn, self.baud = conn, baud
        self.writer, self.mav, self.key, self._stats = writer, mav, key, stats
        self.gap_timeout = gap_timeout
        self.sysid = sysid
        self.on_vehicle = on_vehicle
        self.q: queue.Queue = queue.Queue(maxsize=queue_size)
        self.stop = threading.Event()
        self.hb = threading.Event()
        self.replies = Replies()
        self.rates = RateMeter()
        self.events: deque = deque(maxlen=256)  # LinkEvents from the reader thread
        self.tlog: TlogWriter | None = None
        self.last_rx_mono = time.monotonic()
        self.connected_once = False
        self.connected_at = time.monotonic()
        self.connect_error: str | None = None  # why the last connection attempt failed
        self.need_request = False  # streams to be asked again (after a reconnect)

    @property
    def stats(self) -> Any:
        """The link's stats now (the source may swap them, e.g. while prescanning)."""
        return self._stats()

    def run(self) -> None:
        """The thread's loop, until :attr:`stop` is set."""
        backoff = 0.1
        while not self.stop.is_set():
            tr = self.writer.transport
            if tr is None:
                tr = self._connect()
                if tr is None:
                    self.stop.wait(backoff)
                    backoff = min(2 * backoff, 2.0)
                    continue
                backoff = 0.1
            try:
                data = tr.recv(0.05)
            except Disconnected:
                self.drop_transport(tr)
                continue
            except OSError:
                self.drop_transport(tr)
                continue
            if not data:
                quiet = time.monotonic() - max(self.last_rx_mono, self.connected_at)
                if tr.kind == "tcp" and quiet > max(self.gap_timeout, TCP_SILENCE):
                    self.drop_transport(tr)  # silent TCP peer: reconnect
                self.flush_tlog()
                continue
            if tr.kind.startswith("udp"):
                self.reset_parser(count=True)  # a datagram is a unit: no frame spans two
            rx_us = int(time.time() * 1e6) & ~3  # as MAVProxy: low bits are the link id
            rx = rx_us * 1.0e-6  # exactly what mavlogfile computes from the tlog
            try:
                msgs = self.mav.parse_buffer(data) or []
            except Exception:  # noqa: BLE001 - garbage must never stop the reader
                self.stats.corrupt += 1
                self.reset_parser()
                msgs = []
            kept = [m for m in msgs if self.handle(m, rx_us, rx)]
            if kept:  # the last of this read's burst: released on arrival when it is taken
                kept[-1]._burst_end = True
            for m in kept:
                try:
                    self.q.put_nowait((m, rx))
                except queue.Full:
                    self.stats.queue_overflow += 1
            self.flush_tlog()

    def _connect(self) -> Transport | None:
        """Open the transport (None on failure, the reason in :attr:`connect_error`); a
        reconnection is counted, said as a ``reconnect`` event, and asks for the streams."""
        try:
            tr = Transport(self.conn, self.baud)
        except OSError as e:  # e.g. a refused TCP connection: said while waiting
            self.connect_error = e.strerror or str(e) or type(e).__name__
            return None
        self.connect_error = None
        self.connected_at = time.monotonic()
        with self.writer.lock:
            self.writer.transport = tr
        self.reset_parser(count=True)
        if self.connected_once:
            self.stats.reconnect += 1
            self.events.append(LinkEvent(0.0, "reconnect", count=self.stats.reconnect,
                                         detail="TCP reconnected", source=self.conn))
            self.need_request = True
        self.connected_once = True
        return tr

    def reset_parser(self, count: bool = False) -> None:
        """Forget buffered bytes; with ``count``, count them (truncated frame / junk)."""
        kind = reset_parser(self.mav)
        if count and kind is not None:
            setattr(self.stats, kind, getattr(self.stats, kind) + 1)

    def drop_transport(self, tr: Transport) -> None:
        """After a read error: TCP and serial are closed and reopened with backoff; a UDP
        socket stays (an ICMP 'port unreachable' for udpout is not a broken socket)."""
        if tr.kind.startswith("udp"):
            self.stop.wait(0.05)
            return
        with self.writer.lock:
            tr.close()
            self.writer.transport = None

    def flush_tlog(self) -> None:
        if self.tlog is not None:
            self.tlog.flush()

    def close_tlog(self) -> None:
        if self.tlog is not None:
            self.tlog.close()
            self.tlog = None

    def handle(self, m: Any, rx_us: int, rx: float) -> bool:
        """One parsed message received at ``rx``: dropped and counted (False), or kept
        (True: recorded; the caller queues it)."""
        st = self.stats
        name = m.get_type()
        if name == "BAD_DATA":
            kind = bad_data_kind(m)
            setattr(st, kind, getattr(st, kind) + 1)
            return False
        if name.startswith("UNKNOWN"):
            st.unknown_message += 1
            return False
        if self.key is not None and not getattr(m, "_signed", False):
            st.unsigned += 1  # belt and braces: the parser should have refused it
            return False
        sysid = m.get_srcSystem()
        if name == "HEARTBEAT" and self.sysid in (None, sysid) and is_vehicle(m):
            if self.sysid is None:
                self.sysid = sysid
            self.on_vehicle(sysid, m.get_srcComponent(), int(m.type), int(m.autopilot))
            self.hb.set()
        if self.sysid is None:
            st.pre_heartbeat += 1
            return False
        if sysid != self.sysid:
            st.wrong_sysid += 1
            return False
        self._keep(m, name, rx_us, rx)
        return True

    def _keep(self, m: Any, name: str, rx_us: int, rx: float) -> None:
        """A message of the vehicle: rate, replies, tlog (the caller queues it)."""
        self.last_rx_mono = time.monotonic()
        self.rates.add(name, rx)
        if name == "COMMAND_ACK":
            self.replies.ack(int(m.command), int(m.result))
        elif name == "PARAM_VALUE":
            self.replies.param(param_name(m.param_id), float(m.param_value))
        if self.tlog is not None:
            self.tlog.add(rx_us, bytes(m.get_msgbuf()))
