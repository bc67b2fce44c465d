"""Built-in vehicle-and-radar simulator speaking MAVLink 2 (``uavest sim``).

* :mod:`.vehicle`: multirotor truth motion (scenario manoeuvres) and IMU / magnetometer;
* :mod:`.radar`: target aircraft, the body-fixed radar and ADS-B;
* :mod:`uavest.geometry.geodesy`: WGS84 geodetic <-> local NED (shared with ingest);
* :mod:`.mavlink`: :class:`Simulator`, the ArduPilot-like MAVLink endpoint.

See ``docs/sim.md``.
"""

from .mavlink import STREAMS, TRUTH_COLUMNS, RunSummary, Simulator, Truth, VehicleTruth
from .radar import CLUTTER_ID, Detection, Radar, Targets

__all__ = ["CLUTTER_ID", "STREAMS", "TRUTH_COLUMNS", "Detection", "Radar", "RunSummary",
           "Simulator", "Targets", "Truth", "VehicleTruth"]
