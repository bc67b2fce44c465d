"""The simulator's MAVLink 2 endpoint: an ArduPilot-like autopilot on any pymavlink link.

:class:`Simulator` steps the truth (:mod:`.vehicle`, :mod:`.radar`) at the IMU rate and
sends, on the simulated boot clock, what an ArduPilot copter would send (see
``docs/sim.md`` for the message list, rates and units). Like an ArduPilot SITL it sends
only HEARTBEAT until asked: SET_MESSAGE_INTERVAL (COMMAND_LONG 511) and
REQUEST_DATA_STREAM (ArduPilot's stream groups, capped at 50 Hz) turn messages on;
radar detections (OBSTACLE_DISTANCE_3D) and ADSB_VEHICLE reports are sent unrequested
when the scenario enables the radar / ADS-B (SET_MESSAGE_INTERVAL with -1 stops them).

Frames are encoded by one ``ardupilotmega`` MAVLink 2 encoder and written both to the
link and, optionally, to a telemetry log (8-byte big-endian microsecond timestamp +
frame, as MAVProxy writes ``.tlog``). Tlog timestamps are on the *simulated* clock
(``epoch + time since boot``, the same mapping SYSTEM_TIME reports), so a ``--speed 0``
run gives a byte-identical log for a given seed.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before pymavlink.mavutil is imported anywhere by us

import bisect  # noqa: E402
import math  # noqa: E402
import struct  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav2  # noqa: E402

from ..errors import InputError
from ..geometry.geodesy import LocalFrame  # noqa: E402
from ..geometry.rotation import G0  # noqa: E402
from .radar import Detection, Radar, Targets  # noqa: E402
from .vehicle import (  # noqa: E402
    GaussMarkov,
    ImuChunk,
    ImuModel,
    TruthChunk,
    VehicleModel,
    stream_rng,
)

Array = np.ndarray

#: Columns of the truth CSV (``run(truth=...)`` / ``--truth``). ``kind`` is ``vehicle``
#: (id 0), ``target`` (id = obstacle id, origin = target index) or ``det`` (a radar
#: detection: id = obstacle_id sent, origin = target index or -1 for clutter, n/e/d =
#: the FRD x/y/z sent, a/b/c = range m, azimuth rad, elevation rad). Vehicle rows: a/b/c =
#: roll, pitch, yaw rad. NED m and m/s from the origin; lat/lon deg, alt m.
TRUTH_COLUMNS = ("t", "kind", "id", "origin", "n", "e", "d", "vn", "ve", "vd", "a", "b", "c",
                 "lat", "lon", "alt")
STREAM_CAP_HZ = 50.0  # ArduPilot's maximum data-stream rate (SRn_* parameters)
DEFAULT_EPOCH = 1767225600.0  # 2026-01-01T00:00:00Z, UNIX time of boot (scenario time.epoch)

#: ArduPilot (Copter) MAV_DATA_STREAM groups -> messages this simulator implements
#: (libraries/GCS_MAVLink/GCS_Common.cpp, ArduCopter/GCS_Mavlink.cpp). Note GPS_RAW_INT
#: is in EXTENDED_STATUS in ArduPilot, not RAW_SENSORS.
STREAMS: dict[int, tuple[str, ...]] = {
    mav2.MAV_DATA_STREAM_RAW_SENSORS: ("RAW_IMU", "SCALED_PRESSURE"),
    mav2.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS", "GPS_RAW_INT"),
    mav2.MAV_DATA_STREAM_POSITION: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    mav2.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE", "SIMSTATE"),
    mav2.MAV_DATA_STREAM_EXTRA2: ("VFR_HUD",),
    mav2.MAV_DATA_STREAM_EXTRA3: ("SYSTEM_TIME",),
}
STREAM_NAMES = {
    "RAW_SENSORS": mav2.MAV_DATA_STREAM_RAW_SENSORS,
    "EXTENDED_STATUS": mav2.MAV_DATA_STREAM_EXTENDED_STATUS,
    "POSITION": mav2.MAV_DATA_STREAM_POSITION,
    "EXTRA1": mav2.MAV_DATA_STREAM_EXTRA1,
    "EXTRA2": mav2.MAV_DATA_STREAM_EXTRA2,
    "EXTRA3": mav2.MAV_DATA_STREAM_EXTRA3,
}
#: periodic messages (scheduled by interval) and their MAVLink ids
PERIODIC = {
    name: getattr(mav2, f"MAVLINK_MSG_ID_{name}")
    for name in ("RAW_IMU", "HIGHRES_IMU", "SCALED_PRESSURE", "SYS_STATUS", "GPS_RAW_INT",
                 "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "SIMSTATE",
                 "VFR_HUD", "SYSTEM_TIME")
}
EVENT = {"OBSTACLE_DISTANCE_3D": mav2.MAVLINK_MSG_ID_OBSTACLE_DISTANCE_3D,
         "ADSB_VEHICLE": mav2.MAVLINK_MSG_ID_ADSB_VEHICLE,
         "HEARTBEAT": mav2.MAVLINK_MSG_ID_HEARTBEAT}
ID_TO_NAME = {v: k for k, v in {**PERIODIC, **EVENT}.items()}

ADSB_FLAGS = (mav2.ADSB_FLAGS_VALID_COORDS | mav2.ADSB_FLAGS_VALID_ALTITUDE
              | mav2.ADSB_FLAGS_VALID_HEADING | mav2.ADSB_FLAGS_VALID_VELOCITY
              | mav2.ADSB_FLAGS_VALID_CALLSIGN | mav2.ADSB_FLAGS_VALID_SQUAWK
              | mav2.ADSB_FLAGS_SIMULATED | mav2.ADSB_FLAGS_VERTICAL_VELOCITY_VALID)


def _i16(x: float) -> int:
    return int(max(-32768, min(32767, round(x))))


def _deg_e7(x: float) -> int:
    return int(round(x * 1e7))


def isa_pressure_hpa(alt_m: float) -> float:
    """ISA static pressure (hPa) at geopotential altitude ``alt_m`` (m, troposphere)."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_m) ** 5.25588


@dataclass
class VehicleTruth:
    """Vehicle truth at one time: NED position/velocity (m, m/s) from the origin,
    attitude ``q`` (body FRD -> NED, scalar-first), ``euler`` (roll, pitch, yaw rad),
    body rates ``omega`` (rad/s, FRD), specific force ``f_body`` (m/s^2, FRD), the IMU
    biases (FRD) and the geodetic position ``lla`` (deg, deg, m)."""

    t: float
    q: Array
    euler: Array
    omega: Array
    f_body: Array
    pos_ned: Array
    vel_ned: Array
    gyro_bias: Array
    accel_bias: Array
    lla: Array


@dataclass
class Truth:
    """Truth of the whole scene at time ``t`` (s since boot): the vehicle and the targets
    (``target_pos`` / ``target_vel`` (n, 3) NED m, m/s; ``target_lla`` (n, 3) deg, deg, m;
    ``target_ids`` the obstacle ids, ``target_icao`` the ICAO addresses)."""

    t: float
    vehicle: VehicleTruth
    target_pos: Array
    target_vel: Array
    target_lla: Array
    target_ids: list[int]
    target_icao: list[int]


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


class _Sink:
    """File-like object the encoder writes packed frames into."""

    def __init__(self) -> None:
        self.buf = b""

    def write(self, b: bytes) -> None:
        self.buf += b


@dataclass
class _Sched:
    interval_us: int
    next_us: int


@dataclass
class _Chunk:
    k0: int
    t_us: Array
    truth: TruthChunk
    imu: ImuChunk
    att_err: Array
    nav_err: Array
    vel_err: Array
    baro_err: Array
    lla: Array = field(default=None)  # (N, 3) deg, deg, m


class Simulator:
    """Vehicle + radar simulator speaking MAVLink 2 (see module docstring).

    Args:
      scenario: a ``kind = "sim"`` scenario dict (:func:`uavest.scenarios.load_scenario`).
      seed: master seed; every random stream is ``default_rng([seed, crc32(name)])``.
      imu_rate: IMU sample rate = simulation step rate (Hz); default the scenario's
        ``imu.rate_hz`` (400).
      sysid: MAVLink system id (component id is 1, MAV_COMP_ID_AUTOPILOT1).
      rates: initial message / stream rates (Hz) as if requested, e.g.
        ``{"RAW_IMU": 200, "EXTRA1": 50}`` (stream names are capped at 50 Hz like
        REQUEST_DATA_STREAM); merged over the scenario's ``[mavlink.rates]``.
      history_s: seconds of vehicle truth kept for :meth:`truth_at` (None: all).
    """

    CHUNK_S = 0.5

    def __init__(
        self,
        scenario: dict,
        seed: int = 0,
        imu_rate: float | None = None,
        sysid: int = 1,
        rates: dict[str, float] | None = None,
        history_s: float | None = 3600.0,
    ) -> None:
        self.sc = scenario
        self.seed = int(seed)
        imu_cfg = scenario.get("imu", {})
        self.imu_rate = float(imu_rate or imu_cfg.get("rate_hz", 400.0))
        if not 1.0 <= self.imu_rate <= 2000.0:
            raise InputError("imu rate must be within 1-2000 Hz")
        self.sysid = int(sysid)
        self.history_s = history_s
        o = scenario.get("origin", {})
        self.frame = LocalFrame(o.get("lat_deg", 0.0), o.get("lon_deg", 0.0), o.get("alt_m", 0.0))
        self.epoch = float(scenario.get("time", {}).get("epoch", DEFAULT_EPOCH))
        self.vehicle = VehicleModel(scenario.get("vehicle", {}), stream_rng(seed, "motion"))
        self.imu = ImuModel(imu_cfg, scenario.get("mag", {}), self.imu_rate, seed)
        self.targets = Targets(scenario.get("targets", []))
        self.radar = Radar(scenario.get("radar", {}), stream_rng(seed, "radar"))
        a = scenario.get("adsb", {})
        self.adsb_enabled = bool(a.get("enabled", True)) and len(self.targets) > 0
        self.adsb_interval_us = int(1e6 / float(a.get("rate_hz", 1.0)))
        self.adsb_sigma = (float(a.get("sigma_h", 3.0)), float(a.get("sigma_v", 5.0)),
                           float(a.get("sigma_vel", 0.3)))
        self.adsb_rng = stream_rng(seed, "adsb")
        g = scenario.get("gps", {})
        self.gps_rate = float(g.get("rate_hz", 5.0))
        dt_gps = 1.0 / self.gps_rate
        self.gps_err = GaussMarkov([g.get("sigma_h", 0.8)] * 2 + [g.get("sigma_v", 1.5)],
                                   float(g.get("tau_s", 60.0)), dt_gps, stream_rng(seed, "gps"))
        self.gps_vel_sigma = float(g.get("sigma_vel", 0.1))
        self.gps_rng = stream_rng(seed, "gps.vel")
        ah = scenario.get("ahrs", {})
        dt = 1.0 / self.imu_rate
        self.att_err = GaussMarkov(
            np.deg2rad([ah.get("roll_err_deg", 1.0), ah.get("pitch_err_deg", 1.0),
                        ah.get("yaw_err_deg", 2.0)]),
            float(ah.get("tau_s", 30.0)), dt, stream_rng(seed, "ahrs"))
        self.nav_err = GaussMarkov([ah.get("pos_err_m", 0.3)] * 3, float(ah.get("tau_s", 30.0)),
                                   dt, stream_rng(seed, "nav"))
        self.vel_err = GaussMarkov([ah.get("vel_err", 0.05)] * 3, 2.0, dt,
                                   stream_rng(seed, "nav.vel"))
        self.baro_err = GaussMarkov([scenario.get("baro", {}).get("sigma_m", 0.5)], 20.0, dt,
                                    stream_rng(seed, "baro"))
        self.params = self._make_params()
        # MAVLink state
        self.k = 0  # next IMU step
        self.stream_hz: dict[int, float] = {}
        self.override_us: dict[str, int | None] = {}  # None = disabled (-1)
        self.sched: dict[str, _Sched] = {}
        self.radar_on = self.radar.enabled and len(self.targets) + self.radar.clutter_rate > 0
        self.adsb_on = self.adsb_enabled
        merged = dict(scenario.get("mavlink", {}).get("rates", {}))
        merged.update(rates or {})
        for name, hz in merged.items():
            self.set_rate(name, float(hz))
        # run state
        self.t = 0.0
        self._hist: tuple[list[_Chunk], list[int]] = ([], [])
        self._gps_fix: dict | None = None
        self._next_gps_us = 0
        self._next_scan_us = 0
        n_t = len(self.targets)
        self._next_adsb_us = [int(i * self.adsb_interval_us / max(n_t, 1)) for i in range(n_t)]
        self._next_hb_us = 0
        self._mag_seq = 0
        self._mag_seq_sent = -1
        self.detections: list[tuple[float, list[Detection]]] = []
        self.sent: Counter = Counter()
        self.ready = threading.Event()
        self._enc = mav2.MAVLink(_Sink(), srcSystem=self.sysid, srcComponent=1)
        self._rx = mav2.MAVLink(None, srcSystem=self.sysid, srcComponent=1)
        self._rx.robust_parsing = True
        self._conn = None
        self._tlog = None
        self._truth = None
        self._pending_once: list[str] = []
        self._n_det = 0
        self.received: Counter = Counter()

    # ------------------------------------------------------------------ params / rates

    def _make_params(self) -> dict[str, tuple[float, int]]:
        P = mav2
        return {
            "COMPASS_DEC": (float(np.float32(self.imu.declination)), P.MAV_PARAM_TYPE_REAL32),
            "COMPASS_AUTODEC": (0.0, P.MAV_PARAM_TYPE_INT8),
            "SYSID_THISMAV": (float(self.sysid), P.MAV_PARAM_TYPE_INT16),
            "SCHED_LOOP_RATE": (float(round(self.imu_rate)), P.MAV_PARAM_TYPE_INT16),
            "AHRS_EKF_TYPE": (3.0, P.MAV_PARAM_TYPE_INT8),
            "SIM_SPEEDUP": (1.0, P.MAV_PARAM_TYPE_REAL32),
        }

    @property
    def dt_us(self) -> float:
        return 1e6 / self.imu_rate

    def set_rate(self, name: str, hz: float) -> None:
        """Request a message (by name) or a data stream (RAW_SENSORS, EXTRA1, ..., ALL)
        at ``hz`` (0 = stop), as SET_MESSAGE_INTERVAL / REQUEST_DATA_STREAM would."""
        name = name.upper()
        if name == "ALL" or name in STREAM_NAMES:
            self.set_stream(0 if name == "ALL" else STREAM_NAMES[name], hz)
        elif name in PERIODIC or name in EVENT:
            self.set_interval({**PERIODIC, **EVENT}[name], -1 if hz <= 0 else 1e6 / hz)
        else:
            raise InputError(f"unknown message or stream {name!r}; known: "
                             + ", ".join(list(STREAM_NAMES) + list(PERIODIC) + list(EVENT)))

    def set_stream(self, stream_id: int, hz: float) -> bool:
        """REQUEST_DATA_STREAM: rate (Hz, capped at 50; 0 stops) for a stream (0 = all)."""
        hz = min(max(float(hz), 0.0), STREAM_CAP_HZ)
        ids = list(STREAMS) if stream_id == mav2.MAV_DATA_STREAM_ALL else [stream_id]
        if not all(i in STREAMS for i in ids):
            return False
        for i in ids:
            self.stream_hz[i] = hz
        self._reschedule()
        return True

    def set_interval(self, msg_id: int, interval_us: float) -> int:
        """SET_MESSAGE_INTERVAL semantics; returns a MAV_RESULT. ``interval_us`` -1
        disables, 0 restores the default (the message's stream rate; radar/ADS-B: on)."""
        name = ID_TO_NAME.get(int(msg_id))
        if name is None:
            return mav2.MAV_RESULT_DENIED
        iv = float(interval_us)
        if name == "HEARTBEAT":
            return mav2.MAV_RESULT_ACCEPTED if iv in (0.0, 1e6) else mav2.MAV_RESULT_DENIED
        if name == "OBSTACLE_DISTANCE_3D":
            self.radar_on = self.radar.enabled and iv != -1
            return mav2.MAV_RESULT_ACCEPTED
        if name == "ADSB_VEHICLE":
            self.adsb_on = self.adsb_enabled and iv != -1
            if iv > 0:
                self.adsb_interval_us = int(iv)
            return mav2.MAV_RESULT_ACCEPTED
        if iv == 0:
            self.override_us.pop(name, None)
        elif iv < 0:
            self.override_us[name] = None
        else:
            self.override_us[name] = max(1, int(round(iv)))
        self._reschedule()
        return mav2.MAV_RESULT_ACCEPTED

    def interval_us(self, name: str) -> int | None:
        """Current interval (us) of a periodic message, None if off."""
        if name in self.override_us:
            return self.override_us[name]
        hz = max((self.stream_hz.get(s, 0.0) for s, msgs in STREAMS.items() if name in msgs),
                 default=0.0)
        return int(round(1e6 / hz)) if hz > 0 else None

    def _reschedule(self) -> None:
        now = int(round(self.k * self.dt_us))
        for name in PERIODIC:
            iv = self.interval_us(name)
            old = self.sched.get(name)
            if iv is None:
                self.sched.pop(name, None)
            elif old is None:
                self.sched[name] = _Sched(iv, now)
            elif old.interval_us != iv:
                self.sched[name] = _Sched(iv, min(old.next_us, now + iv))

    # ------------------------------------------------------------------ truth

    def _new_chunk(self) -> _Chunk:
        n = max(1, int(round(self.CHUNK_S * self.imu_rate)))
        k = np.arange(self.k, self.k + n)
        t_us = np.round(k * self.dt_us).astype(np.int64)
        tr = self.vehicle.chunk(t_us * 1e-6)
        imu = self.imu.chunk(tr)
        lat, lon, h = self.frame.ned_to_geodetic(tr.pos)
        ch = _Chunk(self.k, t_us, tr, imu, self.att_err.run(n), self.nav_err.run(n),
                    self.vel_err.run(n), self.baro_err.run(n)[:, 0],
                    np.column_stack([lat, lon, h]))
        chunks = self._hist[0] + [ch]
        if self.history_s is not None:
            keep = self.history_s * 1e6
            while len(chunks) > 2 and chunks[1].t_us[0] < t_us[-1] - keep:
                chunks.pop(0)
        # new lists (not in-place edits) so that truth_at in another thread sees a
        # consistent pair
        self._hist = (chunks, [int(c.t_us[0]) for c in chunks])
        return ch

    def truth_at(self, t: float) -> Truth:
        """Truth of the vehicle and the targets at ``t`` (s since boot). The vehicle part
        needs ``t`` within the simulated history (kept ``history_s``); position and
        velocity are linearly interpolated between IMU steps, attitude and rates are
        evaluated exactly, biases taken at the step before ``t``."""
        t_us = t * 1e6
        chunks, starts = self._hist  # one tuple, replaced (never mutated) by the sim
        n = bisect.bisect_right(starts, t_us + 1e-6) - 1
        # the newest step may still be unsent: only times up to the current step count
        if n < 0 or t_us > min(chunks[-1].t_us[-1], self.k * self.dt_us) + 1e-6:
            raise ValueError(f"t = {t} s is outside the simulated history")
        ch = chunks[n]
        i = int(np.searchsorted(ch.t_us, t_us, side="right") - 1)
        if i + 1 < ch.t_us.size:
            c2, j = ch, i + 1
        elif n + 1 < len(chunks):
            c2, j = chunks[n + 1], 0
        else:
            c2, j = ch, i
        span = c2.t_us[j] - ch.t_us[i]
        s = 0.0 if span == 0 else (t_us - ch.t_us[i]) / span
        tr, tr2 = ch.truth, c2.truth
        pos = (1 - s) * tr.pos[i] + s * tr2.pos[j]
        vel = (1 - s) * tr.vel[i] + s * tr2.vel[j]
        f_b = (1 - s) * tr.f_body[i] + s * tr2.f_body[j]
        from ..geometry.rotation import euler_to_quat
        from .vehicle import body_rates

        val, rate = self.vehicle.man.eval(np.array([t]))
        e = val[0, :3].copy()
        q = euler_to_quat(e[0], e[1], e[2])
        om = body_rates(val[:, :3], rate[:, :3])[0]
        e[2] = (e[2] + np.pi) % (2 * np.pi) - np.pi
        lat, lon, h = self.frame.ned_to_geodetic(pos)
        vt = VehicleTruth(t, q, e, om, f_b, pos, vel, ch.imu.gyro_bias[i].copy(),
                          ch.imu.accel_bias[i].copy(), np.array([lat, lon, h], float))
        P, V = self.targets.state_at(t) if len(self.targets) else (np.zeros((0, 3)),) * 2
        la, lo, hh = self.frame.ned_to_geodetic(P)
        return Truth(t, vt, P, V, np.column_stack([la, lo, hh]),
                     [tg.ident for tg in self.targets.targets],
                     [tg.icao for tg in self.targets.targets])

    # ------------------------------------------------------------------ encoding / io

    def _send(self, msg, t_us: int) -> None:
        self._enc.file.buf = b""
        self._enc.send(msg)
        buf = self._enc.file.buf
        if self._conn is not None:
            try:
                self._conn.write(buf)
            except OSError:
                pass  # peer gone / buffer full: a real link drops too
        if self._tlog is not None:
            self._tlog.write(struct.pack(">Q", int(self.epoch * 1e6) + t_us) + buf)
        self.sent[msg.get_type()] += 1

    def _heartbeat(self):
        m = mav2
        return self._enc.heartbeat_encode(
            m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_ARDUPILOTMEGA,
            m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_SAFETY_ARMED
            | m.MAV_MODE_FLAG_STABILIZE_ENABLED | m.MAV_MODE_FLAG_GUIDED_ENABLED,
            4, m.MAV_STATE_ACTIVE)  # custom_mode 4 = GUIDED

    def _poll(self, t_us: int) -> bool:
        """Read and handle what the peer sent; True if anything arrived."""
        if self._conn is None:
            return False
        got = False
        for _ in range(64):
            try:
                data = self._conn.recv(4096)
            except OSError:
                data = b""
            if not data:
                break
            msgs = self._rx.parse_buffer(bytes(data) if not isinstance(data, bytes) else data)
            for msg in msgs or ():
                got = True
                self.received[msg.get_type()] += 1
                self._handle(msg, t_us)
        return got

    def _for_me(self, msg) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.sysid) and tc in (0, 1)

    def _handle(self, msg, t_us: int) -> None:
        typ = msg.get_type()
        e = self._enc
        if typ == "COMMAND_LONG" and self._for_me(msg):
            cmd = msg.command
            if cmd == mav2.MAV_CMD_SET_MESSAGE_INTERVAL:
                res = self.set_interval(int(msg.param1), msg.param2)
            elif cmd == mav2.MAV_CMD_GET_MESSAGE_INTERVAL:
                name = ID_TO_NAME.get(int(msg.param1))
                res = mav2.MAV_RESULT_ACCEPTED if name else mav2.MAV_RESULT_DENIED
                if name:
                    self._send(e.message_interval_encode(int(msg.param1),
                                                         self._report_interval(name)), t_us)
            elif cmd == mav2.MAV_CMD_REQUEST_MESSAGE:
                name = ID_TO_NAME.get(int(msg.param1))
                res = mav2.MAV_RESULT_ACCEPTED if name in PERIODIC or name == "HEARTBEAT" \
                    else mav2.MAV_RESULT_DENIED
                if res == mav2.MAV_RESULT_ACCEPTED:
                    self._pending_once.append(name)
            else:
                res = mav2.MAV_RESULT_UNSUPPORTED
            self._send(e.command_ack_encode(cmd, res, 0, 0, msg.get_srcSystem(),
                                            msg.get_srcComponent()), t_us)
        elif typ == "REQUEST_DATA_STREAM" and self._for_me(msg):
            if msg.start_stop in (0, 1):
                self.set_stream(msg.req_stream_id, msg.req_message_rate if msg.start_stop else 0)
        elif typ == "PARAM_REQUEST_READ" and self._for_me(msg):
            names = list(self.params)
            pid = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else \
                msg.param_id.decode(errors="replace").rstrip("\x00")
            if msg.param_index >= 0:
                if msg.param_index < len(names):
                    self._send_param(names[msg.param_index], t_us)
            elif pid in self.params:
                self._send_param(pid, t_us)
        elif typ == "PARAM_REQUEST_LIST" and self._for_me(msg):
            for name in self.params:
                self._send_param(name, t_us)
        elif typ == "PARAM_SET" and self._for_me(msg):
            pid = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else \
                msg.param_id.decode(errors="replace").rstrip("\x00")
            if pid in self.params:  # stored (what the autopilot believes), physics unchanged
                self.params[pid] = (float(np.float32(msg.param_value)), self.params[pid][1])
                self._send_param(pid, t_us)

    def _report_interval(self, name: str) -> int:
        if name == "HEARTBEAT":
            return 1_000_000
        if name == "OBSTACLE_DISTANCE_3D":
            return int(1e6 / self.radar.rate) if self.radar_on else -1
        if name == "ADSB_VEHICLE":
            return self.adsb_interval_us if self.adsb_on else -1
        iv = self.interval_us(name)
        return -1 if iv is None else iv

    def _send_param(self, name: str, t_us: int) -> None:
        names = list(self.params)
        v, typ = self.params[name]
        self._send(self._enc.param_value_encode(name.encode(), v, typ, len(names),
                                                names.index(name)), t_us)

    # ------------------------------------------------------------------ message builders

    def _build(self, name: str, ch: _Chunk, i: int):
        e = self._enc
        t_us = int(ch.t_us[i])
        t_ms = t_us // 1000
        tr, imu = ch.truth, ch.imu
        lat, lon, h = ch.lla[i]
        if name == "RAW_IMU":
            a = imu.accel[i] / G0 * 1000.0
            g = imu.gyro[i] * 1000.0
            m = imu.mag[i] * 1000.0
            return e.raw_imu_encode(t_us, _i16(a[0]), _i16(a[1]), _i16(a[2]), _i16(g[0]),
                                    _i16(g[1]), _i16(g[2]), _i16(m[0]), _i16(m[1]), _i16(m[2]),
                                    0, 3500)
        if name == "HIGHRES_IMU":
            a, g, m = imu.accel[i], imu.gyro[i], imu.mag[i]
            upd = 0x3F | 0x200 | 0x800 | 0x1000
            if self._mag_seq != self._mag_seq_sent:
                upd |= 0x1C0
                self._mag_seq_sent = self._mag_seq
            alt = h + ch.baro_err[i]
            return e.highres_imu_encode(t_us, *map(float, a), *map(float, g), *map(float, m),
                                        isa_pressure_hpa(alt), 0.0, float(alt), 35.0, upd, 0)
        if name == "SCALED_PRESSURE":
            return e.scaled_pressure_encode(t_ms, isa_pressure_hpa(h + ch.baro_err[i]), 0.0,
                                            3500, 0)
        if name == "GPS_RAW_INT":
            f = self._gps_fix
            if f is None:  # no fix yet: no GNSS time either (ArduPilot sends 0)
                return e.gps_raw_int_encode(0, 1, 0, 0, 0, 65535, 65535, 65535, 65535, 0)
            vn, ve, vd = f["vel"]
            cog = int(round(math.degrees(math.atan2(ve, vn)) * 100)) % 36000
            # time_usec: the fix's UNIX (GNSS) time, as ArduPilot sends it, not boot time
            return e.gps_raw_int_encode(
                int(self.epoch * 1e6) + f["t_us"], 3, _deg_e7(f["lat"]), _deg_e7(f["lon"]),
                int(round(f["alt"] * 1e3)),
                70, 110, int(round(math.hypot(vn, ve) * 100)), cog, 14,
                int(round(f["alt"] * 1e3)), 800, 1500, 150, 0, 0)
        if name in ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"):
            p = tr.pos[i] + ch.nav_err[i]
            v = tr.vel[i] + ch.vel_err[i]
            if name == "LOCAL_POSITION_NED":
                return e.local_position_ned_encode(t_ms, *map(float, p), *map(float, v))
            la, lo, hh = self.frame.ned_to_geodetic(p)
            hdg = int(round(math.degrees(tr.euler[i, 2]) * 100)) % 36000
            return e.global_position_int_encode(
                t_ms, _deg_e7(float(la)), _deg_e7(float(lo)), int(round(float(hh) * 1e3)),
                int(round((float(hh) - self.frame.h0) * 1e3)),
                _i16(v[0] * 100), _i16(v[1] * 100), _i16(v[2] * 100), hdg)
        if name == "ATTITUDE":
            eu = tr.euler[i] + ch.att_err[i]
            eu[2] = (eu[2] + np.pi) % (2 * np.pi) - np.pi
            w = tr.omega[i]
            return e.attitude_encode(t_ms, *map(float, eu), *map(float, w))
        if name == "SIMSTATE":
            eu, f, w = tr.euler[i], tr.f_body[i], tr.omega[i]
            return e.simstate_encode(*map(float, eu), *map(float, f), *map(float, w),
                                     _deg_e7(lat), _deg_e7(lon))
        if name == "SYSTEM_TIME":
            return e.system_time_encode(int(self.epoch * 1e6) + t_us, t_ms)
        if name == "SYS_STATUS":
            bits = 1 | 2 | 4 | 8 | 32  # gyro, accel, mag, abs pressure, GPS
            return e.sys_status_encode(bits, bits, bits, 200, 16000, -1, -1, 0, 0, 0, 0, 0, 0)
        if name == "VFR_HUD":
            v = tr.vel[i]
            gs = float(math.hypot(v[0], v[1]))
            hdg = int(round(math.degrees(tr.euler[i, 2]))) % 360
            thr = int(round(min(100.0, 50.0 * -tr.f_body[i, 2] / G0)))
            return e.vfr_hud_encode(gs, gs, hdg, thr, float(h), float(-v[2]))
        if name == "HEARTBEAT":
            return self._heartbeat()
        raise KeyError(name)

    # ------------------------------------------------------------------ sensors with events

    def _gps_update(self, ch: _Chunk, i: int) -> None:
        err = self.gps_err.step()
        tr = ch.truth
        p = tr.pos[i] + err
        la, lo, hh = self.frame.ned_to_geodetic(p)
        v = tr.vel[i] + self.gps_rng.standard_normal(3) * self.gps_vel_sigma
        self._gps_fix = {"t_us": int(ch.t_us[i]), "lat": float(la), "lon": float(lo),
                         "alt": float(hh), "vel": v}

    def _radar_scan(self, ch: _Chunk, i: int) -> None:
        t = ch.t_us[i] * 1e-6
        P, _ = self.targets.state_at(t) if len(self.targets) else (np.zeros((0, 3)), None)
        dets = self.radar.scan(ch.truth.R[i], ch.truth.pos[i], P,
                               [tg.ident for tg in self.targets.targets])
        self.detections.append((float(t), dets))
        if self._truth is not None:
            rows = []
            for d in dets:
                r, az, el = d.rae
                rows.append(f"{t:.6f},det,{d.obstacle_id},{d.origin},{d.xyz[0]:.3f},"
                            f"{d.xyz[1]:.3f},{d.xyz[2]:.3f},,,,{r:.3f},{az:.6f},{el:.6f},,,")
            if rows:
                self._truth.write("\n".join(rows) + "\n")
        if self.history_s is not None:
            while self.detections and self.detections[0][0] < t - self.history_s:
                self.detections.pop(0)
        if not self.radar_on:
            return
        t_ms = int(ch.t_us[i]) // 1000
        for d in dets:
            self._send(self._enc.obstacle_distance_3d_encode(
                t_ms, mav2.MAV_DISTANCE_SENSOR_RADAR, mav2.MAV_FRAME_BODY_FRD, d.obstacle_id,
                *map(float, d.xyz), self.radar.r_min, self.radar.r_max), int(ch.t_us[i]))
        self._n_det += len(dets)

    def _adsb(self, j: int, t_us: int) -> None:
        tg = self.targets.targets[j]
        P, V = self.targets.state_at(t_us * 1e-6)
        sh, sv, svel = self.adsb_sigma
        r = self.adsb_rng
        p = P[j] + r.standard_normal(3) * np.array([sh, sh, sv])
        v = V[j] + r.standard_normal(3) * svel
        la, lo, hh = self.frame.ned_to_geodetic(p)
        hdg = int(round(math.degrees(math.atan2(v[1], v[0])) * 100)) % 36000
        self._send(self._enc.adsb_vehicle_encode(
            tg.icao, _deg_e7(float(la)), _deg_e7(float(lo)), mav2.ADSB_ALTITUDE_TYPE_GEOMETRIC,
            int(round(float(hh) * 1e3)), hdg, int(min(65535, round(math.hypot(v[0], v[1]) * 100))),
            _i16(-v[2] * 100), tg.name.encode(), tg.emitter, 0, ADSB_FLAGS, 1200), t_us)

    # ------------------------------------------------------------------ main loop

    def _open(self, conn: str | None):
        if conn is None or str(conn).lower() == "none":
            return None
        from pymavlink import mavutil

        return mavutil.mavlink_connection(conn, source_system=self.sysid, source_component=1)

    def _wait_gcs(self, conn: str, stop: threading.Event) -> bool:
        """Before t = 0: wait for a peer (tcpin: a connection; UDP: any message), sending a
        HEARTBEAT every wall second (not logged). False if stopped first."""
        last = -math.inf
        while not stop.is_set():
            if conn.startswith("tcpin") and getattr(self._conn, "port", None) is not None:
                return True
            if time.monotonic() - last >= 1.0:
                last = time.monotonic()
                self._enc.file.buf = b""
                self._enc.send(self._heartbeat())
                try:
                    self._conn.write(self._enc.file.buf)
                except OSError:
                    pass
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
        reason = "duration"
        self._conn = self._open(conn)
        self._tlog = open(tlog, "wb") if tlog else None  # noqa: SIM115
        self._truth = open(truth, "w") if truth else None  # noqa: SIM115
        if self._truth is not None:
            self._truth.write(",".join(TRUTH_COLUMNS) + "\n")
        truth_iv = int(round(1e6 / truth_rate)) if truth_rate > 0 else None
        next_truth = 0
        try:
            self.ready.set()
            if wait_gcs and self._conn is not None and not self._wait_gcs(str(conn), stop):
                reason = "stopped"
                return self._summary(wall0, reason, tlog)
            wall0 = time.monotonic()
            end_us = None if duration is None else int(round(duration * 1e6))
            dt_us = self.dt_us
            gps_iv = int(round(1e6 / self.gps_rate))
            scan_iv = int(round(1e6 / self.radar.rate))
            ch = None
            while True:
                if stop.is_set():
                    reason = "stopped"
                    break
                t_us = int(round(self.k * dt_us))
                if end_us is not None and t_us > end_us:
                    break
                if ch is None or self.k >= ch.k0 + ch.t_us.size:
                    ch = self._new_chunk()
                i = self.k - ch.k0
                self.t = t_us * 1e-6
                if speed > 0:  # pace against the wall clock
                    lag = wall0 + self.t / speed - time.monotonic()
                    if lag > 0.0005:
                        stop.wait(lag)
                self._poll(t_us)
                if ch.imu.mag_new[i]:
                    self._mag_seq += 1
                if t_us >= self._next_hb_us:
                    self._send(self._heartbeat(), t_us)
                    self._next_hb_us += 1_000_000
                if send_params:
                    send_params = False
                    for name in self.params:
                        self._send_param(name, t_us)
                if t_us >= self._next_gps_us:
                    self._gps_update(ch, i)
                    self._next_gps_us += gps_iv
                for name in self._pending_once:
                    self._send(self._build(name, ch, i), t_us)
                self._pending_once.clear()
                for name, s in self.sched.items():
                    if t_us >= s.next_us:
                        self._send(self._build(name, ch, i), t_us)
                        s.next_us += s.interval_us
                        if s.next_us <= t_us:
                            s.next_us = t_us + s.interval_us
                if t_us >= self._next_scan_us:
                    self._radar_scan(ch, i)
                    self._next_scan_us += scan_iv
                if self._truth is not None and truth_iv and t_us >= next_truth:
                    self._write_truth(ch, i)
                    next_truth += truth_iv
                for j in range(len(self.targets)):
                    if t_us >= self._next_adsb_us[j]:
                        self._next_adsb_us[j] += self.adsb_interval_us
                        if self.adsb_on and self.targets.targets[j].adsb:
                            self._adsb(j, t_us)
                self.k += 1
            return self._summary(wall0, reason, tlog)
        finally:
            if self._truth is not None:
                self._truth.close()
                self._truth = None
            if self._tlog is not None:
                self._tlog.close()
                self._tlog = None
            if self._conn is not None:
                try:
                    self._conn.close()
                except OSError:
                    pass
                self._conn = None

    def _write_truth(self, ch: _Chunk, i: int) -> None:
        t = ch.t_us[i] * 1e-6
        tr = ch.truth
        p, v, e = tr.pos[i], tr.vel[i], tr.euler[i]
        la, lo, h = ch.lla[i]
        rows = [f"{t:.6f},vehicle,0,,{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},{v[0]:.4f},{v[1]:.4f},"
                f"{v[2]:.4f},{e[0]:.6f},{e[1]:.6f},{e[2]:.6f},{la:.8f},{lo:.8f},{h:.3f}"]
        if len(self.targets):
            P, V = self.targets.state_at(t)
            LA, LO, H = self.frame.ned_to_geodetic(P)
            for j, tg in enumerate(self.targets.targets):
                p, v = P[j], V[j]
                rows.append(f"{t:.6f},target,{tg.ident},{j},{p[0]:.3f},{p[1]:.3f},{p[2]:.3f},"
                            f"{v[0]:.3f},{v[1]:.3f},{v[2]:.3f},,,,{LA[j]:.8f},{LO[j]:.8f},"
                            f"{H[j]:.3f}")
        self._truth.write("\n".join(rows) + "\n")
        self._truth.flush()

    @property
    def _chunks(self) -> list[_Chunk]:
        return self._hist[0]

    def _summary(self, wall0: float, reason: str, tlog) -> RunSummary:
        return RunSummary(max(self.k - 1, 0) * self.dt_us * 1e-6, time.monotonic() - wall0,
                          Counter(self.sent), reason, None if tlog is None else str(tlog),
                          self.k, self._n_det)

