"""Issue: a SITL telemetry log that opens with the SITL's console text (one 8-byte record
time + one byte of text per record, ~150 records of "Init ArduRover V4.7.0-dev ...") made
``uavest replay`` exit 2 ("no IMU samples could be read"): the tlog reader never got back
in step, while pymavlink's own ``mavlogdump.py`` reads every message of the same file.

Reproduced from the shared vtol.tlog by modification (banner prepended, random garbage
records inserted, the last frame cut) and compared, message type by message type, with
pymavlink's own decoding as mavlogdump.py does it (``mavutil.mavlink_connection`` and a
``recv_match`` loop, MAVLink 2, robust parsing off and on) in a real subprocess: uavest
must never decode fewer messages of any type.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_log

from tests.hostile.corpus import tlog_records
from uavest.cli import main
from uavest.ingest.mavlink import MavlinkSource

# each test decodes whole logs with uavest and pymavlink: seconds of CPU each
pytestmark = pytest.mark.slow

BANNER = (b"Init ArduRover V4.7.0-dev (8a1b2c3d)\r\n\r\nFree RAM: 131072\r\nFRAM: 0\r\n"
          b"Starting SITL input...\r\nbind port 5760 for 0\r\nSerial port 0 on TCP port "
          b"5760\r\nWaiting for connection ....\r\n")[:150]

# mavlogdump.py's reading loop (pymavlink/tools/mavlogdump.py: MAVLINK20 set, the
# ardupilotmega dialect, recv_match until None), with --robust off and on
_MAVLOGDUMP = r"""
import collections, json, os, sys
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
out = {}
for robust in (False, True):
    mlog = mavutil.mavlink_connection(sys.argv[1], robust_parsing=robust,
                                      dialect="ardupilotmega")
    c = collections.Counter()
    try:
        while True:
            m = mlog.recv_match(blocking=False)
            if m is None:
                break
            c[m.get_type()] += 1
    except Exception as e:  # mavlogdump.py would stop here too
        c["EXCEPTION " + type(e).__name__] += 1
    out[str(robust)] = c
print(json.dumps(out))
"""

KEY_TYPES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "ATTITUDE", "SIMSTATE",
             "AHRS2", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "LOCAL_POSITION_NED")


def _pymavlink_counts(path) -> dict[str, int]:
    """Per type, the most messages pymavlink decodes (robust parsing off or on)."""
    env = {k: v for k, v in os.environ.items() if k != "MAVLINK20"}
    r = subprocess.run([sys.executable, "-c", _MAVLOGDUMP, str(path)], capture_output=True,
                       text=True, env=env, timeout=300, check=True)
    both = json.loads(r.stdout.strip().splitlines()[-1])
    best: dict[str, int] = {}
    for c in both.values():
        for k, v in c.items():
            if k != "BAD_DATA" and not k.startswith(("UNKNOWN", "EXCEPTION")):
                best[k] = max(best.get(k, 0), v)
    return best


def _uavest(path):
    src = MavlinkSource(path, "tlog")
    for _ in src:
        pass
    return src.stats


def _banner(data: bytes) -> bytes:
    (t0,) = struct.unpack(">Q", data[:8])
    out = bytearray()
    for i, c in enumerate(BANNER):
        out += struct.pack(">Q", t0 - 5_000_000 + 2_000 * i) + bytes([c])
    return bytes(out) + data


def _garbage(data: bytes, seed: int = 20) -> bytes:
    """40 records of random bytes (1-60, a third starting with a MAVLink 2 marker: frame
    headers whose frame is cut) inserted between records, each with a plausible time."""
    rng = np.random.default_rng(seed)
    recs = tlog_records(data)
    at = sorted(rng.choice(len(recs), 40, replace=False))
    out, last = bytearray(), 0
    for k, i in enumerate(at):
        off = recs[i][0]
        out += data[last:off]
        body = bytearray(rng.integers(0, 256, int(rng.integers(1, 61)), dtype=np.uint8))
        if k % 3 == 0:
            body[0] = 0xFD
        out += data[off:off + 8] + body
        last = off
    return bytes(out + data[last:])


def _cut_last(data: bytes) -> bytes:
    off, ln, _ = tlog_records(data)[-1]
    return data[: off + 8 + ln // 2]


CASES = {"as is": lambda d: d, "banner prepended": _banner, "garbage records": _garbage,
         "last frame cut": _cut_last, "banner + garbage + cut": lambda d: _cut_last(
             _garbage(_banner(d)))}


@pytest.mark.parametrize("case", list(CASES))
def test_uavest_decodes_at_least_what_pymavlink_does(tmp_path, case):
    p = tmp_path / "case.tlog"
    p.write_bytes(CASES[case](shared_log("vtol.tlog").read_bytes()))
    ref = _pymavlink_counts(p)
    st = _uavest(p)
    assert ref.get("RAW_IMU", 0) > 700, ref  # pymavlink reads this log: a real comparison
    less = {k: (st.messages[k], v) for k, v in ref.items() if st.messages[k] < v}
    assert not less, f"uavest decoded fewer than pymavlink (uavest, pymavlink): {less}"
    for k in KEY_TYPES:
        assert st.messages[k] >= ref.get(k, 0)
    sk = st.skipped
    if "banner" in case:
        assert sk["text_bytes"] >= len(BANNER) and st.non_mavlink >= 1
    if "garbage" in case:
        assert sk["junk_bytes"] + sk["partial_frame"] > 0 and st.corrupt > 0
    if "cut" in case:
        assert st.truncated == 1 and sk["truncated_bytes"] > 0
    if case == "as is":
        assert not sk and st.bad_total == _uavest(shared_log("vtol.tlog")).bad_total


def test_repo_sim_log_decodes_at_least_what_pymavlink_does():
    """The project's own simulator log (logs/sim_200hz.tlog), as is."""
    p = Path(__file__).resolve().parents[2] / "logs" / "sim_200hz.tlog"
    if not p.is_file():
        pytest.skip(f"{p} not present")
    ref, st = _pymavlink_counts(p), _uavest(p)
    assert ref and not {k for k, v in ref.items() if st.messages[k] < v}


def test_decode_all_and_skipping_reader_agree_on_the_damaged_copy(tmp_path):
    """Both reader paths share one framer: same counts, same skipped kinds."""
    p = tmp_path / "all.tlog"
    p.write_bytes(CASES["banner + garbage + cut"](shared_log("vtol.tlog").read_bytes()))
    a, b = MavlinkSource(p, "tlog"), MavlinkSource(p, "tlog")
    b._decode_all = True
    na, nb = sum(1 for _ in a), sum(1 for _ in b)
    assert na == nb > 1000 and a.undecoded > 0 == b.undecoded
    assert a.stats.as_dict() == b.stats.as_dict()


def test_replay_of_the_banner_log_runs_and_names_what_was_skipped(tmp_path, capsys):
    p = tmp_path / "banner.tlog"
    p.write_bytes(_banner(shared_log("vtol.tlog").read_bytes()))
    assert main(["replay", str(p), "--filters", "ekf", "--no-progress"]) == 0
    out = capsys.readouterr()
    text = out.out + out.err
    assert f"text bytes {len(BANNER)}" in text and "UNRELIABLE" not in text
