"""MAVLink 2 signing: the key, signing what we send, and a strict check of what we receive.

The check (:func:`enable_signing` with ``verify=True``) replaces pymavlink's: pymavlink
stores a packet's timestamp *before* checking its signature, so one forged packet with a
future timestamp would block the real stream; here the HMAC is checked first, then the
per-stream timestamp (a replayed or duplicated packet, or a new stream more than a minute
in the past, is refused).
"""

from __future__ import annotations

import contextlib
import hashlib
import struct
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

from ..errors import InputError

__all__ = ["SIGNING_EPOCH", "enable_signing", "signature_checker", "signing_key_bytes"]

#: The MAVLink signing time base (UNIX s): signing timestamps count 10 us from here.
SIGNING_EPOCH = datetime(2015, 1, 1, tzinfo=UTC).timestamp()


def signing_key_bytes(key: str | bytes | Path) -> bytes:
    """The 32-byte MAVLink 2 signing key.

    ``bytes`` of length 32 are the key.  A path to an existing file: its content, if it is
    32 bytes, else its text stripped is a passphrase.  Any other string is a passphrase;
    key = sha256(passphrase), the MAVProxy ``signing setup`` convention.
    """
    if isinstance(key, bytes):
        if len(key) != 32:
            raise InputError(f"signing key must be 32 bytes, got {len(key)}")
        return key
    p = Path(str(key))
    with contextlib.suppress(OSError):
        if p.is_file():
            data = p.read_bytes()
            if len(data) == 32:
                return data
            key = data.decode("utf-8", "replace").strip()
    if not str(key):
        raise InputError("empty signing passphrase")
    return hashlib.sha256(str(key).encode("utf-8")).digest()


def signature_checker(mav) -> Callable[[bytes, int, int], bool]:
    """A ``check_signature(msgbuf, src_system, src_component)`` for the pymavlink ``MAVLink``
    object ``mav``: HMAC first, then the per-stream timestamp (replay)."""

    def check(msgbuf, src_system: int, src_component: int) -> bool:
        sig = mav.signing
        h = hashlib.sha256()
        h.update(sig.secret_key)
        h.update(msgbuf[:-6])
        if h.digest()[:6] != bytes(msgbuf[-6:]):
            return False
        tlow, thigh = struct.unpack("<IH", bytes(msgbuf[-12:-6]))
        ts = tlow + (thigh << 32)
        key = (msgbuf[-13], src_system, src_component)
        last = sig.stream_timestamps.get(key)
        if last is not None and ts <= last:
            return False  # replayed or duplicated signed packet
        if last is None and ts + 6000 * 1000 < sig.timestamp:
            return False  # a new stream more than a minute in the past
        sig.stream_timestamps[key] = ts
        sig.timestamp = max(sig.timestamp, ts)
        return True

    return check


def enable_signing(mav, key: bytes, *, verify: bool) -> None:
    """Sign what ``mav`` (a pymavlink ``MAVLink``) sends with ``key`` (32 bytes), the
    timestamp starting at the host's clock. ``verify``: also refuse every unsigned or
    wrongly signed packet it parses (link id 0, the strict :func:`signature_checker`)."""
    s = mav.signing
    s.secret_key = key
    s.sign_outgoing = True
    if verify:
        s.link_id = 0
    s.timestamp = int((time.time() - SIGNING_EPOCH) * 1e5)
    if verify:
        s.allow_unsigned_callback = lambda _mav, _msgid: False
        mav.check_signature = signature_checker(mav)
