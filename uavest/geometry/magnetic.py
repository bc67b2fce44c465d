"""Magnetic declination from the World Magnetic Model (WMM2025, via ``pygeomag``).

Declination is the angle from true north to magnetic north, positive east, in
radians (the sign convention of ArduPilot's ``COMPASS_DEC``): a magnetometer
heading plus the declination gives the true heading.
"""

from __future__ import annotations

import math
from datetime import UTC, date, datetime
from functools import lru_cache
from typing import Any

from ..errors import InputError

__all__ = ["declination", "decimal_year"]


def decimal_year(when: datetime | date | float) -> float:
    """``when`` as a decimal year (2026.5 = about 1 July 2026); floats pass through.

    Naive datetimes are taken as UTC.
    """
    if isinstance(when, int | float):
        return float(when)
    if isinstance(when, datetime):
        if when.tzinfo is None:
            when = when.replace(tzinfo=UTC)
        when = when.astimezone(UTC)
        start = datetime(when.year, 1, 1, tzinfo=UTC)
        end = datetime(when.year + 1, 1, 1, tzinfo=UTC)
        return when.year + (when - start).total_seconds() / (end - start).total_seconds()
    if isinstance(when, date):
        return decimal_year(datetime(when.year, when.month, when.day, 12, tzinfo=UTC))
    raise TypeError(f"when must be a datetime, a date or a decimal year, not {type(when).__name__}")


@lru_cache(maxsize=1)
def _model() -> Any:
    from pygeomag import GeoMag

    return GeoMag(base_year=2025)  # WMM-2025, valid 2025.0 .. 2030.0


def declination(
    lat_deg: float, lon_deg: float, alt_m: float, when: datetime | date | float
) -> float:
    """Magnetic declination (rad, positive east of true north) at a place and date.

    lat_deg, lon_deg: geodetic WGS84 degrees; alt_m: metres above mean sea level
    (the WMM takes height above the ellipsoid; the geoid difference of < 110 m is
    negligible for declination); when: a ``datetime`` (naive = UTC), a ``date`` or a
    decimal year.  Raises ``ValueError`` (one line) outside the WMM2025 lifespan
    (2025.0-2030.0) or for non-finite / out-of-range coordinates.
    """
    vals = (lat_deg, lon_deg, alt_m)
    if not all(math.isfinite(float(v)) for v in vals):
        raise InputError(f"declination: non-finite position {vals}")
    if abs(lat_deg) > 90 or abs(lon_deg) > 360:
        raise InputError(f"declination: latitude/longitude out of range ({lat_deg}, {lon_deg})")
    year = decimal_year(when)
    try:
        r = _model().calculate(glat=float(lat_deg), glon=float(lon_deg), alt=alt_m / 1000.0,
                               time=year)
    except Exception as e:  # pygeomag raises its own exceptions outside the lifespan
        raise InputError(f"declination: WMM2025 cannot be used for year {year:.2f} ({e})") from e
    return math.radians(float(r.d))
