"""WGS84 geodetic <-> local NED (exact, through ECEF).

The local frame is the tangent plane NED at an origin
(lat0, lon0, h0): x north, y east, z down, metres. Geodetic heights are WGS84 ellipsoidal
heights; the simulator takes the geoid undulation as 0, so they double as MSL altitudes
in GPS_RAW_INT / GLOBAL_POSITION_INT / ADSB_VEHICLE.

Formulas: Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation
Systems* (2nd ed.), eqs. 2.112 (geodetic -> ECEF) and 2.150 (NED rotation); ECEF ->
geodetic by Bowring's iteration (converges to < 1e-9 rad in 3 iterations near the Earth).
"""

from __future__ import annotations

import numpy as np

Array = np.ndarray

A = 6378137.0  # m, WGS84 semi-major axis
F = 1.0 / 298.257223563
E2 = F * (2.0 - F)  # first eccentricity squared
B = A * (1.0 - F)


def geodetic_to_ecef(lat: Array | float, lon: Array | float, h: Array | float) -> Array:
    """ECEF (..., 3) m from latitude, longitude (rad) and ellipsoidal height (m)."""
    lat, lon, h = np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float)
    sl, cl = np.sin(lat), np.cos(lat)
    n = A / np.sqrt(1.0 - E2 * sl * sl)
    return np.stack(
        [(n + h) * cl * np.cos(lon), (n + h) * cl * np.sin(lon), (n * (1.0 - E2) + h) * sl],
        axis=-1,
    )


def ecef_to_geodetic(xyz: Array) -> tuple[Array, Array, Array]:
    """(lat rad, lon rad, h m) of ECEF points (..., 3) m."""
    xyz = np.asarray(xyz, float)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - E2))
    for _ in range(5):
        sl = np.sin(lat)
        n = A / np.sqrt(1.0 - E2 * sl * sl)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - E2 * n / (n + h)))
    sl = np.sin(lat)
    n = A / np.sqrt(1.0 - E2 * sl * sl)
    h = p / np.cos(lat) - n
    return lat, lon, h


def _r_en(lat0: float, lon0: float) -> Array:
    """ECEF-from-NED rotation at (lat0, lon0) rad (columns: north, east, down in ECEF)."""
    sl, cl, so, co = np.sin(lat0), np.cos(lat0), np.sin(lon0), np.cos(lon0)
    return np.array(
        [[-sl * co, -so, -cl * co], [-sl * so, co, -cl * so], [cl, 0.0, -sl]]
    )


class LocalFrame:
    """Local tangent-plane NED frame at a geodetic origin.

    Args:
      lat_deg, lon_deg: origin latitude / longitude (degrees).
      alt_m: origin ellipsoidal height (m).
    """

    def __init__(self, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        self.lat0 = np.deg2rad(float(lat_deg))
        self.lon0 = np.deg2rad(float(lon_deg))
        self.h0 = float(alt_m)
        self.origin_ecef = geodetic_to_ecef(self.lat0, self.lon0, self.h0)
        self.R_en = _r_en(self.lat0, self.lon0)

    def ned_to_geodetic(self, ned: Array) -> tuple[Array, Array, Array]:
        """(lat deg, lon deg, h m) of NED points (..., 3) m."""
        ecef = self.origin_ecef + np.einsum("ij,...j->...i", self.R_en, np.asarray(ned, float))
        lat, lon, h = ecef_to_geodetic(ecef)
        return np.rad2deg(lat), np.rad2deg(lon), h

    def geodetic_to_ned(self, lat_deg: Array, lon_deg: Array, h: Array) -> Array:
        """NED (..., 3) m of geodetic points (degrees, m)."""
        ecef = geodetic_to_ecef(np.deg2rad(lat_deg), np.deg2rad(lon_deg), h)
        res: Array = np.einsum("ji,...j->...i", self.R_en, ecef - self.origin_ecef)
        return res


#: ArduPilot's metres per 1e-7 degree of latitude (``LOCATION_SCALING_FACTOR``, AP_Common
#: Location): a sphere of radius 6,378,100 m.
ARDUPILOT_LATLON_TO_M = 0.011131884502145034
_M_PER_DEG = ARDUPILOT_LATLON_TO_M * 1e7

#: The local frames a navigation run can use (:func:`make_frame`).
GEODESIES = ("wgs84", "sphere")


class SphereFrame:
    """ArduPilot's flat-Earth local frame at a geodetic origin (``Location::offset`` and
    ``get_distance_NE``): north = dlat x :data:`ARDUPILOT_LATLON_TO_M` per 1e-7 deg,
    east = dlon x the same x cos(the mean of the point's and the origin's latitudes),
    down = -(h - h0). The lat/lon an ArduPilot SITL reports (its GPS and its truth,
    SIM_STATE / SIMSTATE) are made this way from its metric positions: read through
    WGS84 (:class:`LocalFrame`) their displacements are 0.13 % short north and 0.18 %
    long east at 47 deg latitude against the SITL's metric velocities
    (docs/navigation.md). Same interface as :class:`LocalFrame`."""

    def __init__(self, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        self.lat0 = np.deg2rad(float(lat_deg))
        self.lon0 = np.deg2rad(float(lon_deg))
        self.h0 = float(alt_m)
        self._lat0d, self._lon0d = float(lat_deg), float(lon_deg)

    def geodetic_to_ned(self, lat_deg: Array, lon_deg: Array, h: Array) -> Array:
        """NED (..., 3) m of geodetic points (degrees, m)."""
        lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
        sc = np.cos(np.deg2rad(0.5 * (lat + self._lat0d)))
        dlon = (lon - self._lon0d + 180.0) % 360.0 - 180.0
        return np.stack([(lat - self._lat0d) * _M_PER_DEG,
                         dlon * _M_PER_DEG * sc,
                         self.h0 - np.asarray(h, float)], axis=-1)

    def ned_to_geodetic(self, ned: Array) -> tuple[Array, Array, Array]:
        """(lat deg, lon deg, h m) of NED points (..., 3) m."""
        ned = np.asarray(ned, float)
        lat = self._lat0d + ned[..., 0] / _M_PER_DEG
        sc = np.cos(np.deg2rad(0.5 * (lat + self._lat0d)))
        lon = (self._lon0d + ned[..., 1] / (_M_PER_DEG * sc) + 180.0) % 360.0 - 180.0
        return lat, lon, self.h0 - ned[..., 2]


def make_frame(lat_deg: float, lon_deg: float, alt_m: float,
               geodesy: str = "wgs84") -> LocalFrame | SphereFrame:
    """The local NED frame at the origin: ``geodesy`` "wgs84" (:class:`LocalFrame`) or
    "sphere" (ArduPilot's, :class:`SphereFrame`)."""
    if geodesy == "sphere":
        return SphereFrame(lat_deg, lon_deg, alt_m)
    if geodesy == "wgs84":
        return LocalFrame(lat_deg, lon_deg, alt_m)
    raise ValueError(f"geodesy must be one of {GEODESIES}, not {geodesy!r}")


def geodetic_to_ned(lla_deg: Array, origin_deg: Array) -> Array:
    """NED (..., 3) m of geodetic points ``lla_deg`` (..., 3) (deg, deg, m) relative to the
    geodetic ``origin_deg`` (3,) (deg, deg, m)."""
    lla = np.asarray(lla_deg, float)
    return LocalFrame(*np.asarray(origin_deg, float)).geodetic_to_ned(
        lla[..., 0], lla[..., 1], lla[..., 2])


def gravity(lat: Array, h: Array) -> Array:
    """Magnitude of normal gravity (m/s^2) at geodetic latitude ``lat`` (rad) and ellipsoidal
    height ``h`` (m): Somigliana's formula with the free-air height correction of Groves
    (2nd ed.) eqs. 2.134 and 2.139, WGS84 constants."""
    lat, h = np.asarray(lat, float), np.asarray(h, float)
    s2 = np.sin(lat) ** 2
    g0 = 9.7803253359 * (1.0 + 0.001931853 * s2) / np.sqrt(1.0 - E2 * s2)
    omega, mu = 7.292115e-5, 3.986004418e14
    m = omega * omega * A * A * B / mu
    res: Array = g0 * (1.0 - 2.0 / A * (1.0 + F + m - 2.0 * F * s2) * h + 3.0 * h * h / (A * A))
    return res


#: Earth's rotation rate, rad/s (WGS84).
EARTH_RATE = 7.292115e-5
