"""Publish estimates over MAVLink on a ground-station-side link, under our own identity.

Identity (see ``docs/live.md``): system id 250 (:data:`DEFAULT_SYSID`; not 1, the usual
vehicle, nor 255, the usual GCS), component ``MAV_COMP_ID_ONBOARD_COMPUTER`` (191), a
HEARTBEAT of type ``MAV_TYPE_ONBOARD_CONTROLLER`` with ``MAV_AUTOPILOT_INVALID`` at 1 Hz,
so no ground station mistakes it for a vehicle.  Never the vehicle's link: the constructor
refuses (``ValueError``) a connection on the same endpoint as an open
:class:`uavest.ingest.LiveLink` (:func:`uavest.link.is_vehicle_endpoint`) or the
``vehicle_conn`` given, unless ``allow_vehicle_link=True``.

Messages:

* ``attitude(label, t, q, rates)``: ATTITUDE (roll, pitch, yaw rad; rates rad/s body FRD)
  from the label's component: the first label uses ``compid`` (191), the next ones 192,
  193, 194 (``MAV_COMP_ID_ONBOARD_COMPUTER2..4``), each with its own heartbeat; plus
  NAMED_VALUE_FLOAT ``<lbl>_rol``, ``<lbl>_pit``, ``<lbl>_yaw`` (rad, ``lbl`` = the label's
  first 6 characters) for every label.
* ``value(name, t, v)``: NAMED_VALUE_FLOAT (name <= 10 characters, else ValueError).
* ``vector(name, t, xyz)``: DEBUG_VECT (name <= 10 characters).
* ``track(label, track_id, t, lat, lon, alt, vel_ned)``: ADSB_VEHICLE with
  ``ADSB_FLAGS_SIMULATED``; ICAO address ``0xF00000 | label_index << 16 | track_id & 0xFFFF``
  (label_index 0..15 in order of first use), callsign ``<LBL4><id % 10000:04d>``.

``t`` is the vehicle clock (s); ``time_boot_ms`` = ``round(t * 1000) mod 2**32``.
Every (kind, name) is rate-limited to ``rate_hz``; the excess is dropped and counted in
:attr:`MavlinkPublisher.dropped`.
"""

from __future__ import annotations

import math
import os
import threading
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

import numpy as np  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from ..errors import InputError
from ..geometry.rotation import quat_to_euler  # noqa: E402
from ..link import (  # noqa: E402
    Transport,
    Writer,
    enable_signing,
    endpoint_key,
    is_vehicle_endpoint,
    signing_key_bytes,
)

__all__ = ["MavlinkPublisher", "DEFAULT_SYSID", "icao_address"]

DEFAULT_SYSID = 250
_EXTRA_COMPIDS = (192, 193, 194)  # MAV_COMP_ID_ONBOARD_COMPUTER2..4
_ADSB_FLAGS = (mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE
               | mavlink.ADSB_FLAGS_VALID_HEADING | mavlink.ADSB_FLAGS_VALID_VELOCITY
               | mavlink.ADSB_FLAGS_VALID_CALLSIGN | mavlink.ADSB_FLAGS_SIMULATED
               | mavlink.ADSB_FLAGS_VERTICAL_VELOCITY_VALID)


def icao_address(label_index: int, track_id: int) -> int:
    """The 24-bit ICAO address of a published track: ``0xF00000 | index << 16 | id``."""
    if not 0 <= label_index < 16:
        raise InputError(f"at most 16 track labels can be published, got index {label_index}")
    return 0xF00000 | (label_index << 16) | (int(track_id) & 0xFFFF)


def _ms(t: float) -> int:
    return int(round(t * 1000.0)) % (1 << 32)


class MavlinkPublisher:
    """MAVLink publisher of estimates (see module docstring).

    conn: connection string of the ground-station side (``udpout:127.0.0.1:14551`` to a
    MAVProxy/QGC listening there, ``udpin:...`` to answer whoever sends to us,
    ``tcp:...``).  sysid, compid: our identity.  rate_hz: max rate per stream.
    vehicle_conn: the vehicle's connection string (also refused).  signing_key: sign what
    we send (MAVLink 2).  heartbeat_hz: 1.
    """

    def __init__(
        self,
        conn: str,
        *,
        sysid: int = DEFAULT_SYSID,
        compid: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER,
        rate_hz: float = 10.0,
        vehicle_conn: str | None = None,
        allow_vehicle_link: bool = False,
        signing_key: str | bytes | Path | None = None,
        heartbeat_hz: float = 1.0,
    ) -> None:
        if not 1 <= sysid <= 255 or not 1 <= compid <= 255:
            raise InputError(f"sysid/compid must be 1..255, got {sysid}/{compid}")
        if not allow_vehicle_link:
            same = vehicle_conn is not None and endpoint_key(conn) == endpoint_key(vehicle_conn)
            if same or is_vehicle_endpoint(conn):
                raise InputError(
                    f"{conn}: is the vehicle's link; publish on a separate ground-station "
                    f"link (or pass allow_vehicle_link=True)")
        self.conn = conn
        self.sysid, self.compid = sysid, compid
        self.min_interval = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.dropped = 0
        self.sent = 0
        self._writer = Writer()
        try:
            self._writer.transport = Transport(conn, 115200)
        except (OSError, ValueError) as e:
            raise InputError(f"{conn}: cannot open publisher link ({e})") from None
        self._key = signing_key_bytes(signing_key) if signing_key is not None else None
        self._mavs: dict[int, mavlink.MAVLink] = {}
        self._labels: dict[str, int] = {}  # attitude label -> compid
        self._track_labels: dict[str, int] = {}
        self._last: dict[tuple, float] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._mav(compid)
        self._hb_period = 1.0 / heartbeat_hz
        self._thread = threading.Thread(target=self._heartbeats, name="uavest-mavpub",
                                        daemon=True)
        self._heartbeat()
        self._thread.start()

    # ------------------------------------------------------------ plumbing
    def _mav(self, compid: int) -> mavlink.MAVLink:
        m = self._mavs.get(compid)
        if m is None:
            m = mavlink.MAVLink(self._writer, srcSystem=self.sysid, srcComponent=compid)
            if self._key is not None:
                enable_signing(m, self._key, verify=False)
            self._mavs[compid] = m
        return m

    def _heartbeat(self) -> None:
        with self._lock:
            for m in self._mavs.values():
                m.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                 mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE)

    def _heartbeats(self) -> None:
        while not self._stop.wait(self._hb_period):
            self._heartbeat()

    def _due(self, key: tuple) -> bool:
        now = time.monotonic()
        last = self._last.get(key)
        if last is not None and now - last < self.min_interval:
            self.dropped += 1
            return False
        self._last[key] = now
        return True

    @staticmethod
    def _name(name: str) -> bytes:
        b = name.encode("ascii")
        if not 1 <= len(b) <= 10:
            raise ValueError(f"MAVLink value name {name!r} must be 1..10 ASCII characters")
        return b

    # ------------------------------------------------------------ API
    def attitude(self, label: str, t: float, q, rates=None) -> bool:
        """Publish an attitude: ``q`` [w,x,y,z] body FRD -> NED, ``rates`` (3,) rad/s FRD.

        Returns False if rate-limited.  ``t``: vehicle clock, s.
        """
        if not self._due(("att", label)):
            return False
        q = np.asarray(q, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1) > 1e-3:
            raise ValueError(f"attitude {label!r}: q must be a finite unit quaternion [w,x,y,z]")
        roll, pitch, yaw = (float(v) for v in quat_to_euler(q / np.linalg.norm(q)))
        p, qr, r = (0.0, 0.0, 0.0) if rates is None else (float(v) for v in rates)
        with self._lock:
            compid = self._labels.get(label)
            if compid is None:
                used = len(self._labels)
                compid = self.compid if used == 0 else (
                    _EXTRA_COMPIDS[used - 1] if used - 1 < len(_EXTRA_COMPIDS) else None)
                self._labels[label] = compid if compid is not None else -1
            if compid is not None and compid > 0:
                self._mav(compid).attitude_send(_ms(t), roll, pitch, yaw, p, qr, r)
                self.sent += 1
            base = self._mav(self.compid)
            ab = label[:6]
            for suffix, v in (("rol", roll), ("pit", pitch), ("yaw", yaw)):
                base.named_value_float_send(_ms(t), self._name(f"{ab}_{suffix}"), v)
                self.sent += 1
        return True

    def value(self, name: str, t: float, v: float) -> bool:
        """Publish one scalar (NIS, resets, ...) as NAMED_VALUE_FLOAT; False if rate-limited."""
        nb = self._name(name)
        if not self._due(("val", name)):
            return False
        with self._lock:
            self._mav(self.compid).named_value_float_send(_ms(t), nb, float(v))
            self.sent += 1
        return True

    def vector(self, name: str, t: float, xyz) -> bool:
        """Publish a 3-vector as DEBUG_VECT (time_usec = t * 1e6); False if rate-limited."""
        nb = self._name(name)
        if not self._due(("vec", name)):
            return False
        x, y, z = (float(v) for v in xyz)
        with self._lock:
            self._mav(self.compid).debug_vect_send(nb, int(round(t * 1e6)), x, y, z)
            self.sent += 1
        return True

    def track(self, label: str, track_id: int, t: float, lat: float, lon: float, alt: float,
              vel_ned=None) -> bool:
        """Publish a track as ADSB_VEHICLE (flag SIMULATED).  lat/lon deg, alt m AMSL
        (sent as geometric altitude), vel_ned (3,) m/s.  False if rate-limited."""
        if not self._due(("trk", label, int(track_id))):
            return False
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
            raise ValueError(f"track {label}/{track_id}: non-finite position")
        with self._lock:
            idx = self._track_labels.setdefault(label, len(self._track_labels))
        icao = icao_address(idx, track_id)
        vn, ve, vd = (0.0, 0.0, 0.0) if vel_ned is None else (float(v) for v in vel_ned)
        hdg = (math.degrees(math.atan2(ve, vn)) % 360.0) * 100.0
        hor = min(math.hypot(vn, ve) * 100.0, 65535.0)
        ver = max(-32768.0, min(32767.0, -vd * 100.0))
        callsign = f"{label[:4].upper()}{int(track_id) % 10000:04d}".encode("ascii")[:8]
        with self._lock:
            self._mav(self.compid).adsb_vehicle_send(
                icao, int(round(lat * 1e7)), int(round(lon * 1e7)),
                mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC, int(round(alt * 1000)),
                int(hdg) % 36000, int(hor), int(ver), callsign,
                mavlink.ADSB_EMITTER_TYPE_NO_INFO, 0, _ADSB_FLAGS, 0)
            self.sent += 1
        return True

    def close(self) -> None:
        """Stop the heartbeat thread (joined) and close the link.  Idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=5.0)
        with self._writer.lock:
            if self._writer.transport is not None:
                self._writer.transport.close()
                self._writer.transport = None

    def __enter__(self) -> MavlinkPublisher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
