"""The simulator's MAVLink protocol: what an ArduPilot copter sends, when, and how it
answers a ground station.

:class:`Protocol` holds the message schedule (SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM
in ArduPilot's stream groups, capped at 50 Hz), the parameters, the answers to
COMMAND_LONG / PARAM_* requests, and the builders that turn one IMU step of truth and
sensor outputs (:class:`.truth.Chunk`) into the messages of ``docs/sim.md`` (units as
MAVLink: 1e-7 deg, mm, cm/s, mG, millirad/s). It encodes with the shared
:class:`uavest.link.FrameEncoder` and hands each message to ``send(msg, t_us)``; the
transport and the tlog are the :class:`.mavlink.Simulator`'s.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav2

from ..errors import InputError
from ..geometry.geodesy import LocalFrame
from ..geometry.rotation import G0
from ..link import FrameEncoder
from ..link.framing import param_name
from .truth import Chunk

__all__ = ["ADSB_FLAGS", "EVENT", "ID_TO_NAME", "PERIODIC", "STREAMS", "STREAM_CAP_HZ",
           "STREAM_NAMES", "Protocol", "isa_pressure_hpa"]

STREAM_CAP_HZ = 50.0  # ArduPilot's maximum data-stream rate (SRn_* parameters)

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
                 "HIL_STATE_QUATERNION", "VFR_HUD", "SYSTEM_TIME")
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


def _c_i16(x: float) -> int:
    """``x`` passed to an int16 field as ArduPilot's C code passes a float: truncated
    towards zero (and saturated here), as its RAW_IMU / SCALED_IMU milli-units are; a
    reader takes each count as the middle of its unit
    (:func:`uavest.ingest.convert.count_middle`)."""
    return int(max(-32768.0, min(32767.0, x)))


def _deg_e7(x: float) -> int:
    return int(round(x * 1e7))


def isa_pressure_hpa(alt_m: float) -> float:
    """ISA static pressure (hPa) at geopotential altitude ``alt_m`` (m, troposphere)."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_m) ** 5.25588




@dataclass
class _Sched:
    interval_us: int
    next_us: int


class Protocol:
    """The ArduPilot-like message schedule, parameters and request handling of one
    simulated vehicle (see module docstring).

    Args:
      enc: the encoder (our identity: ``sysid``, component 1).
      sysid: our MAVLink system id (requests for other systems are ignored).
      send: ``send(msg, t_us)`` puts one encoded message on the link and in the tlog.
      now_us: the simulated time of the current step (us since boot).
      epoch: UNIX time (s) of boot (SYSTEM_TIME).
      frame: the local NED frame (geodetic positions).
      params: the parameter list (name -> (value, MAV_PARAM_TYPE)).
      radar_enabled, radar_rate: the radar (OBSTACLE_DISTANCE_3D) is configured, its scan
        rate (Hz); radar_active: it has anything to report.
      adsb_enabled, adsb_interval_us: ADS-B reports are configured, their interval.
    """

    def __init__(self, enc: FrameEncoder, sysid: int, send: Callable[[object, int], None],
                 now_us: Callable[[], float], epoch: float, frame: LocalFrame,
                 params: dict[str, tuple[float, int]], *, radar_enabled: bool,
                 radar_active: bool, radar_rate: float, adsb_enabled: bool,
                 adsb_interval_us: int) -> None:
        self.enc = enc
        self.sysid = int(sysid)
        self.send = send
        self.now_us = now_us
        self.epoch = float(epoch)
        self.frame = frame
        self.params = params
        self.radar_enabled = radar_enabled
        self.radar_rate = float(radar_rate)
        self.adsb_enabled = adsb_enabled
        self.adsb_interval_us = int(adsb_interval_us)
        self.stream_hz: dict[int, float] = {}
        self.override_us: dict[str, int | None] = {}  # None = disabled (-1)
        self.sched: dict[str, _Sched] = {}
        self.radar_on = radar_enabled and radar_active
        self.adsb_on = adsb_enabled
        self.pending_once: list[str] = []  # REQUEST_MESSAGE: sent at the next step
        self.mag_seq = 0  # magnetometer samples so far
        self.mag_seq_sent = -1  # ... and the one HIGHRES_IMU last flagged as new

    # ------------------------------------------------------------------ rates

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
        self.reschedule()
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
            self.radar_on = self.radar_enabled and iv != -1
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
        self.reschedule()
        return mav2.MAV_RESULT_ACCEPTED

    def interval_us(self, name: str) -> int | None:
        """Current interval (us) of a periodic message, None if off."""
        if name in self.override_us:
            return self.override_us[name]
        hz = max((self.stream_hz.get(s, 0.0) for s, msgs in STREAMS.items() if name in msgs),
                 default=0.0)
        return int(round(1e6 / hz)) if hz > 0 else None

    def reschedule(self) -> None:
        now = int(self.now_us())
        for name in PERIODIC:
            iv = self.interval_us(name)
            old = self.sched.get(name)
            if iv is None:
                self.sched.pop(name, None)
            elif old is None:
                self.sched[name] = _Sched(iv, now)
            elif old.interval_us != iv:
                self.sched[name] = _Sched(iv, min(old.next_us, now + iv))

    # ------------------------------------------------------------------ requests

    def heartbeat(self):
        m = mav2
        return self.enc.mav.heartbeat_encode(
            m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_ARDUPILOTMEGA,
            m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_SAFETY_ARMED
            | m.MAV_MODE_FLAG_STABILIZE_ENABLED | m.MAV_MODE_FLAG_GUIDED_ENABLED,
            4, m.MAV_STATE_ACTIVE)  # custom_mode 4 = GUIDED

    def _for_me(self, msg) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.sysid) and tc in (0, 1)

    def handle(self, msg, t_us: int) -> None:
        typ = msg.get_type()
        e = self.enc.mav
        if typ == "COMMAND_LONG" and self._for_me(msg):
            cmd = msg.command
            if cmd == mav2.MAV_CMD_SET_MESSAGE_INTERVAL:
                res = self.set_interval(int(msg.param1), msg.param2)
            elif cmd == mav2.MAV_CMD_GET_MESSAGE_INTERVAL:
                name = ID_TO_NAME.get(int(msg.param1))
                res = mav2.MAV_RESULT_ACCEPTED if name else mav2.MAV_RESULT_DENIED
                if name:
                    self.send(e.message_interval_encode(int(msg.param1),
                                                         self._report_interval(name)), t_us)
            elif cmd == mav2.MAV_CMD_REQUEST_MESSAGE:
                name = ID_TO_NAME.get(int(msg.param1))
                res = mav2.MAV_RESULT_ACCEPTED if name in PERIODIC or name == "HEARTBEAT" \
                    else mav2.MAV_RESULT_DENIED
                if res == mav2.MAV_RESULT_ACCEPTED:
                    self.pending_once.append(name)
            else:
                res = mav2.MAV_RESULT_UNSUPPORTED
            self.send(e.command_ack_encode(cmd, res, 0, 0, msg.get_srcSystem(),
                                            msg.get_srcComponent()), t_us)
        elif typ == "REQUEST_DATA_STREAM" and self._for_me(msg):
            if msg.start_stop in (0, 1):
                self.set_stream(msg.req_stream_id, msg.req_message_rate if msg.start_stop else 0)
        elif typ == "PARAM_REQUEST_READ" and self._for_me(msg):
            names = list(self.params)
            pid = param_name(msg.param_id)
            if msg.param_index >= 0:
                if msg.param_index < len(names):
                    self.send_param(names[msg.param_index], t_us)
            elif pid in self.params:
                self.send_param(pid, t_us)
        elif typ == "PARAM_REQUEST_LIST" and self._for_me(msg):
            for name in self.params:
                self.send_param(name, t_us)
        elif typ == "PARAM_SET" and self._for_me(msg):
            pid = param_name(msg.param_id)
            if pid in self.params:  # stored (what the autopilot believes), physics unchanged
                self.params[pid] = (float(np.float32(msg.param_value)), self.params[pid][1])
                self.send_param(pid, t_us)

    def _report_interval(self, name: str) -> int:
        if name == "HEARTBEAT":
            return 1_000_000
        if name == "OBSTACLE_DISTANCE_3D":
            return int(1e6 / self.radar_rate) if self.radar_on else -1
        if name == "ADSB_VEHICLE":
            return self.adsb_interval_us if self.adsb_on else -1
        iv = self.interval_us(name)
        return -1 if iv is None else iv

    def send_param(self, name: str, t_us: int) -> None:
        names = list(self.params)
        v, typ = self.params[name]
        self.send(self.enc.mav.param_value_encode(name.encode(), v, typ, len(names),
                                                names.index(name)), t_us)

    # ------------------------------------------------------------------ message builders

    def build(self, name: str, ch: Chunk, i: int, gps_fix: dict | None):
        e = self.enc.mav
        t_us = int(ch.t_us[i])
        t_ms = t_us // 1000
        tr, imu = ch.truth, ch.imu
        lat, lon, h = ch.lla[i]
        if name == "RAW_IMU":
            a = imu.accel[i] / G0 * 1000.0
            g = imu.gyro[i] * 1000.0
            m = imu.mag[i] * 1000.0
            return e.raw_imu_encode(t_us, _c_i16(a[0]), _c_i16(a[1]), _c_i16(a[2]),
                                    _c_i16(g[0]), _c_i16(g[1]), _c_i16(g[2]), _c_i16(m[0]),
                                    _c_i16(m[1]), _c_i16(m[2]), 0, 3500)
        if name == "HIGHRES_IMU":
            a, g, m = imu.accel[i], imu.gyro[i], imu.mag[i]
            upd = 0x3F | 0x200 | 0x800 | 0x1000
            if self.mag_seq != self.mag_seq_sent:
                upd |= 0x1C0
                self.mag_seq_sent = self.mag_seq
            alt = h + ch.baro_err[i]
            return e.highres_imu_encode(t_us, *map(float, a), *map(float, g), *map(float, m),
                                        isa_pressure_hpa(alt), 0.0, float(alt), 35.0, upd, 0)
        if name == "SCALED_PRESSURE":
            return e.scaled_pressure_encode(t_ms, isa_pressure_hpa(h + ch.baro_err[i]), 0.0,
                                            3500, 0)
        if name == "GPS_RAW_INT":
            f = gps_fix
            if f is None:  # no fix yet: no GNSS time either (ArduPilot sends 0)
                return e.gps_raw_int_encode(0, 1, 0, 0, 0, 65535, 65535, 65535, 65535, 0)
            vn, ve, vd = f["vel"]
            cog = int(round(math.degrees(math.atan2(ve, vn)) * 100)) % 36000
            # the receiver's accuracies, mm and mm/s (at least 1: 0 is "not reported")
            h_acc, v_acc, vel_acc = (max(1, int(round(a * 1e3))) for a in f["acc"])
            # time_usec: the fix's UNIX (GNSS) time, as ArduPilot sends it, not boot time;
            # the ground speed truncated to whole cm/s, as ArduPilot's float -> uint16
            return e.gps_raw_int_encode(
                int(self.epoch * 1e6) + f["t_us"], 3, _deg_e7(f["lat"]), _deg_e7(f["lon"]),
                int(round(f["alt"] * 1e3)),
                70, 110, min(int(math.hypot(vn, ve) * 100), 65534), cog, 14,
                int(round(f["alt"] * 1e3)), h_acc, v_acc, vel_acc, 0, 0)
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
        if name == "HIL_STATE_QUATERNION":  # the true state, as PX4 SITL sends its own
            v, w = tr.vel[i], tr.omega[i]
            a = tr.f_body[i] / G0 * 1000.0
            spd = int(round(float(np.linalg.norm(v)) * 100))
            return e.hil_state_quaternion_encode(
                t_us, [float(c) for c in tr.q[i]], *map(float, w), _deg_e7(lat), _deg_e7(lon),
                int(round(float(h) * 1e3)), _i16(v[0] * 100), _i16(v[1] * 100),
                _i16(v[2] * 100), min(spd, 65535), min(spd, 65535), _i16(a[0]), _i16(a[1]),
                _i16(a[2]))
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
            return self.heartbeat()
        raise KeyError(name)

    def obstacle(self, t_ms: int, d, r_min: float, r_max: float):
        """OBSTACLE_DISTANCE_3D of one radar detection ``d`` (:class:`.radar.Detection`:
        FRD position m) at ``t_ms`` (ms since boot); ``r_min``/``r_max`` the radar's
        range limits (m)."""
        return self.enc.mav.obstacle_distance_3d_encode(
            t_ms, mav2.MAV_DISTANCE_SENSOR_RADAR, mav2.MAV_FRAME_BODY_FRD, d.obstacle_id,
            *map(float, d.xyz), r_min, r_max)

    def adsb_vehicle(self, tg, p, v):
        """ADSB_VEHICLE of target ``tg`` (:class:`.radar.Target`) reported at NED position
        ``p`` (m) with NED velocity ``v`` (m/s)."""
        la, lo, hh = self.frame.ned_to_geodetic(p)
        hdg = int(round(math.degrees(math.atan2(v[1], v[0])) * 100)) % 36000
        return self.enc.mav.adsb_vehicle_encode(
            tg.icao, _deg_e7(float(la)), _deg_e7(float(lo)), mav2.ADSB_ALTITUDE_TYPE_GEOMETRIC,
            int(round(float(hh) * 1e3)), hdg, int(min(65535, round(math.hypot(v[0], v[1]) * 100))),
            _i16(-v[2] * 100), tg.name.encode(), tg.emitter, 0, ADSB_FLAGS, 1200)
