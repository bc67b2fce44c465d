"""A virtual radar made from ADS-B traffic, relative to the ownship (a seeded streaming stage).

Input: a time-ordered sample stream with the ownship's :class:`PositionSample` (with
``lat_lon_alt``; ``GLOBAL_POSITION_INT`` preferred, else ``GPS_RAW_INT``) and
:class:`AdsbSample` reports of other aircraft.  Output: the same stream with a
:class:`DetectionScan` inserted every ``period`` s of vehicle time: range / azimuth /
elevation detections with Gaussian noise, detection probability ``pd``, Poisson clutter
and a maximum range, every random draw from the ``numpy.random.Generator`` the caller
passes.  Ground truth (position and velocity in the same local NED frame) is kept per ICAO
address: the ArduPilot SITL gives an aircraft that leaves its simulated radius a *new*
address when it comes back, so truth is per address, not per aircraft.

Frames: local NED with origin ``origin`` (lat, lon, alt AMSL; default the first ownship
fix), from WGS84 geodetic coordinates through ECEF (exact, no flat-earth approximation;
the AMSL altitudes are used as ellipsoid heights for both ownship and targets, so the
geoid offset cancels to < 1 mm over tens of km).  Sensor frame: level and north-aligned
(``q`` = identity: x north, y east, z down) unless ``attitude`` names an AttitudeRef kind,
then the vehicle body FRD axes.  ``rae`` uses the conventions of
:mod:`uavest.ingest.detections` (= :mod:`uavest.models.radar` with
``SensorPose.from_ned_frd(det.q, det.sensor_ned)``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..geometry.geodesy import geodetic_to_ned
from ..geometry.rotation import quat_rotate_inv
from .detections import frd_from_rae, rae_from_frd
from .types import AdsbSample, AttitudeRef, DetectionSample, DetectionScan, PositionSample

__all__ = ["RadarConfig", "AdsbRadar", "virtual_radar", "geodetic_to_ned"]

_UNKNOWN_ID = 65535


@dataclass
class RadarConfig:
    """Virtual radar parameters.

    sigma_r m, sigma_az rad, sigma_el rad: measurement noise std.  pd: detection
    probability of an aircraft in the field of view.  clutter_rate: mean number of false
    detections per scan (Poisson), uniform in range [0, max_range], azimuth [-pi, pi),
    elevation ``el_limits``.  max_range m.  el_limits rad: field of view in elevation.
    period s: scan period (vehicle time).  max_age s: an ADS-B report older than this at a
    scan is stale (the aircraft is not in the scan nor in the truth).
    origin: (lat deg, lon deg, alt m AMSL) of the local NED frame, default first ownship
    fix.  attitude: None (level, north-aligned sensor) or an AttitudeRef kind
    (``"autopilot"``, ``"truth"``) whose latest quaternion gives the sensor axes.
    ownship_sources: PositionSample sources accepted as the ownship, by preference.
    """

    sigma_r: float = 10.0
    sigma_az: float = math.radians(1.0)
    sigma_el: float = math.radians(1.0)
    pd: float = 0.9
    clutter_rate: float = 1.0
    max_range: float = 10_000.0
    el_limits: tuple[float, float] = (-math.pi / 2, math.pi / 2)
    period: float = 1.0
    max_age: float = 5.0
    origin: tuple[float, float, float] | None = None
    attitude: str | None = None
    ownship_sources: tuple[str, ...] = ("GLOBAL_POSITION_INT", "GPS_RAW_INT")

    def __post_init__(self) -> None:
        for name in ("sigma_r", "sigma_az", "sigma_el", "clutter_rate"):
            if not getattr(self, name) >= 0:
                raise InputError(f"RadarConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.pd <= 1.0:
            raise InputError(f"RadarConfig.pd must be in [0, 1], got {self.pd}")
        if not self.max_range > 0 or not self.period > 0:
            raise InputError("RadarConfig.max_range and period must be > 0")
        lo, hi = self.el_limits
        if not -math.pi / 2 <= lo < hi <= math.pi / 2:
            raise InputError(f"RadarConfig.el_limits must be within [-pi/2, pi/2], got {lo, hi}")

    @property
    def clutter_density(self) -> float:
        """False detections per unit measurement volume (1 / (m rad^2)) per scan, for JPDA."""
        lo, hi = self.el_limits
        return self.clutter_rate / (self.max_range * 2.0 * math.pi * (hi - lo))


@dataclass
class _Aircraft:
    t: float  # s, vehicle time of the position
    ned: np.ndarray
    vel: np.ndarray


@dataclass
class AdsbRadar:
    """The virtual radar's state; feed samples with :meth:`push` (see :func:`virtual_radar`).

    ``truth``: ICAO -> list of ``(t, state)`` with ``state`` (6,) ``[n, e, d, vn, ve, vd]``
    m, m/s local NED at every scan where the aircraft was fresh (in range or not).
    ``origin``: the local frame origin once known.  ``scans``: number emitted.
    """

    rng: np.random.Generator
    config: RadarConfig = field(default_factory=RadarConfig)
    truth: dict[int, list] = field(default_factory=dict)
    origin: np.ndarray | None = None
    scans: int = 0
    _own: dict = field(default_factory=dict)  # source -> (t, lla, vel or None)
    _air: dict = field(default_factory=dict)  # icao -> _Aircraft
    _q: np.ndarray | None = None
    _next: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.rng, np.random.Generator):
            raise TypeError("AdsbRadar needs an explicit numpy.random.Generator (seeded)")
        if self.config.origin is not None:
            self.origin = np.asarray(self.config.origin, dtype=float)

    # ------------------------------------------------------------------ snapshots
    def snapshot(self) -> tuple:
        """This moment of the radar (its generator's state, aircraft, ownship, the next
        scan time; the truth series, which only grow, as their lengths), for
        :meth:`restore` (a live lane's history, ``uavest.engine.history``)."""
        return (self.rng.bit_generator.state, {k: len(v) for k, v in self.truth.items()},
                self.origin, self.scans, dict(self._own), dict(self._air), self._q,
                self._next)

    def restore(self, snap: tuple) -> None:
        st, lens, self.origin, self.scans, own, air, self._q, self._next = snap
        self.rng.bit_generator.state = st
        for k in list(self.truth):
            if k in lens:
                del self.truth[k][lens[k]:]
            else:
                del self.truth[k]
        self._own, self._air = dict(own), dict(air)

    # ------------------------------------------------------------------ input
    def push(self, s) -> list[DetectionScan]:
        """Take one sample; return the scans due *before* it (time-ordered input)."""
        out = []
        if self._next is not None:
            if s.t - self._next > 10 * self.config.period:  # a long gap: skip to now
                self._next += math.floor((s.t - self._next) / self.config.period) * \
                    self.config.period
            while s.t >= self._next:
                out.append(self._scan(self._next))
                self._next += self.config.period
        cfg = self.config
        if isinstance(s, PositionSample) and s.lat_lon_alt is not None \
                and s.source in cfg.ownship_sources:
            self._own[s.source] = (s.t, np.asarray(s.lat_lon_alt, float), s.vel_ned)
            if self.origin is None:
                self.origin = np.asarray(s.lat_lon_alt, float).copy()
            if self._next is None:
                self._next = s.t + cfg.period
        elif isinstance(s, AdsbSample) and self.origin is not None:
            vel = np.zeros(3) if s.vel_ned is None else np.asarray(s.vel_ned, float)
            self._air[s.icao] = _Aircraft(s.t - s.tslc, geodetic_to_ned(s.lat_lon_alt,
                                                                        self.origin), vel)
        elif isinstance(s, AttitudeRef) and cfg.attitude is not None and s.kind == cfg.attitude:
            self._q = np.asarray(s.q, float)
        return out

    def _ownship(self, t: float) -> np.ndarray | None:
        for src in self.config.ownship_sources:
            if src in self._own:
                t0, lla, vel = self._own[src]
                p = geodetic_to_ned(lla, self.origin)
                if vel is not None and np.all(np.isfinite(vel)):
                    p = p + np.asarray(vel, float) * (t - t0)
                return p
        return None

    def _scan(self, t: float) -> DetectionScan:
        cfg, rng = self.config, self.rng
        own = self._ownship(t)
        q = np.array([1.0, 0.0, 0.0, 0.0]) if cfg.attitude is None or self._q is None \
            else self._q
        dets: list[DetectionSample] = []
        origin: list[int | None] = []
        truth: dict[int, np.ndarray] = {}
        lo, hi = cfg.el_limits
        for icao in sorted(self._air):
            a = self._air[icao]
            if t - a.t > cfg.max_age:
                continue
            p = a.ned + a.vel * (t - a.t)
            state = np.concatenate([p, a.vel])
            self.truth.setdefault(icao, []).append((t, state))
            if own is None:
                continue
            rae = rae_from_frd(quat_rotate_inv(q, p - own))
            if rae[0] > cfg.max_range or not lo <= rae[2] <= hi:
                continue
            truth[icao] = state
            hit = rng.random() < cfg.pd
            noise = rng.normal(size=3) * (cfg.sigma_r, cfg.sigma_az, cfg.sigma_el)
            if hit:
                z = rae + noise
                z[1] = (z[1] + math.pi) % (2 * math.pi) - math.pi
                dets.append(self._det(t, z, q, own))
                origin.append(icao)
        if own is not None:
            for _ in range(int(rng.poisson(cfg.clutter_rate))):
                z = np.array([rng.uniform(0.0, cfg.max_range), rng.uniform(-math.pi, math.pi),
                              rng.uniform(lo, hi)])
                dets.append(self._det(t, z, q, own))
                origin.append(None)
            order = rng.permutation(len(dets))  # the order must not give the origin away
            dets = [dets[i] for i in order]
            origin = [origin[i] for i in order]
        self.scans += 1
        return DetectionScan(t, tuple(dets), "adsb_radar", tuple(origin), truth)

    def _det(self, t: float, z: np.ndarray, q: np.ndarray, own: np.ndarray) -> DetectionSample:
        # sensor axes: body FRD with an attitude, else NED (q = identity): "BODY_NED"
        frame = "BODY_NED" if self.config.attitude is None else "BODY_FRD"
        return DetectionSample(t, _UNKNOWN_ID, frd_from_rae(z), frame, z, 0.0,
                               self.config.max_range, "adsb_radar", 3, q, own.copy())

    def truth_arrays(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """ICAO -> (t (K,) s, states (K, 6) m, m/s local NED) of :attr:`truth`."""
        return {k: (np.array([x[0] for x in v]), np.array([x[1] for x in v]))
                for k, v in self.truth.items()}


def virtual_radar(
    samples: Iterable, rng: np.random.Generator, config: RadarConfig | None = None,
    *, radar: AdsbRadar | None = None,
) -> Iterator:
    """Streaming stage: pass ``samples`` through and insert the virtual radar's scans.

    ``rng`` is the only source of randomness (seed it per stream, e.g.
    ``np.random.default_rng(seed)``).  Pass ``radar`` (an :class:`AdsbRadar`) to read its
    ``truth`` afterwards; otherwise one is made from ``rng`` and ``config``.
    """
    r = radar if radar is not None else AdsbRadar(rng, config or RadarConfig())
    for s in samples:
        yield from r.push(s)
        yield s
