"""The MAVLink link: bytes to and from a vehicle, a ground station or a simulator peer.

Shared by the live source (:mod:`uavest.ingest.live`), the estimate publisher
(:mod:`uavest.sinks.mavlink_pub`) and the simulator (:mod:`uavest.sim.mavlink`); knows
nothing of samples, filters or records (only :mod:`uavest.errors` and pymavlink):

* :mod:`.transport`: connection strings (``udpin:``, ``udpout:``, ``tcp:``, ``tcpin:``, a
  serial device), :class:`Transport` (raw bytes over UDP, TCP or serial), the endpoint key
  and the registry of the endpoints open as a vehicle link;
* :mod:`.signing`: MAVLink 2 signing (the key, signing what we send, the strict check of
  what we receive);
* :mod:`.framing`: MAVLink 2 frames as bytes (the encoder buffer, tlog records and the
  tlog writer, the parser's left-over bytes and bad packets classified);
* :mod:`.spec`: the ``SPEC_*`` parameters in which a vehicle (the simulator) states its
  sensors' datasheet, and their reading.

See ``docs/live.md``.
"""

import os

os.environ.setdefault("MAVLINK20", "1")  # before any pymavlink.mavutil import (signing)

from .framing import (  # noqa: E402
    FrameEncoder,
    TlogWriter,
    bad_data_kind,
    param_name,
    reset_parser,
    tlog_record,
)
from .signing import SIGNING_EPOCH, enable_signing, signing_key_bytes  # noqa: E402
from .transport import (  # noqa: E402
    Disconnected,
    Transport,
    Writer,
    endpoint_key,
    is_vehicle_endpoint,
    register_vehicle_endpoint,
    split_conn,
    unregister_vehicle_endpoint,
)

__all__ = ["Disconnected", "FrameEncoder", "SIGNING_EPOCH", "TlogWriter", "Transport", "Writer",
           "bad_data_kind", "param_name",
           "enable_signing", "endpoint_key", "is_vehicle_endpoint",
           "register_vehicle_endpoint", "reset_parser", "signing_key_bytes", "split_conn",
           "tlog_record", "unregister_vehicle_endpoint"]
