"""The simulator's MAVLink 2 endpoint: an ArduPilot-like autopilot on any pymavlink link.

:class:`Simulator` steps the truth (:mod:`.vehicle`, :mod:`.radar`) at the IMU rate and
sends, on the simulated boot clock, what an ArduPilot copter would send (see
``docs/sim.md`` for the message list, rates and units). Like an ArduPilot SITL it sends
only HEARTBEAT until asked: SET_MESSAGE_INTERVAL (COMMAND_LONG 511) and
REQUEST_DATA_STREAM (ArduPilot's stream groups, capped at 50 Hz) turn messages on;
radar detections (OBSTACLE_DISTANCE_3D) and ADSB_VEHICLE reports are sent unrequested
when the scenario enables the radar / ADS-B (SET_MESSAGE_INTERVAL with -1 stops them).

The parts: :mod:`.vehicle` (truth motion), :mod:`.sensors` (IMU, GPS, the autopilot's
estimate errors, ADS-B), :mod:`.radar`, :mod:`.protocol` (what is sent when, requests
answered, messages built), :mod:`.truth` (truth history and CSV) and
:mod:`uavest.link` (the transport and the frame encoder, shared with the live link).

Frames are encoded by one ``ardupilotmega`` MAVLink 2 encoder and written both to the
link and, optionally, to a telemetry log (8-byte big-endian microsecond timestamp +
frame, as MAVProxy writes ``.tlog``). Tlog timestamps are on the *simulated* clock
(``epoch + time since boot``, the same mapping SYSTEM_TIME reports), so a ``--speed 0``
run gives a byte-identical log for a given seed.
"""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav2

from ..errors import InputError
from ..geometry.geodesy import LocalFrame
from ..link import FrameEncoder, Transport, tlog_record
from ..link.spec import spec_params
from .protocol import EVENT, PERIODIC, STREAM_NAMES, STREAMS, Protocol
from .radar import Detection, Radar, Targets
from .sensors import GNSS_DELAY_S, AdsbReports, ImuModel, NavSensors, spec_noise
from .truth import TRUTH_COLUMNS, Chunk, Truth, TruthCsv, TruthHistory, VehicleTruth
from .vehicle import VehicleModel, stream_rng

Array = np.ndarray

__all__ = ["DEFAULT_EPOCH", "EVENT", "PERIODIC", "RunSummary", "STREAMS", "STREAM_NAMES",
           "Simulator", "TRUTH_COLUMNS", "Truth", "VehicleTruth"]

DEFAULT_EPOCH = 1767225600.0  # 2026-01-01T00:00:00Z, UNIX time of boot (scenario time.epoch)


@dataclass
class RunSummary:
    """What a :meth:`Simulator.run` did: simulated seconds, wall seconds, messages sent per
    type, and why it stopped (``duration``, ``stopped``)."""

    sim_time: float
    wall_time: float
    sent: Counter
    reason: str
    tlog: str | None = None
    steps: int = 0
    detections: int = 0

    def __str__(self) -> str:
        top = ", ".join(f"{k} {v}" for k, v in sorted(self.sent.items()))
        return (f"simulated {self.sim_time:.2f} s in {self.wall_time:.2f} s wall ({self.reason});"
                f" sent {sum(self.sent.values())} messages: {top}")


class Simulator:
    """Vehicle + radar simulator speaking MAVLink 2 (see module docstring): the
    composition of the vehicle, its sensors, the radar and targets, the protocol and the
    link, stepped at the IMU rate by :meth:`run`.

    Args:
      scenario: a typed ``kind = "sim"`` scenario (``SimScenario`` of
        :mod:`uavest.scenarios.schema`, from :func:`uavest.scenarios.load_typed`); its
        fields declare the units and ranges.
      seed: master seed; every random stream is ``default_rng([seed, crc32(name)])``.
      imu_rate: IMU sample rate = simulation step rate (Hz); default the scenario's
        ``imu.rate_hz`` (400).
      sysid: MAVLink system id (component id is 1, MAV_COMP_ID_AUTOPILOT1).
      rates: initial message / stream rates (Hz) as if requested, e.g.
        ``{"RAW_IMU": 200, "EXTRA1": 50}`` (stream names are capped at 50 Hz like
        REQUEST_DATA_STREAM); merged over the scenario's ``[mavlink.rates]``.
      history_s: seconds of vehicle truth kept for :meth:`truth_at` (None: all).
      state_spec: answer the sensors' datasheet as the ``SPEC_*`` parameters
        (:mod:`uavest.link.spec`); False: as an autopilot, which does not.
    """

    CHUNK_S = 0.5

    def __init__(
        self,
        scenario: Any,
        seed: int = 0,
        imu_rate: float | None = None,
        sysid: int = 1,
        rates: dict[str, float] | None = None,
        history_s: float | None = 3600.0,
        state_spec: bool = True,
    ) -> None:
        if isinstance(scenario, dict):
            raise TypeError("Simulator takes the typed scenario "
                            "(uavest.scenarios.load_typed), not its TOML dict")
        self.sc = scenario
        self.seed = int(seed)
        self.imu_rate = float(imu_rate or scenario.imu.rate_hz)
        if not 1.0 <= self.imu_rate <= 2000.0:
            raise InputError("imu rate must be within 1-2000 Hz")
        self.sysid = int(sysid)
        self.history_s = history_s
        self.state_spec = bool(state_spec)
        o = scenario.origin
        self.frame = LocalFrame(o.lat_deg, o.lon_deg, o.alt_m)
        epoch = scenario.time.epoch
        self.epoch = float(DEFAULT_EPOCH if epoch is None else epoch)
        # the parts
        self.vehicle = VehicleModel(scenario.vehicle, stream_rng(seed, "motion"))
        self.imu = ImuModel(scenario.imu, scenario.mag, self.imu_rate, seed)
        self.targets = Targets(scenario.targets)
        self.radar = Radar(scenario.radar, stream_rng(seed, "radar"))
        self.nav = NavSensors(scenario, self.imu_rate, seed, self.frame)
        self.adsb = AdsbReports(scenario.adsb, len(self.targets), seed)
        self.history = TruthHistory(self.vehicle, self.targets, self.frame, history_s)
        self._enc = FrameEncoder(self.sysid, 1)
        self.k = 0  # next IMU step
        self.protocol = Protocol(
            self._enc, self.sysid, self._send, lambda: round(self.k * self.dt_us), self.epoch,
            self.frame, self._make_params(), radar_enabled=self.radar.enabled,
            radar_active=len(self.targets) + self.radar.clutter_rate > 0,
            radar_rate=self.radar.rate, adsb_enabled=self.adsb.enabled,
            adsb_interval_us=self.adsb.interval_us)
        merged = dict(scenario.mavlink.rates or {})
        merged.update(rates or {})
        for name, hz in merged.items():
            self.set_rate(name, float(hz))
        self._init_run_state()

    def _init_run_state(self) -> None:
        """The clock, the next event times and the outputs of :meth:`run`."""
        self.t = 0.0
        self._next_gps_us = 0
        self._next_scan_us = 0
        n_t = len(self.targets)
        iv = self.protocol.adsb_interval_us
        self._next_adsb_us = [int(i * iv / max(n_t, 1)) for i in range(n_t)]
        self._next_hb_us = 0
        self._gps_iv = self._scan_iv = 0  # us between GPS fixes / radar scans (run)
        self.detections: list[tuple[float, list[Detection]]] = []
        self.sent: Counter = Counter()
        self.ready = threading.Event()
        self._rx = mav2.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        self._rx.robust_parsing = True
        self._conn: Transport | None = None
        self._tlog = None
        self._truth: TruthCsv | None = None
        self._n_det = 0
        self.received: Counter = Counter()

    # ------------------------------------------------------------------ params / rates

    def _make_params(self) -> dict[str, tuple[float, int]]:
        P = mav2
        spec = (spec_params({**spec_noise(self.sc), "gnss_delay": GNSS_DELAY_S})
                if self.state_spec else {})
        return {
            "COMPASS_DEC": (float(np.float32(self.imu.declination)), P.MAV_PARAM_TYPE_REAL32),
            "COMPASS_AUTODEC": (0.0, P.MAV_PARAM_TYPE_INT8),
            "SYSID_THISMAV": (float(self.sysid), P.MAV_PARAM_TYPE_INT16),
            "SCHED_LOOP_RATE": (float(round(self.imu_rate)), P.MAV_PARAM_TYPE_INT16),
            "AHRS_EKF_TYPE": (3.0, P.MAV_PARAM_TYPE_INT8),
            "SIM_SPEEDUP": (1.0, P.MAV_PARAM_TYPE_REAL32),
            # its sensors' datasheet (uavest.link.spec), for the estimator to take
            **{k: (float(np.float32(v)), P.MAV_PARAM_TYPE_REAL32) for k, v in spec.items()},
        }

    @property
    def dt_us(self) -> float:
        return 1e6 / self.imu_rate

    @property
    def params(self) -> dict[str, tuple[float, int]]:
        """The parameter list (name -> (value, MAV_PARAM_TYPE))."""
        return self.protocol.params

    def set_rate(self, name: str, hz: float) -> None:
        """Request a message (by name) or a data stream (RAW_SENSORS, EXTRA1, ..., ALL)
        at ``hz`` (0 = stop), as SET_MESSAGE_INTERVAL / REQUEST_DATA_STREAM would."""
        self.protocol.set_rate(name, hz)

    def set_stream(self, stream_id: int, hz: float) -> bool:
        """REQUEST_DATA_STREAM (:meth:`.protocol.Protocol.set_stream`)."""
        return self.protocol.set_stream(stream_id, hz)

    def set_interval(self, msg_id: int, interval_us: float) -> int:
        """SET_MESSAGE_INTERVAL (:meth:`.protocol.Protocol.set_interval`): a MAV_RESULT."""
        return self.protocol.set_interval(msg_id, interval_us)

    def interval_us(self, name: str) -> int | None:
        """Current interval (us) of a periodic message, None if off."""
        return self.protocol.interval_us(name)

    # ------------------------------------------------------------------ truth

    def _new_chunk(self) -> Chunk:
        n = max(1, int(round(self.CHUNK_S * self.imu_rate)))
        k = np.arange(self.k, self.k + n)
        t_us = np.round(k * self.dt_us).astype(np.int64)
        tr = self.vehicle.chunk(t_us * 1e-6)
        imu = self.imu.chunk(tr)
        lat, lon, h = self.frame.ned_to_geodetic(tr.pos)
        ch = Chunk(self.k, t_us, tr, imu, *self.nav.errors(n), np.column_stack([lat, lon, h]))
        self.history.push(ch)
        return ch

    def truth_at(self, t: float) -> Truth:
        """Truth of the vehicle and the targets at ``t`` (s since boot), within the
        simulated history (:meth:`.truth.TruthHistory.truth_at`)."""
        return self.history.truth_at(t, self.k * self.dt_us)

    @property
    def _chunks(self) -> list[Chunk]:
        return self.history.chunks

    # ------------------------------------------------------------------ link / tlog

    def _send(self, msg, t_us: int) -> None:
        buf = self._enc.encode(msg)
        if self._conn is not None:
            self._conn.write(buf)  # best effort: peer gone / buffer full, a real link drops
        if self._tlog is not None:
            self._tlog.write(tlog_record(int(self.epoch * 1e6) + t_us, buf))
        self.sent[msg.get_type()] += 1

    def _poll(self, t_us: int) -> bool:
        """Read and handle what the peer sent; True if anything arrived."""
        if self._conn is None:
            return False
        got = False
        for _ in range(64):
            try:
                data = self._conn.recv(0.0)
            except OSError:
                data = b""
            if not data:
                break
            msgs = self._rx.parse_buffer(data)
            for msg in msgs or ():
                got = True
                self.received[msg.get_type()] += 1
                self.protocol.handle(msg, t_us)
        return got

    def _open(self, conn: str | None) -> Transport | None:
        if conn is None or str(conn).lower() == "none":
            return None
        # as pymavlink's links: a UDP server answers every client, writes never block
        return Transport(str(conn), 115200, reply_all=True, blocking=False)

    # ------------------------------------------------------------------ sensors with events

    def _radar_scan(self, ch: Chunk, i: int) -> None:
        t = ch.t_us[i] * 1e-6
        P, _ = self.targets.state_at(t) if len(self.targets) else (np.zeros((0, 3)), None)
        dets = self.radar.scan(ch.truth.R[i], ch.truth.pos[i], P,
                               [tg.ident for tg in self.targets.targets])
        self.detections.append((float(t), dets))
        if self._truth is not None:
            self._truth.write_detections(t, dets)
        if self.history_s is not None:
            while self.detections and self.detections[0][0] < t - self.history_s:
                self.detections.pop(0)
        if not self.protocol.radar_on:
            return
        t_ms = int(ch.t_us[i]) // 1000
        for d in dets:
            self._send(self.protocol.obstacle(t_ms, d, self.radar.r_min, self.radar.r_max),
                       int(ch.t_us[i]))
        self._n_det += len(dets)

    def _adsb(self, j: int, t_us: int) -> None:
        tg = self.targets.targets[j]
        P, V = self.targets.state_at(t_us * 1e-6)
        p, v = self.adsb.report(P[j], V[j])
        self._send(self.protocol.adsb_vehicle(tg, p, v), t_us)

    # ------------------------------------------------------------------ main loop

    def _wait_gcs(self, stop: threading.Event) -> bool:
        """Before t = 0: wait for a peer (tcpin: a connection; UDP: any message), sending a
        HEARTBEAT every wall second (not logged). False if stopped first."""
        last = -math.inf
        while not stop.is_set():
            if self._conn.kind == "tcpin" and self._conn.connected:
                return True
            if time.monotonic() - last >= 1.0:
                last = time.monotonic()
                self._conn.write(self._enc.encode(self.protocol.heartbeat()))
            if self._poll(0):
                return True
            stop.wait(0.02)
        return False

    def run(
        self,
        conn: str | None = "udpout:127.0.0.1:14550",
        duration: float | None = None,
        speed: float = 1.0,
        stop_event: threading.Event | None = None,
        tlog: str | Path | None = None,
        wait_gcs: bool = False,
        send_params: bool = False,
        truth: str | Path | None = None,
        truth_rate: float = 10.0,
    ) -> RunSummary:
        """Simulate and send until ``duration`` simulated seconds (None: until stopped).

        Args:
          conn: pymavlink connection string (``udpout:127.0.0.1:14550``,
            ``tcpin:127.0.0.1:5760``, ...) or None / "none" for no link (tlog only).
          speed: simulated seconds per wall second (1 real time; 0 as fast as possible).
          stop_event: set it (e.g. from a signal handler or another thread) to stop
            cleanly after the current step.
          tlog: write everything sent to this telemetry log.
          wait_gcs: hold the clock at 0 until a peer shows up (see :meth:`_wait_gcs`).
          send_params: send the parameter list (PARAM_VALUE) once at t = 0, as if a
            ground station had asked (PARAM_REQUEST_LIST); handy for logs made without a
            peer so that they carry COMPASS_DEC.
          truth: write a truth CSV as the run goes (:data:`TRUTH_COLUMNS`; one row per
            object, vehicle and targets, every ``1 / truth_rate`` s, plus one row per
            radar detection with its origin), flushed every row block.
        Call once per Simulator (the clock is not rewound).
        """
        if duration is None and (conn is None or str(conn).lower() == "none"):
            raise InputError("without a link a duration is required")
        if self.k > 0:
            raise RuntimeError("Simulator.run was already called; make a new Simulator")
        stop = stop_event or threading.Event()
        speed = float(speed)
        self.params["SIM_SPEEDUP"] = (float(speed), mav2.MAV_PARAM_TYPE_REAL32)
        wall0 = time.monotonic()
        self._conn = self._open(conn)
        self._tlog = open(tlog, "wb") if tlog else None  # noqa: SIM115
        if truth:
            self._truth = TruthCsv(open(truth, "w"), self.targets, self.frame)  # noqa: SIM115
        try:
            self.ready.set()
            if wait_gcs and self._conn is not None and not self._wait_gcs(stop):
                return self._summary(wall0, "stopped", tlog)
            wall0 = time.monotonic()
            reason = self._loop(stop, duration, speed, wall0, send_params, truth_rate)
            return self._summary(wall0, reason, tlog)
        finally:
            self._close_outputs()

    def _loop(self, stop: threading.Event, duration: float | None, speed: float,
              wall0: float, send_params: bool, truth_rate: float) -> str:
        """Step until ``duration`` (``"duration"``) or ``stop`` (``"stopped"``), paced at
        ``speed`` simulated seconds per wall second (0: as fast as possible)."""
        end_us = None if duration is None else int(round(duration * 1e6))
        dt_us = self.dt_us
        self._gps_iv = int(round(1e6 / self.nav.gps_rate))
        self._scan_iv = int(round(1e6 / self.radar.rate))
        truth_iv = int(round(1e6 / truth_rate)) if truth_rate > 0 else None
        next_truth = 0
        ch = None
        while True:
            if stop.is_set():
                return "stopped"
            t_us = int(round(self.k * dt_us))
            if end_us is not None and t_us > end_us:
                return "duration"
            if ch is None or self.k >= ch.k0 + ch.t_us.size:
                ch = self._new_chunk()
            i = self.k - ch.k0
            self.t = t_us * 1e-6
            if speed > 0:  # pace against the wall clock
                lag = wall0 + self.t / speed - time.monotonic()
                if lag > 0.0005:
                    stop.wait(lag)
            self._poll(t_us)
            self._step(ch, i, t_us, params=send_params)
            send_params = False
            if self._truth is not None and truth_iv and t_us >= next_truth:
                self._truth.write_state(ch, i)
                next_truth += truth_iv
            self._step_adsb(t_us)
            self.k += 1

    def _step(self, ch: Chunk, i: int, t_us: int, params: bool = False) -> None:
        """What one IMU step sends: heartbeat, the parameter list once (``params``), GPS
        fix update, the requested-once and scheduled messages, a radar scan when due."""
        proto = self.protocol
        if ch.imu.mag_new[i]:
            proto.mag_seq += 1
        if t_us >= self._next_hb_us:
            self._send(proto.heartbeat(), t_us)
            self._next_hb_us += 1_000_000
        if params:
            for name in self.params:
                proto.send_param(name, t_us)
        if t_us >= self._next_gps_us:
            self.nav.gps_update(int(ch.t_us[i]), ch.truth.pos[i], ch.truth.vel[i])
            self._next_gps_us += self._gps_iv
        fix = self.nav.fix
        for name in proto.pending_once:
            self._send(proto.build(name, ch, i, fix), t_us)
        proto.pending_once.clear()
        for name, s in proto.sched.items():
            if t_us >= s.next_us:
                self._send(proto.build(name, ch, i, fix), t_us)
                s.next_us += s.interval_us
                if s.next_us <= t_us:
                    s.next_us = t_us + s.interval_us
        if t_us >= self._next_scan_us:
            self._radar_scan(ch, i)
            self._next_scan_us += self._scan_iv

    def _step_adsb(self, t_us: int) -> None:
        """The ADS-B reports due at ``t_us`` (one per target and interval)."""
        proto = self.protocol
        for j in range(len(self.targets)):
            if t_us >= self._next_adsb_us[j]:
                self._next_adsb_us[j] += proto.adsb_interval_us
                if proto.adsb_on and self.targets.targets[j].adsb:
                    self._adsb(j, t_us)

    def _close_outputs(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None
        if self._tlog is not None:
            self._tlog.close()
            self._tlog = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _summary(self, wall0: float, reason: str, tlog) -> RunSummary:
        return RunSummary(max(self.k - 1, 0) * self.dt_us * 1e-6, time.monotonic() - wall0,
                          Counter(self.sent), reason, None if tlog is None else str(tlog),
                          self.k, self._n_det)

