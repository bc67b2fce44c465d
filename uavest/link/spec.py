"""A vehicle's sensor datasheet as parameters: the ``SPEC_*`` parameters.

A vehicle (uavest's own simulator, ``uavest sim``, answers them; an autopilot may be
given them as user parameters) states its sensors' noise the way a user would take it
from their datasheets. ``uavest run`` asks for them with the vehicle's other parameters,
and a log that carries them (a ``uavest sim --params --tlog`` log, a live session's tlog)
hands them to the replay. The navigation model takes them where the options leave a
value open (docs/navigation.md, "The vehicle's sensor spec"): they are the sensors'
statement about themselves, as ``INS_GYRO_FILTER`` is ArduPilot's about its IMU filter.

The names are none of ArduPilot's or PX4's (whose ``SIM_*`` simulator parameters mean
amplitudes of their own simulators' noise, not densities), and at most 16 characters
(MAVLink ``param_id``).
"""

from __future__ import annotations

import math
from typing import Any

#: parameter -> (the navigation model's noise name (``NavNoise`` field), unit, meaning)
SPEC_PARAMS: dict[str, tuple[str, str, str]] = {
    "SPEC_GYR_NSD": ("gyro_noise", "rad/s/sqrt(Hz)", "the gyro's noise density"),
    "SPEC_MAG_NSR": ("mag_noise", "rad",
                     "the magnetometer's per-sample noise over the field's intensity"),
    "SPEC_GPS_SDH": ("gnss_bias_h", "m",
                     "the receiver's horizontal position error (Gauss-Markov std)"),
    "SPEC_GPS_SDV": ("gnss_bias_v", "m",
                     "the receiver's vertical position error (Gauss-Markov std)"),
    "SPEC_GPS_TAU": ("gnss_bias_tau", "s", "that error's time constant"),
    "SPEC_GPS_DLY": ("gnss_delay", "s",
                     "the age of a fix when it is stamped (0: stamped when measured)"),
}

#: the noise name -> its parameter
PARAM_OF: dict[str, str] = {v[0]: k for k, v in SPEC_PARAMS.items()}


def sensor_spec(params: dict[str, Any]) -> tuple[dict[str, float], list[str]]:
    """(the spec: noise name -> value, the parameters skipped as ``NAME=value (why)``)
    from a vehicle's or a log's parameters. A value must be a finite number, at least 0
    (a time constant more than 0, a delay at most 1 s); anything else is skipped and
    said, never taken."""
    spec: dict[str, float] = {}
    skipped: list[str] = []
    for name, (key, unit, _) in SPEC_PARAMS.items():
        if name not in params:
            continue
        raw = params[name]
        try:
            v = float(raw)
        except (TypeError, ValueError):
            skipped.append(f"{name}={raw!r} (not a number)")
            continue
        lo_ok = v > 0 if key == "gnss_bias_tau" else v >= 0
        if not math.isfinite(v) or not lo_ok or (key == "gnss_delay" and v > 1.0):
            skipped.append(f"{name}={v:g} (out of range for {unit})")
            continue
        spec[key] = v
    return spec, skipped


def spec_params(spec: dict[str, float]) -> dict[str, float]:
    """The parameters (name -> value) that state ``spec`` (noise name -> value; names
    with no parameter are left out): what a simulator answers."""
    return {PARAM_OF[k]: float(v) for k, v in spec.items() if k in PARAM_OF}


def describe(spec: dict[str, float]) -> str:
    """``SPEC_GYR_NSD 0.00015 rad/s/sqrt(Hz), ...`` for a decision line."""
    return ", ".join(f"{PARAM_OF[k]} {v:.3g} {SPEC_PARAMS[PARAM_OF[k]][1]}"
                     for k, v in spec.items() if k in PARAM_OF)
