"""The aiding a previous navigation result learned, for a live run to start with
(``uavest run --aiding-from FILE``).

A live run learns its GNSS delay, the GNSS velocity's window and the baro's delay only
once the vehicle has manoeuvred (:class:`~uavest.engine.gnss_delay.LiveDelayLearner`, 60 s
after its first step); until then it widens the GNSS velocity and the baro for timings
it does not know, and its tilt pays for it in the takeoff (docs/live.md). These are the
receiver's and the baro's properties, the same from one flight of a vehicle to the next,
so a run can start with what a previous one learned: a ``uavest run --json`` result (its
``gnss_delay_live``) or a ``uavest replay --json`` result of a log of the same vehicle
(its probe's ``gnss_delay_estimate``). Taken: the GNSS delay, the GNSS velocity's window,
the baro's noise (its spread against the GNSS height, at least
:data:`~uavest.engine.gnss_delay.BARO_NOISE_MIN`) and the magnetometer's (the spread of
its readings' direction, at least :data:`~uavest.engine.gnss_delay.MAG_NOISE_MIN`: a live
run learns it with the GNSS delay, 60 s in, when the attitude NEES of a live ArduCopter
SITL session had already been set by the profile's larger noise; started with it the
session's attitude NEES was in band on 0.86 of the airborne steps, against 0.78-0.79,
docs/live.md), and the magnetic field's inclination
where the result learned one (a replay's probe, a live run's learner or its filters'
magnetic reference states) with the place it was learned at (the result's ``origin``):
the field is the site's, not the vehicle's, and a run starting more than
:data:`~uavest.engine.nav_align.MAG_SITE_KM` km from there does not take it (a live run
otherwise starts on the angle between its accelerometer and magnetometer, which an
accelerating start bends: docs/live.md). Not taken: the baro's delay, which
changed from 44 to 96 ms between sessions of one ArduCopter SITL (taken from the previous
session, it put the pitch of the next back where it was without any: docs/live.md). The
run still learns its own and takes them when it has them; options given on the command
line win over the file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from ..engine.nav_align import MAG_SITE_KM
from ..errors import InputError

__all__ = ["AIDING", "AIDING_KEYS", "MAG_SITE_KM", "aiding_hint", "aiding_words", "read_aiding"]

#: What a result may give, with the words and unit it is said in: the GNSS delay (s), the
#: GNSS velocity's window (s), the baro's noise (m), the magnetometer's noise (rad, the
#: std of the field's direction per axis), the field's inclination (rad, said in degrees;
#: read with where it was learned, ``mag_site_lat`` / ``mag_site_lon`` deg).
AIDING = {"gnss_delay": ("GNSS delay", "s"), "gnss_vel_window": ("velocity window", "s"),
          "baro_noise": ("baro noise", "m"), "mag_noise": ("magnetometer noise", "rad"),
          "mag_inclination": ("field inclination", "rad")}
AIDING_KEYS = tuple(AIDING)
#: the timings and noises: non-negative numbers, read alike from either kind of result
_TIMING_KEYS = ("gnss_delay", "gnss_vel_window", "baro_noise", "mag_noise")


def _model(doc: dict[str, Any]) -> Any:
    m = doc.get("model")
    return m.get("value") if isinstance(m, dict) else m


def _number(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) and f >= 0 else None


def read_aiding(path: str | Path) -> tuple[dict[str, float], str]:
    """({name: value} of :data:`AIDING_KEYS` the result at ``path`` learned, the words
    saying where they come from). A file that cannot be read, is not JSON, is not a
    navigation result or learned none of them: :class:`InputError`, one line."""
    try:
        doc = json.loads(Path(path).read_text())
    except OSError as e:
        raise InputError(f"--aiding-from {path}: cannot read it ({e.strerror or e})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"--aiding-from {path}: not a JSON result of uavest run or "
                         f"uavest replay ({e})") from None
    if not isinstance(doc, dict) or _model(doc) != "nav":
        raise InputError(f"--aiding-from {path}: not a navigation result of uavest run or "
                         "uavest replay (--json of a run with the navigation model)")
    got: dict[str, Any] = {}
    live = doc.get("gnss_delay_live")
    probe = doc.get("gnss_delay_estimate")
    if isinstance(live, dict):
        what = "a live run's estimates"
        got = {"gnss_delay": live.get("delay"), "gnss_vel_window": live.get("window"),
               "baro_noise": live.get("baro_noise"), "mag_noise": live.get("mag_noise")}
    elif isinstance(probe, dict):
        what = "a replay's estimates"
        baro = probe.get("baro") or {}
        got = {"gnss_delay": probe.get("delay_used"),
               "gnss_vel_window": probe.get("window_used"),
               "baro_noise": baro.get("noise_used"),
               "mag_noise": (probe.get("mag") or {}).get("noise_used")}
    else:
        what = ""
    out = {k: f for k in _TIMING_KEYS if (f := _number(got.get(k))) is not None}
    out.update(_inclination(doc, live, probe))
    if not out:
        raise InputError(f"--aiding-from {path}: the result learned none of the GNSS delay, "
                         "the GNSS velocity window, the baro and magnetometer noise and the "
                         "field's inclination")
    return out, f"{what} in {Path(path).name}"


def _inclination(doc: dict[str, Any], live: Any, probe: Any) -> dict[str, float]:
    """{"mag_inclination": rad, "mag_site_lat", "mag_site_lon": deg} the result ``doc``
    learned (a replay's probe; a live run's learner, else its first filter's magnetic
    reference states), or {} (none, or no ``origin`` to say where)."""
    inc: Any = None
    if isinstance(live, dict):
        inc = (live.get("inclination") or {}).get("value")
        if inc is None:
            rows = doc.get("attitude") if isinstance(doc.get("attitude"), dict) else {}
            refs = [r["mag_ref"] for r in rows.values()
                    if isinstance(r, dict) and isinstance(r.get("mag_ref"), dict)]
            if refs and refs[0].get("inclination_deg") is not None:
                inc = math.radians(float(refs[0]["inclination_deg"]))
    elif isinstance(probe, dict):
        inc = (probe.get("mag") or {}).get("inclination")
    origin = doc.get("origin")
    if not isinstance(origin, dict):
        return {}
    try:
        inc, lat, lon = float(inc), float(origin["lat"]), float(origin["lon"])
    except (TypeError, ValueError, KeyError):
        return {}
    if not (all(map(math.isfinite, (inc, lat, lon))) and abs(inc) < math.pi / 2
            and abs(lat) <= 90 and abs(lon) <= 180):
        return {}
    return {"mag_inclination": inc, "mag_site_lat": lat, "mag_site_lon": lon}


def aiding_words(key: str, value: float) -> str:
    """One aiding value in words: "GNSS delay 0.120 s", "field inclination 64.21 deg"."""
    name, unit = AIDING[key]
    if key == "mag_inclination":
        return f"{name} {math.degrees(value):.2f} deg"
    return f"{name} {value:.3f} {unit}"


def aiding_hint(path: str | Path, what: str) -> str | None:
    """The line that tells how to start a live run against the vehicle with what the
    ``what`` ("run", "replay") whose result is at ``path`` learned (``--aiding-from``);
    None when it learned nothing a live run would take."""
    try:
        got, _ = read_aiding(path)
    except InputError:
        return None
    said = ", ".join(aiding_words(k, v) for k, v in got.items() if k in AIDING)
    return (f"a live run against this vehicle can start with what this {what} learned "
            f"({said}): uavest run --model nav --aiding-from {path}")
