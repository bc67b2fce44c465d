"""Built-in vehicle-and-radar simulator speaking MAVLink 2 (``uavest sim``).

* :mod:`.vehicle`: multirotor truth motion (scenario manoeuvres);
* :mod:`.sensors`: IMU / magnetometer, GPS, the autopilot's estimate errors, ADS-B reports;
* :mod:`.radar`: target aircraft and the body-fixed radar;
* :mod:`.protocol`: the ArduPilot-like MAVLink protocol (schedule, requests, messages);
* :mod:`.truth`: the truth history (``truth_at``) and the truth CSV;
* :mod:`uavest.geometry.geodesy`: WGS84 geodetic <-> local NED (shared with ingest);
* :mod:`uavest.link`: the transport and the frame encoder (shared with the live link);
* :mod:`.mavlink`: :class:`Simulator`, the composition stepped at the IMU rate.

See ``docs/sim.md``.
"""

from .mavlink import STREAMS, TRUTH_COLUMNS, RunSummary, Simulator, Truth, VehicleTruth
from .radar import CLUTTER_ID, Detection, Radar, Targets

__all__ = ["CLUTTER_ID", "STREAMS", "TRUTH_COLUMNS", "Detection", "Radar", "RunSummary",
           "Simulator", "Targets", "Truth", "VehicleTruth"]
