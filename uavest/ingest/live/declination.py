"""The live link's magnetic declination (rad, east positive): the autopilot's COMPASS_DEC,
else the WMM at the first 3-D GPS fix, kept up to date from the messages flowing by."""

from __future__ import annotations

import logging
import math
from datetime import UTC, datetime
from typing import Any

from ...link.framing import param_name

log = logging.getLogger("uavest.live")


class Declination:
    """The declination the link reports: COMPASS_DEC when the autopilot has one (0 with
    auto-declination on means unknown until GPS lock, and is asked again then), else the
    WMM at the first 3-D GPS fix (the host's date)."""

    def __init__(self, conn: str) -> None:
        self.conn = conn
        self.value: float | None = None  # rad
        self.source = "unknown"
        self.pending = False  # waiting for a GPS fix
        self.autodec: float | None = None  # COMPASS_AUTODEC as read
        self.gps_fix: tuple[float, float, float] | None = None

    def from_params(self, dec: float | None, auto: float | None) -> None:
        """COMPASS_DEC / COMPASS_AUTODEC as read at start (None: no answer)."""
        self.autodec = auto
        if dec is not None and (dec != 0.0 or not auto):
            self.value, self.source = float(dec), "param:COMPASS_DEC"
        else:
            # auto-declination with 0 = unknown until GPS lock; no param: WMM once we have GPS
            self.pending = True
            self.source = "unknown (waiting for GPS)"

    def on_gps(self, lat: float, lon: float, alt: float) -> bool:
        """A GPS fix (deg, deg, m): the WMM's declination if we were waiting for one. True
        if COMPASS_DEC should be asked again (auto-declination: computed after lock)."""
        if not self.pending:
            return False
        self.pending = False
        self.gps_fix = (lat, lon, alt)
        try:  # the host's date: a day's error changes the declination by < 0.001 deg
            from ...geometry.magnetic import declination

            self.value = declination(lat, lon, alt, datetime.now(UTC))
            self.source = "wmm2025"
        except ImportError:
            self.source = "unknown (pygeomag not installed for the WMM)"
            log.warning("%s: no declination: COMPASS_DEC unknown and pygeomag missing",
                        self.conn)
        except ValueError as e:
            log.warning("%s: %s", self.conn, e)
        return bool(self.autodec)

    def on_param(self, pid: str, v: float) -> None:
        """A PARAM_VALUE flowing by: a usable COMPASS_DEC replaces what we have."""
        if pid == "COMPASS_DEC" and math.isfinite(v) and (v != 0.0 or not self.autodec):
            self.value, self.source = v, "param:COMPASS_DEC"
            self.pending = False

    def watch(self, m: Any, name: str) -> bool:
        """Bookkeeping from a vehicle message ``m`` of type ``name`` (GPS fixes in degE7 /
        mm, PARAM_VALUE). True if COMPASS_DEC should be asked again."""
        if name == "GPS_RAW_INT" and m.fix_type >= 3 and (m.lat or m.lon):
            return self.on_gps(m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3)
        if name == "GLOBAL_POSITION_INT" and (m.lat or m.lon):
            return self.on_gps(m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3)
        if name == "PARAM_VALUE":
            self.on_param(param_name(m.param_id), float(m.param_value))
        return False
