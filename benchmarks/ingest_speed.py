"""Ingest speed: decoding only the record types the converters use (``uavest/ingest/skip.py``)
against decoding every record (``MavlinkSource._decode_all = True``).

    PYTHONPATH=$PWD python benchmarks/ingest_speed.py [--rounds 5] [--logs ../shared/logs]

In one process, for each log (``vtol.tlog`` and ``test.BIN`` from the shared logs,
``logs/sim_200hz.tlog``), the two paths alternate (the order flips every round) for
``--rounds`` rounds; the best time of each is kept. Two stages are timed:

* ``samples``: every sample of the log (``list(MavlinkSource(...))``: open, read, convert,
  check, time base, reorder), what a replay pays for ingest;
* ``records``: the reader alone (``MavlinkSource._messages()``: open and read the records,
  bad-data counting, receive-time check), where the decoding is.

Then, for each tlog, the decoding of its used records alone: pymavlink's ``decode``
against the reader's :class:`~uavest.ingest.skip.FrameDecoder` (the message class's own
struct for frames the framer has checked), best CPU time of ``--rounds`` alternating rounds.

Printed per log: records in the log, the share of them decoded (``used``), samples,
best CPU times of the process (s; ``time.process_time``, less disturbed than the wall clock
by other processes on a shared machine) of decoding every (``all``) and only the used
types (``used``), and used/all ratios (< 1: decoding only the used types is faster;
the wall-clock ratio in brackets), and whether both paths gave the same samples and stats
(checked on the first round). Only ratios mean anything on a shared, loaded machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from _shared_logs import SHARED_LOGS  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _shared(arg: str | None) -> Path | None:
    cands = [arg, SHARED_LOGS]
    for c in cands:
        if c and (Path(c) / "vtol.tlog").is_file():
            return Path(c)
    return None


def _source(path: Path, decode_all: bool):
    from uavest.ingest.api import detect_format
    from uavest.ingest.mavlink import MavlinkSource

    src = MavlinkSource(path, detect_format(str(path)))
    src._decode_all = decode_all
    return src


def _time_samples(path: Path, decode_all: bool) -> tuple[tuple[float, float], object, list]:
    src = _source(path, decode_all)
    c0, t0 = time.process_time(), time.perf_counter()
    out = list(src)
    return (time.process_time() - c0, time.perf_counter() - t0), src, out


def _time_records(path: Path, decode_all: bool) -> tuple[float, float]:
    src = _source(path, decode_all)
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in src._messages():
        pass
    return time.process_time() - c0, time.perf_counter() - t0


def _same(a: list, b: list) -> bool:
    """Same samples: types and every value (shortest round-trip float repr: exact)."""
    import numpy as np

    with np.printoptions(floatmode="unique", threshold=sys.maxsize):
        return len(a) == len(b) and all(repr(x) == repr(y) for x, y in zip(a, b, strict=True))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="alternating rounds (best of)")
    ap.add_argument("--logs", default=None, help="directory of vtol.tlog and test.BIN")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    shared = _shared(a.logs)
    logs = []
    if shared is None:
        print("shared logs not found (--logs DIR): vtol.tlog and test.BIN left out")
    else:
        logs += [shared / "vtol.tlog", shared / "test.BIN"]
    if (ROOT / "logs" / "sim_200hz.tlog").is_file():
        logs.append(ROOT / "logs" / "sim_200hz.tlog")
    print(f"best of {a.rounds} alternating rounds, one process; times in s of CPU time of the"
          " process (robust to other load; wall-clock ratio in brackets); ratio = used / all")
    print(f"{'log':<15} {'records':>7} {'decoded':>7} {'samples':>7} | "
          f"{'samples: all':>12} {'used':>6} {'ratio':>12} | "
          f"{'records: all':>12} {'used':>6} {'ratio':>12} | same")
    for path in logs:
        inf = (float("inf"), float("inf"))
        best = {(stage, every): inf for stage in ("s", "r") for every in (True, False)}
        same = None
        info = None
        for r in range(a.rounds):
            order = (True, False) if r % 2 == 0 else (False, True)
            got = {}
            for every in order:
                dt, src, out = _time_samples(path, every)
                best["s", every] = tuple(map(min, best["s", every], dt))
                got[every] = (src, out)
            for every in order:
                best["r", every] = tuple(map(min, best["r", every], _time_records(path, every)))
            if same is None:
                (so, oo), (sn, on) = got[True], got[False]
                same = _same(oo, on) and so.stats.as_dict() == sn.stats.as_dict()
                n = sum(sn.stats.messages.values())
                info = (n, (n - sn.undecoded) / n if n else 1.0, len(on))
        n, frac, ns = info
        cols = []
        for stage in ("s", "r"):
            o, w = best[stage, True], best[stage, False]
            ratio = f"{w[0] / o[0]:.2f} ({w[1] / o[1]:.2f})"
            cols.append(f"{o[0]:>12.3f} {w[0]:>6.3f} {ratio:>12}")
        print(f"{path.name:<15} {n:>7} {100 * frac:>6.1f}% {ns:>7} | {cols[0]} | {cols[1]} | "
              f"{'yes' if same else 'NO'}")
    print("\ndecoding the used records of a tlog, best CPU s: pymavlink's decode, the "
          "reader's FrameDecoder")
    for path in logs:
        if path.suffix == ".tlog":
            n, best = _time_decoders(path, a.rounds)
            print(f"{path.name:<15} {n:>7} records  decode {best['decode']:.3f}  frame "
                  f"{best['frame']:.3f}  ratio {best['frame'] / best['decode']:.2f}")
    return 0


def _time_decoders(path: Path, rounds: int) -> tuple[int, dict[str, float]]:
    """(used records, {"decode": best s, "frame": best s}) of decoding every used record
    of the tlog ``path`` with pymavlink's ``decode`` and with ``FrameDecoder``."""
    import mmap

    from pymavlink.dialects.v20 import ardupilotmega as mod

    from uavest.ingest.skip import TLOG_DECODED, FrameDecoder, TlogFramer

    mav = mod.MAVLink(None)
    mav.robust_parsing = True
    dec = FrameDecoder(mod, mav)
    best = {"decode": float("inf"), "frame": float("inf")}
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        recs = [r for r in TlogFramer(mm, mod).records()
                if mod.mavlink_map[r[2]].msgname in TLOG_DECODED]
        for r in range(rounds):
            for which in (("decode", "frame") if r % 2 == 0 else ("frame", "decode")):
                t = time.process_time()
                if which == "decode":
                    for o, end, _ in recs:
                        mav.decode(bytearray(mm[o:end]))
                else:
                    for o, end, mid in recs:
                        dec(mm, o, end, mid)
                best[which] = min(best[which], time.process_time() - t)
    return len(recs), best


if __name__ == "__main__":
    raise SystemExit(main())
