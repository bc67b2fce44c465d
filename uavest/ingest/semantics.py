"""What an IMU message's gyro value is, per format and autopilot (docs/ingest.md, "IMU
message semantics"), and so how a step of several samples is integrated by default.

Three kinds of gyro value (rad/s, body FRD, at the sample's time stamp t_i):

* **rate sample** (``rate_sample``): the sensor driver's latest (filtered) rate when the
  message was sent, at a few Hz (MAVLink ``RAW_IMU``, ``SCALED_IMU``/``2``/``3``,
  ``HIGHRES_IMU``). Between two samples the rate is best taken as linear: trapezoid.
* **filtered snapshot** (``filtered_snapshot``): ArduPilot DataFlash ``IMU`` (old logs:
  ``IMU``/``IMU2``/``IMU3``; new: ``IMU`` with instance ``I``): the low-pass filtered gyro
  and accelerometer as the main loop sees them, copied at the logging rate; it says
  nothing about the interval before it. At 25 Hz a snapshot is not the mean rate of the
  40 ms before it: trapezoid.
* **interval integral / average** (``integral``): the rotation over the interval ending at
  t_i, divided by its length: ArduPilot DataFlash ``IMT`` (``DelA``/``DelaT`` delta angle,
  ``DelV``/``DelvT`` delta velocity; not read by uavest), PX4 ULog ``sensor_combined``
  (``gyro_rad`` is the integral over ``gyro_integral_dt`` divided by it, the accelerometer
  likewise over ``accelerometer_integral_dt``). Held over the interval and pre-integrated
  exactly: hold.
"""

from __future__ import annotations

#: kind -> (default integration, how it is said in the output)
KINDS = {
    "rate_sample": ("trapezoid", "rate samples"),
    "filtered_snapshot": ("trapezoid", "filtered snapshots"),
    "integral": ("hold", "interval averages of integrated gyro"),
}

#: (source name prefix, format label, kind); first match wins. Source names are
#: :class:`uavest.ingest.types.ImuSample` ``source`` values.
IMU_SEMANTICS: tuple[tuple[str, str, str], ...] = (
    ("RAW_IMU", "MAVLink RAW_IMU", "rate_sample"),
    ("SCALED_IMU", "MAVLink SCALED_IMU", "rate_sample"),
    ("HIGHRES_IMU", "MAVLink HIGHRES_IMU", "rate_sample"),
    ("IMT", "DataFlash IMT", "integral"),
    ("IMU", "DataFlash IMU", "filtered_snapshot"),
    ("sensor_combined", "ULog sensor_combined", "integral"),
)

#: below this rate (Hz) an IMU of unknown kind is taken as rate samples (trapezoid)
SLOW_RATE_HZ = 20.0


def imu_semantics(source: str) -> tuple[str, str] | None:
    """(kind, format label) of the IMU source name, or None if not known."""
    for prefix, label, kind in IMU_SEMANTICS:
        if source.startswith(prefix):
            return kind, label
    return None


def default_integration(source: str, rate_hz: float) -> tuple[str, str]:
    """(integration, why) for an IMU source at ``rate_hz`` (Hz): by what its message is
    (:data:`IMU_SEMANTICS`), else by its rate (trapezoid below :data:`SLOW_RATE_HZ`)."""
    sem = imu_semantics(source)
    if sem is not None:
        integ, said = KINDS[sem[0]]
        return integ, f"{sem[1]}: {said}"
    if rate_hz < SLOW_RATE_HZ:
        return "trapezoid", f"unknown IMU message at {rate_hz:.3g} Hz < {SLOW_RATE_HZ:g} Hz"
    return "hold", f"unknown IMU message at {rate_hz:.3g} Hz >= {SLOW_RATE_HZ:g} Hz"
