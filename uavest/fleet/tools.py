"""Small log tools for evaluations: cut a time window out of a tlog."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cut_tlog"]


def cut_tlog(src: str | Path, dst: str | Path, start: float, end: float,
             keep: tuple[str, ...] = ("PARAM_VALUE",)) -> int:
    """Write the records of tlog ``src`` whose tlog timestamps lie in [t0 + start, t0 +
    end) (t0: the first record) to ``dst``, plus every earlier record of a type in
    ``keep`` (the parameters, e.g. the declination); returns the number of records.

    Records are copied byte for byte, found by the reader's own framer
    (:class:`uavest.ingest.skip.TlogFramer`, MAVLink 2 dialect), so the cut does not
    depend on the dialect ``pymavlink.mavutil`` happened to load first."""
    import mmap

    from pymavlink.dialects.v20 import ardupilotmega as mod

    from ..ingest.skip import TlogFramer

    names = {mid: cls.msgname for mid, cls in mod.mavlink_map.items()}
    n, t0 = 0, None
    with open(src, "rb") as f, open(dst, "wb") as out:
        if not os.fstat(f.fileno()).st_size:
            return 0
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            fr = TlogFramer(mm, mod)
            o = 0
            while o < fr.size:
                o, verdict, stop, mid, _ = fr.next(o)
                if verdict == "eof":
                    break
                ts = fr.rx(o)
                t0 = ts if t0 is None else t0
                rel = ts - t0
                if rel >= end:
                    break
                if verdict == "ok" and (rel >= start or names.get(mid) in keep):
                    out.write(mm[o:stop])
                    n += 1
                o = stop
    return n
