"""Telemetry log (.tlog) files: each MAVLink frame preceded by its receive time.

The format pymavlink's ``mavutil.mavlogfile`` reads (and MAVProxy / Mission Planner write): for every
frame, an 8-byte big-endian unsigned integer, microseconds since the Unix epoch, then the raw frame
(``struct.pack('>Q', usec) + msg.get_msgbuf()`` in ``mavutil.mavfile.post_message``).
"""

from __future__ import annotations

import os
import struct
from typing import Iterable

_STAMP = struct.Struct(">Q")


def tlog_record(recv_us: int, frame: bytes) -> bytes:
    if recv_us < 0 or recv_us >= 1 << 64:
        raise ValueError(f"receive time {recv_us} us does not fit the tlog's unsigned 64-bit stamp")
    return _STAMP.pack(recv_us) + frame


def tlog_bytes(records: Iterable[tuple[int, bytes]]) -> bytes:
    """The whole log as bytes from (receive time us since the Unix epoch, frame) pairs."""
    return b"".join(tlog_record(t, f) for t, f in records)


def write_tlog(path: str | os.PathLike, records: Iterable[tuple[int, bytes]]) -> int:
    """Write a .tlog; returns the number of records written."""
    n = 0
    with open(path, "wb") as fh:
        for t, f in records:
            fh.write(tlog_record(t, f))
            n += 1
    return n
