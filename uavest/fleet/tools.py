"""Small log tools for evaluations: cut a time window out of a tlog."""

from __future__ import annotations

import struct
from pathlib import Path

__all__ = ["cut_tlog"]


def cut_tlog(src: str | Path, dst: str | Path, start: float, end: float,
             keep: tuple[str, ...] = ("PARAM_VALUE",)) -> int:
    """Write the records of tlog ``src`` whose tlog timestamps lie in [t0 + start, t0 +
    end) (t0: the first record) to ``dst``, plus every earlier record of a type in
    ``keep`` (the parameters, e.g. the declination); returns the number of records."""
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(src), notimestamps=False, robust_parsing=True)
    n, t0 = 0, None
    with open(dst, "wb") as out:
        while (m := mlog.recv_msg()) is not None:
            ts = getattr(m, "_timestamp", None)
            if ts is None or m.get_type() == "BAD_DATA":
                continue
            t0 = ts if t0 is None else t0
            rel = ts - t0
            if rel >= end:
                break
            if rel >= start or m.get_type() in keep:
                out.write(struct.pack(">Q", int(round(ts * 1e6))) + m.get_msgbuf())
                n += 1
    return n
