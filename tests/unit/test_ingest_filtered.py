"""The file readers decode only the record types the converters and the reader use
(``uavest/ingest/skip.py``); everything they yield and count must be what decoding every
record gives: the same samples (types, times, values), the same stats (bad-data counts,
per-type message counts, accepted/rejected), the same params, geo fix and end position.

Compared on the shared logs (``vtol.tlog``, ``test.BIN``), ``logs/sim_200hz.tlog`` and on
damaged copies in tmp_path: random bit flips, cuts inside a record, CRC errors in a record
of an unused type and of a used one, junk between records, a bad receive time on an unused
record, bad MAVLink 2 flags, broken DataFlash headers and unknown DataFlash types.
A damaged record of an unused type is still counted exactly as before: the skipper steps
over good records only and hands everything else to pymavlink.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_logs_dir

from tests.hostile.corpus import df_records as _df_records
from tests.hostile.corpus import flip_bits as _flip_bits
from uavest.ingest import IngestError
from uavest.ingest.api import detect_format
from uavest.ingest.mavlink import MavlinkSource

REPO = Path(__file__).resolve().parents[2]
SIM_200HZ = REPO / "logs" / "sim_200hz.tlog"


def _shared_logs() -> Path | None:
    """The shared read-only logs (tests/conftest.py: $UAVEST_LOGS or repo_root/../shared/logs)."""
    d = shared_logs_dir()
    return d if (d / "vtol.tlog").is_file() else None


@pytest.fixture(scope="module")
def shared() -> Path:
    d = _shared_logs()
    if d is None:
        pytest.skip(f"shared logs (vtol.tlog, test.BIN) not found in {shared_logs_dir()} "
                    "(repo_root/../shared/logs, or set UAVEST_LOGS)")
    return d


# ------------------------------------------------------------------------- comparison


def _read(path: Path, decode_all: bool, sysid: int | None = None) -> dict:
    src = MavlinkSource(path, detect_format(str(path)), sysid=sysid)
    src._decode_all = decode_all
    try:
        samples = list(src)
    except IngestError as e:  # a log pymavlink cannot open: the same error either way
        return {"error": str(e), "undecoded": 0, "samples": []}
    return {"samples": samples, "stats": src.stats.as_dict(), "params": dict(src.params),
            "geo": src.params.geo, "bytes_read": src.bytes_read, "undecoded": src.undecoded}


def _same_value(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same_value(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return len(a) == len(b) and all(_same_value(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def _assert_same(path: Path, sysid: int | None = None, expect_skips: bool = True) -> dict:
    old = _read(path, decode_all=True, sysid=sysid)
    new = _read(path, decode_all=False, sysid=sysid)
    assert new.get("error") == old.get("error")
    assert "error" not in old, f"{path} cannot be read: pick another damage ({old['error']})"
    assert old["undecoded"] == 0
    if expect_skips:
        assert new["undecoded"] > 0, "nothing was skipped: the test would prove nothing"
    assert len(new["samples"]) == len(old["samples"])
    for i, (a, b) in enumerate(zip(old["samples"], new["samples"], strict=True)):
        assert type(a) is type(b), (i, a, b)
        for f in dataclasses.fields(a):
            va, vb = getattr(a, f.name), getattr(b, f.name)
            assert _same_value(va, vb), (i, type(a).__name__, f.name, va, vb)
    assert new["stats"] == old["stats"]
    assert new["params"] == old["params"]
    assert new["geo"] == old["geo"]
    assert new["bytes_read"] == old["bytes_read"]
    return new


# ------------------------------------------------------------------------- damage


def _tlog_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, length, msgid) of each record: 8-byte big-endian time + MAVLink frame."""
    out, pos, n = [], 0, len(data)
    while pos + 16 <= n:
        stx = data[pos + 8]
        if stx == 0xFE:
            ln, mid = 8 + 8 + data[pos + 9], data[pos + 13]
        elif stx == 0xFD:
            ln = 8 + 12 + data[pos + 9] + (13 if data[pos + 10] & 1 else 0)
            mid = data[pos + 15] | data[pos + 16] << 8 | data[pos + 17] << 16
        else:
            pos += 1
            continue
        out.append((pos, ln, mid))
        pos += ln
    return out



def _nth(recs, key, which: int):
    return [r for r in recs if r[2] == key][which]


VFR_HUD, ATTITUDE, HEARTBEAT = 74, 30, 0  # VFR_HUD and HEARTBEAT: unused (skipped) types


def _tlog_damage(data: bytes) -> dict[str, bytes]:
    recs = _tlog_records(data)
    out = {
        "flip 1e-3 s0": _flip_bits(data, 1e-3, 0),
        "flip 1e-3 s1": _flip_bits(data, 1e-3, 1),
        "flip 1e-2": _flip_bits(data, 1e-2, 2),
        "cut inside a record": data[: recs[len(recs) // 2][0] + 11],
        "cut after a time stamp": data[: recs[len(recs) // 3][0] + 8],
    }
    b = bytearray(data)
    for which in (3, 40, 41):  # a CRC error in a record of an unused type
        off, ln, _ = _nth(recs, VFR_HUD, which)
        b[off + ln - 3] ^= 0x5A
    off, ln, _ = _nth(recs, ATTITUDE, 20)  # ... and in one of a used type
    b[off + ln - 3] ^= 0x5A
    out["crc errors"] = bytes(b)
    b = bytearray(data)
    b[_nth(recs, HEARTBEAT, 5)[0]] |= 0x80  # receive time off by centuries, unused record
    b[_nth(recs, VFR_HUD, 60)[0] + 3] ^= 0x10  # a smaller step
    out["bad receive times"] = bytes(b)
    b = bytearray(data)
    off = _nth(recs, VFR_HUD, 30)[0]
    if b[off + 8] == 0xFD:
        b[off + 10] |= 0x04  # MAVLink 2 incompat flag pymavlink refuses
    off = _nth(recs, VFR_HUD, 31)[0]
    b[off + 8] = 0x55  # not a frame marker: the parser resyncs
    out["bad frame headers"] = bytes(b)
    mid = recs[len(recs) // 4][0]
    junk = np.random.default_rng(5).integers(0, 256, 300, dtype=np.uint8).tobytes()
    out["junk between records"] = data[:mid] + junk + data[mid:]
    out["text between records"] = data[:mid] + b"SITL banner text\r\n" * 4 + data[mid:]
    return out


def _df_damage(data: bytes) -> dict[str, bytes]:
    recs = _df_records(data)
    hdr = max(off + ln for off, ln, name in recs if name == "FMT")  # formats: intact
    out = {
        "flip 1e-3 s0": _flip_bits(data, 1e-3, 0, skip=hdr),
        "flip 1e-3 s1": _flip_bits(data, 1e-3, 1, skip=hdr),
        "flip 1e-2": _flip_bits(data, 1e-2, 2, skip=hdr),
        "cut inside a record": data[: recs[len(recs) // 2][0] + 7],
        "random after header": data[:hdr] + np.random.default_rng(3).integers(
            0, 256, 20_000, dtype=np.uint8).tobytes(),
    }
    b = bytearray(data)
    unused = [r for r in recs if r[2] in ("PIDR", "NKF1", "CTUN")]
    b[unused[5][0] + 1] = 0x00  # broken header of an unused record: resync
    b[unused[9][0] + 2] = 0xFB  # unknown type id
    b[unused[12][0] + 3] ^= 0xFF  # payload byte of an unused record (no CRC in DataFlash)
    out["bad record headers"] = bytes(b)
    b = bytearray(data)
    fmt = [r for r in recs if r[2] == "FMT"][40]
    b[fmt[0] + 4] = 7  # a FMT record with a length its format does not match
    out["bad FMT length"] = bytes(b)
    return out


# ------------------------------------------------------------------------- tests


@pytest.mark.slow
@pytest.mark.parametrize("sysid", [None, 2])
def test_vtol_tlog_same_as_decoding_everything(shared, sysid):
    new = _assert_same(shared / "vtol.tlog", sysid=sysid)
    # the converters use about a third of this log's records
    assert new["undecoded"] > 0.5 * sum(new["stats"]["messages"].values())
    if sysid == 2:
        assert new["stats"]["wrong_sysid"] > 0 and not new["samples"]


def test_dataflash_bin_same_as_decoding_everything(shared):
    _assert_same(shared / "test.BIN")


@pytest.mark.slow
def test_sim_200hz_tlog_same_as_decoding_everything():
    if not SIM_200HZ.is_file():
        pytest.skip(f"{SIM_200HZ} not present")
    _assert_same(SIM_200HZ)


@pytest.fixture(scope="module")
def vtol_part(shared) -> bytes:
    """The first 40 % of vtol.tlog, cut at a record boundary (keeps the test short)."""
    data = (shared / "vtol.tlog").read_bytes()
    recs = _tlog_records(data)
    return data[: recs[len(recs) * 2 // 5][0]]


def _slow(*cases: str) -> list:
    return [pytest.param(c, marks=pytest.mark.slow) for c in cases]


# the fast tier keeps two kinds of damage (a byte flip, CRC errors), the full suite all ten
@pytest.mark.parametrize("case", ["flip 1e-3 s0", "crc errors"] + _slow(
    "flip 1e-3 s1", "flip 1e-2", "cut inside a record", "cut after a time stamp",
    "bad receive times", "bad frame headers", "junk between records", "text between records"))
def test_damaged_tlog_same_counts(vtol_part, tmp_path, case):
    p = tmp_path / "damaged.tlog"
    p.write_bytes(_tlog_damage(vtol_part)[case])
    new = _assert_same(p)
    assert new["stats"]["bad_total"] > 0 or case.startswith("text")


@pytest.mark.parametrize("case", [
    "flip 1e-3 s0", "flip 1e-3 s1", "flip 1e-2", "cut inside a record",
    "random after header", "bad record headers", "bad FMT length"])
def test_damaged_dataflash_same_counts(shared, tmp_path, case):
    p = tmp_path / "damaged.bin"
    p.write_bytes(_df_damage((shared / "test.BIN").read_bytes())[case])
    _assert_same(p, expect_skips=case != "random after header")  # random: no whole record


def test_crc_error_in_unused_record_is_counted(vtol_part, tmp_path):
    """A record of a type no converter uses with a bad CRC is still one ``corrupt``."""
    recs = _tlog_records(vtol_part)
    off, ln, _ = _nth(recs, VFR_HUD, 10)
    b = bytearray(vtol_part)
    b[off + ln - 3] ^= 0x5A
    p = tmp_path / "crc.tlog"
    p.write_bytes(bytes(b))
    clean = tmp_path / "clean.tlog"
    clean.write_bytes(vtol_part)
    c, d = _read(clean, False), _read(p, False)
    assert d["stats"]["corrupt"] == c["stats"]["corrupt"] + 1
    assert d["stats"]["messages"]["VFR_HUD"] == c["stats"]["messages"]["VFR_HUD"] - 1


def test_progress_position_advances_over_skipped_records(shared):
    """``bytes_read`` (the progress bar's position) moves while unused records are skipped
    and ends at the file size, as when every record is decoded."""
    path = shared / "vtol.tlog"
    src = MavlinkSource(path, "tlog")
    seen = [src.bytes_read for _ in src]
    assert src.undecoded > 0
    assert seen == sorted(seen) and seen[-1] == path.stat().st_size
    assert len(set(seen)) > 100


@pytest.mark.parametrize("damaged", [False, True])
def test_skipped_records_keep_type_system_and_receive_time(vtol_part, tmp_path, damaged):
    """Record by record, the reader yields the same (type, system id, receive time) with or
    without decoding: a skipped record's stand-in carries what the reader uses of it."""
    from uavest.ingest.skip import Skipped

    data = _flip_bits(vtol_part, 1e-3, 7) if damaged else vtol_part
    p = tmp_path / "part.tlog"
    p.write_bytes(data)

    def records(decode_all: bool):
        src = MavlinkSource(p, "tlog")
        src._decode_all = decode_all
        out = [(m.get_type(), m.get_srcSystem(), rx, isinstance(m, Skipped))
               for m, rx in src._messages()]
        return out, src.stats.as_dict()

    old, st_old = records(True)
    new, st_new = records(False)
    assert [r[:3] for r in new] == [r[:3] for r in old] and st_new == st_old
    assert not any(r[3] for r in old) and sum(r[3] for r in new) > len(new) / 2
