"""The channels uavest publishes to Foxglove (MCAP recordings, the live WebSocket view),
per domain, composed by one :class:`FoxglovePublisher` (see :mod:`.publisher` and
``docs/recording.md`` for the channel list):

* :mod:`.schemas`: the JSON schemas of uavest's JSON channels;
* :mod:`.channels`: the channels of one context, made on first use and counted;
* :mod:`.frames`: NED/FRD -> ENU/FLU, the 3-D channels (``/tf``, poses, body markers);
* :mod:`.attitude`: raw samples, references, attitude estimates, health and errors;
* :mod:`.state`: generic vector states;
* :mod:`.radar`: radar scans, true targets and tracks;
* :mod:`.encode`: values to message fields, and the recorder's packed fields read back.
"""

from .attitude import euler_sigma_deg, quat_to_rpy_deg
from .encode import b64_floats, triu_to_full
from .frames import DEFAULT_FRAME_RATE_HZ, ned_frd_to_enu_flu
from .publisher import FoxglovePublisher
from .schemas import SCHEMAS

__all__ = [
    "DEFAULT_FRAME_RATE_HZ", "FoxglovePublisher", "SCHEMAS", "euler_sigma_deg",
    "ned_frd_to_enu_flu",
    "b64_floats", "quat_to_rpy_deg", "triu_to_full",
]
