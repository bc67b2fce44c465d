"""The live MAVLink link: a vehicle (autopilot or SITL) as a streaming sample source.

:class:`LiveLink` (made by :func:`open_live`, or by :func:`uavest.ingest.open_source` for a
connection string) owns a reader thread that reads raw bytes from UDP, TCP or a serial port
(the shared :mod:`uavest.link` transport), parses them with its own MAVLink 2 parser
(signing checked there, :mod:`uavest.link.signing`), filters one vehicle,
records the accepted frames to a tlog and puts them in a bounded queue.  Iterating the link
runs the *same* conversion / timing / ordering code as a file (:class:`MavlinkSource`), with
each message timed by its vehicle time field or, for untimed messages, by the receive time
that is also written to the tlog, so replaying the tlog gives the same samples.

The parts: :mod:`.link` (the link: reader thread, vehicle filter, lifecycle, status),
:mod:`.streams` (stream requests and the achieved-rate check), :mod:`.replies` (ACKs and
parameters awaited by the setup steps), :mod:`.declination` (COMPASS_DEC or the WMM) and
:mod:`.gaps` (link lost / restored events). See ``docs/live.md``.
"""

from .link import LinkTimeout, LiveLink, open_live
from .streams import DEFAULT_STREAMS, StreamStatus

__all__ = ["LiveLink", "open_live", "DEFAULT_STREAMS", "LinkTimeout", "StreamStatus"]
