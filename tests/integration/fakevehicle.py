"""A small pymavlink fake vehicle for the live-link tests (real loopback sockets).

UDP mode: sends to the link's ``udpin`` port from its own socket and reads the link's
requests back on it.  TCP mode: listens like an ArduPilot SITL (optional text banner first).
It answers SET_MESSAGE_INTERVAL (accept / deny / silence), records REQUEST_DATA_STREAM,
answers PARAM_REQUEST_READ from ``params`` and streams the requested messages at the
requested rates with time fields from its own boot clock.
"""

from __future__ import annotations

import math
import select
import socket
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink


class _Out:
    def __init__(self, fv: FakeVehicle) -> None:
        self.fv = fv

    def write(self, buf: bytes) -> None:
        self.fv.send_raw(bytes(buf))


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


class FakeVehicle:
    def __init__(self, port: int, *, tcp: bool = False, sysid: int = 1, compid: int = 1,
                 ack: str = "accept", params: dict | None = None, banner: bytes = b"",
                 hb_rate: float = 10.0, rate_cap: dict | None = None,
                 signing_key: bytes | None = None, auto_streams: dict | None = None) -> None:
        self.port, self.tcp, self.ack = port, tcp, ack
        self.params = dict(params or {})
        self.banner = banner
        self.hb_rate = hb_rate
        self.rate_cap = rate_cap or {}
        self.mav = mavlink.MAVLink(_Out(self), srcSystem=sysid, srcComponent=compid)
        if signing_key is not None:
            self.mav.signing.secret_key = signing_key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        self.commands: list = []  # COMMAND_LONG received
        self.data_streams: list = []  # REQUEST_DATA_STREAM received
        self.param_reads: list = []
        self.sent: dict[str, list] = {}  # name -> monotonic send times (stream messages)
        self.streams: dict[str, float] = dict(auto_streams or {})  # name -> Hz being sent
        self.boot = time.monotonic()
        self.silent = False  # stop sending (link cut)
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self.sock = None
        self.client = None
        self.listener = None
        self.peer = ("127.0.0.1", port)
        if tcp:
            self._listen()
        else:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(("127.0.0.1", 0))
        self.thread = threading.Thread(target=self._run, daemon=True)

    # -------------------------------------------------------------- control
    def start(self) -> FakeVehicle:
        self.thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self.thread.is_alive():
            self.thread.join(timeout=5)
        for s in (self.sock, self.client, self.listener):
            if s is not None:
                s.close()

    def __enter__(self) -> FakeVehicle:
        return self.start()

    def __exit__(self, *a) -> None:
        self.stop()

    def _listen(self) -> None:
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", self.port))
        self.listener.listen(1)

    def tcp_down(self) -> None:
        """Close the TCP server and its client (as a SITL that exits)."""
        with self.lock:
            for s in (self.client, self.listener):
                if s is not None:
                    s.close()
            self.client = self.listener = None

    def tcp_up(self, reboot: bool = True) -> None:
        with self.lock:
            self._listen()
            if reboot:
                self.boot = time.monotonic()
                self.streams = {}

    def time_boot_ms(self) -> int:
        return int((time.monotonic() - self.boot) * 1000)

    def send_raw(self, buf: bytes) -> None:
        if self.silent:
            return
        try:
            if self.tcp:
                if self.client is not None:
                    self.client.sendall(buf)
            else:
                self.sock.sendto(buf, self.peer)
        except OSError:
            pass

    # -------------------------------------------------------------- loop
    def _run(self) -> None:
        next_hb = 0.0
        due: dict[str, float] = {}
        while not self._stop.is_set():
            now = time.monotonic()
            with self.lock:
                self._poll()
                if self.tcp and self.client is None:
                    continue
                if now >= next_hb:
                    self.mav.heartbeat_send(mavlink.MAV_TYPE_QUADROTOR,
                                            mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
                    next_hb = now + 1.0 / self.hb_rate
                for name, hz in list(self.streams.items()):
                    hz = min(hz, self.rate_cap.get(name, math.inf))
                    if hz <= 0:
                        continue
                    if now >= due.get(name, 0.0):
                        self._send_stream(name)
                        due[name] = max(due.get(name, now) + 1.0 / hz, now - 0.05)
            time.sleep(0.001)

    def _poll(self) -> None:
        socks = []
        if self.tcp:
            if self.listener is not None and self.client is None:
                r, _, _ = select.select([self.listener], [], [], 0)
                if r:
                    self.client, _ = self.listener.accept()
                    if self.banner:
                        self.client.sendall(self.banner)
            if self.client is not None:
                socks = [self.client]
        else:
            socks = [self.sock]
        for s in socks:
            r, _, _ = select.select([s], [], [], 0)
            if not r:
                continue
            try:
                data = s.recv(65536)
            except OSError:
                continue
            if self.tcp and not data:  # the client went away: accept the next one
                self.client.close()
                self.client = None
                continue
            for m in self.rx.parse_buffer(data) or []:
                self._on(m)

    def _on(self, m) -> None:
        t = m.get_type()
        if t == "COMMAND_LONG":
            self.commands.append(m)
            if m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                name = mavlink.mavlink_map[int(m.param1)].msgname
                if self.ack == "accept":
                    self.streams[name] = 1e6 / m.param2 if m.param2 > 0 else 0.0
                    self.mav.command_ack_send(m.command, mavlink.MAV_RESULT_ACCEPTED)
                elif self.ack == "deny":
                    self.mav.command_ack_send(m.command, mavlink.MAV_RESULT_DENIED)
        elif t == "REQUEST_DATA_STREAM":
            self.data_streams.append(m)
            groups = {1: ["RAW_IMU"], 10: ["ATTITUDE"], 6: ["GLOBAL_POSITION_INT"],
                      2: ["GPS_RAW_INT"], 12: ["SYSTEM_TIME"]}
            for name in groups.get(m.req_stream_id, []):
                self.streams[name] = float(m.req_message_rate)
        elif t == "PARAM_REQUEST_READ":
            pid = m.param_id if isinstance(m.param_id, str) else m.param_id.decode()
            self.param_reads.append(pid)
            if pid in self.params:
                self.mav.param_value_send(pid.encode(), float(self.params[pid]),
                                          mavlink.MAV_PARAM_TYPE_REAL32, len(self.params), 0)

    def _send_stream(self, name: str) -> None:
        if not self.silent:
            self.sent.setdefault(name, []).append(time.monotonic())
        tb = self.time_boot_ms()
        k = tb * 1e-3
        if name == "HIGHRES_IMU":
            self.mav.highres_imu_send(tb * 1000, 0.1, 0.0, -9.8, 0.01 * math.sin(k), 0.0, 0.0,
                                      0.2, 0.0, 0.4, 1013.0, 0, 0, 20.0, 0x3F)
        elif name == "RAW_IMU":
            self.mav.raw_imu_send(tb * 1000, 10, 0, -1000, 5, 0, 0, 200, 0, 400)
        elif name == "ATTITUDE":
            self.mav.attitude_send(tb, 0.01, 0.02, 0.3, 0, 0, 0)
        elif name == "ATTITUDE_QUATERNION":
            self.mav.attitude_quaternion_send(tb, 1.0, 0.0, 0.0, 0.0, 0, 0, 0)
        elif name == "GLOBAL_POSITION_INT":
            self.mav.global_position_int_send(tb, -353632610, 1491652300, 584000, 0, 100, 0,
                                              0, 0)
        elif name == "GPS_RAW_INT":
            self.mav.gps_raw_int_send(tb * 1000, 3, -353632610, 1491652300, 584000, 100, 100,
                                      0, 0, 10)
        elif name == "SYSTEM_TIME":
            self.mav.system_time_send(int(time.time() * 1e6), tb)
