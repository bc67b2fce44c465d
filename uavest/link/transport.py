"""Raw MAVLink bytes over UDP, TCP or a serial port, and the connection strings naming them.

Connection strings are pymavlink's: ``udpin:host:port`` (``udp:`` is the same; we listen
and answer whoever sent last), ``udpout:host:port`` (we send there), ``tcp:host:port``
(we connect; ``tcpout:`` is the same), ``tcpin:host:port`` (we listen for one client), or
a serial device ``/dev/ttyACM0`` / ``/dev/ttyUSB0,57600``. Anything else goes through
``pymavlink.mavutil`` unchanged.
"""

from __future__ import annotations

import contextlib
import select
import socket
import threading

from ..errors import InputError

__all__ = ["Disconnected", "Transport", "Writer", "endpoint_key", "is_vehicle_endpoint",
           "register_vehicle_endpoint", "split_conn", "unregister_vehicle_endpoint"]


def split_conn(conn: str) -> tuple[str, str]:
    """(kind, rest) of a connection string: kind ``udpin`` | ``udpout`` | ``tcp`` |
    ``tcpin`` | ``serial`` (a device, or anything pymavlink opens)."""
    if ":" not in conn:
        return "serial", conn
    scheme, rest = conn.split(":", 1)
    scheme = scheme.lower()
    aliases = {"udp": "udpin", "tcpout": "tcp"}
    scheme = aliases.get(scheme, scheme)
    if scheme not in ("udpin", "udpout", "tcp", "tcpin"):
        return "serial", conn
    return scheme, rest


def hostport(rest: str, default_host: str) -> tuple[str, int]:
    """(host, port) of ``host:port`` (an empty host is ``default_host``); InputError if the
    port is not a number."""
    host, _, port = rest.rpartition(":")
    if not port.isdigit():
        raise InputError(f"bad connection address {rest!r}: expected host:port")
    return (host or default_host), int(port)


def endpoint_key(conn: str) -> tuple:
    """A normalised (kind, address) key of a connection string, to compare two of them.

    UDP in/out and TCP client/server on the same host and port compare equal (a publisher
    there would talk to the vehicle's link); ``localhost`` and ``0.0.0.0`` count as
    127.0.0.1; a serial device compares by path.
    """
    scheme, rest = split_conn(str(conn))
    if scheme == "serial":
        return ("serial", rest.split(",")[0])
    host, port = hostport(rest, "127.0.0.1")
    if host in ("localhost", "0.0.0.0", ""):
        host = "127.0.0.1"
    return ("udp" if scheme.startswith("udp") else "tcp", host, port)


_ACTIVE: dict[tuple, int] = {}  # endpoint_key -> number of vehicle links open on it
_ACTIVE_LOCK = threading.Lock()


def register_vehicle_endpoint(conn: str) -> None:
    """Count one more vehicle link open on ``conn``'s endpoint (see
    :func:`is_vehicle_endpoint`)."""
    with _ACTIVE_LOCK:
        k = endpoint_key(conn)
        _ACTIVE[k] = _ACTIVE.get(k, 0) + 1


def unregister_vehicle_endpoint(conn: str) -> None:
    """Undo one :func:`register_vehicle_endpoint`."""
    with _ACTIVE_LOCK:
        k = endpoint_key(conn)
        _ACTIVE[k] -= 1


def is_vehicle_endpoint(conn: str) -> bool:
    """True if a vehicle link in this process is open on the same endpoint as ``conn``."""
    try:
        k = endpoint_key(conn)
    except ValueError:
        return False
    with _ACTIVE_LOCK:
        return _ACTIVE.get(k, 0) > 0


class Disconnected(ConnectionError):
    """The peer closed the connection or the read failed (TCP, serial)."""


class Transport:
    """Raw bytes over UDP, TCP or (through pymavlink's mavutil) a serial port.

    ``reply_all``: a ``udpin`` transport writes to every address that has sent to it
    (pymavlink's ``udpin``; the simulator) instead of to the last sender only (the live
    link). ``blocking``: False makes socket writes best effort (a full send buffer drops
    the write, as pymavlink does; the simulator must not be paced by a slow reader).
    """

    def __init__(self, conn: str, baud: int, *, reply_all: bool = False,
                 blocking: bool = True) -> None:
        self.conn = conn
        self.kind, rest = split_conn(conn)
        self.sock: socket.socket | None = None
        self.peer = None  # where writes go (UDP in: the last sender)
        self.peers: list = []  # UDP in with reply_all: every sender, in order of arrival
        self.reply_all = reply_all
        self.blocking = blocking
        self.serial = None
        self.listener: socket.socket | None = None
        if self.kind == "udpin":
            host, port = hostport(rest, "127.0.0.1")  # loopback unless the user writes one
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            self.sock.bind((host, port))
        elif self.kind == "udpout":
            self.peer = hostport(rest, "127.0.0.1")
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(("127.0.0.1" if self.peer[0].startswith("127.") else "0.0.0.0", 0))
        elif self.kind == "tcp":
            self.peer = hostport(rest, "127.0.0.1")
            self.sock = socket.create_connection(self.peer, timeout=2.0)
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        elif self.kind == "tcpin":
            self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.listener.bind(hostport(rest, "127.0.0.1"))
            self.listener.listen(1)
        else:
            from pymavlink import mavutil

            dev, _, b = rest.partition(",")
            self.serial = mavutil.mavlink_connection(dev, baud=int(b or baud))
        if self.sock is not None and not blocking:
            self.sock.setblocking(False)

    @property
    def connected(self) -> bool:
        """False only for a ``tcpin`` transport no client has connected to yet."""
        return self.listener is None or self.sock is not None

    def recv(self, timeout: float) -> bytes:
        """Bytes available within ``timeout`` s (b"" if none); raises Disconnected."""
        if self.serial is not None:
            if not self.serial.select(timeout):
                return b""
            return bytes(self.serial.recv(4096) or b"")
        if self.listener is not None and self.sock is None:
            r, _, _ = select.select([self.listener], [], [], timeout)
            if not r:
                return b""
            self.sock, _ = self.listener.accept()
            if not self.blocking:  # as pymavlink's tcpin
                self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.sock.setblocking(False)
            return b""
        r, _, _ = select.select([self.sock], [], [], timeout)
        if not r:
            return b""
        try:
            if self.kind.startswith("udp"):
                data, addr = self.sock.recvfrom(65536)
                if self.kind == "udpin":
                    self.peer = addr
                    if self.reply_all and addr not in self.peers:
                        self.peers.append(addr)
                return data
            data = self.sock.recv(65536)
        except BlockingIOError:
            return b""
        except (ConnectionError, OSError) as e:
            raise Disconnected(str(e)) from e
        if not data:
            if self.kind == "tcpin":
                self.sock.close()
                self.sock = None
                return b""
            raise Disconnected("connection closed by peer")
        return data

    def write(self, buf: bytes) -> None:
        """Send ``buf`` (best effort: a lost link shows as a gap, never as an error)."""
        try:
            if self.serial is not None:
                self.serial.write(buf)
            elif self.kind.startswith("udp"):
                if self.reply_all and self.peers:
                    for addr in self.peers:
                        self.sock.sendto(buf, addr)
                elif self.peer is not None:
                    self.sock.sendto(buf, self.peer)
            elif self.sock is not None:
                if self.blocking:
                    self.sock.sendall(buf)
                else:
                    self.sock.send(buf)
        except OSError:
            pass  # a lost link shows as a gap; sends are best effort

    def close(self) -> None:
        """Close the sockets / the serial port (idempotent, never raises)."""
        for s in (self.sock, self.listener):
            if s is not None:
                with contextlib.suppress(OSError):
                    s.close()
        if self.serial is not None:
            with contextlib.suppress(Exception):
                self.serial.close()


class Writer:
    """Thread-safe write target for a pymavlink ``MAVLink`` object (the current transport,
    None while disconnected)."""

    def __init__(self) -> None:
        self.transport: Transport | None = None
        self.lock = threading.Lock()

    def write(self, buf: bytes) -> None:
        with self.lock:
            if self.transport is not None:
                self.transport.write(bytes(buf))
