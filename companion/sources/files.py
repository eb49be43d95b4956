"""Log files as sources: dataflash ``.bin`` and telemetry ``.tlog``, recognised by content, not name.

A synchronous :class:`LogReader` does the parsing (dataflash: companion.mavlink.dataflash_stream; tlog: pymavlink)
and hands out events in batches, time
ordered through a short reorder buffer; :class:`FileSource` runs it in a worker thread so the asyncio
loop never blocks. :func:`read_events` is the synchronous whole-file shortcut for tools and tests.
"""

from __future__ import annotations

import asyncio
import os
import threading
import struct
from collections.abc import AsyncIterator
from pathlib import Path

from companion.events import Event
from companion.sources.base import Source, SourceError, SourceInfo
from companion.nav.reorder import ReorderBuffer

DATAFLASH_MAGIC = b"\xa3\x95"
MAVLINK_STX = (0xFE, 0xFD)
#: Events of different types within this window are put in time order.
REORDER_HORIZON_S = 0.5
#: A tlog record timestamp must be a plausible Unix time in µs (1995..2100).
_TLOG_TS_RANGE = (788918400_000000, 4102444800_000000)


def detect_format(path: str | os.PathLike) -> str:
    """'dataflash' or 'tlog' from the file's first bytes; SourceError with the reason otherwise."""
    p = Path(path)
    if not p.exists():
        raise SourceError(f"{p}: no such file")
    if p.is_dir():
        raise SourceError(f"{p}: is a directory, not a log file")
    try:
        with open(p, "rb") as f:
            head = f.read(64)
    except OSError as err:
        raise SourceError(f"{p}: cannot read ({err.strerror})") from None
    if not head:
        raise SourceError(f"{p}: the file is empty")
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    if len(head) >= 9 and head[8] in MAVLINK_STX:
        (ts,) = struct.unpack(">Q", head[:8])
        if _TLOG_TS_RANGE[0] <= ts <= _TLOG_TS_RANGE[1]:
            return "tlog"
    if head.lstrip()[:4] in (b"FMT,", b"FMT ") or b"FMT, " in head:
        raise SourceError(f"{p}: text dataflash logs (.log) are not supported; use the binary .bin log")
    kind = "a text file" if _looks_text(head) else "unrecognised binary data"
    raise SourceError(
        f"{p}: not an ArduPilot log — it holds {kind}, neither a dataflash .bin "
        f"(starts with A3 95) nor a telemetry .tlog (8-byte time stamp + MAVLink frame)"
    )


def _looks_text(head: bytes) -> bool:
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


class LogReader:
    """Base of the synchronous readers: ``read_batch(n)`` returns up to n events, [] at the end."""

    kind = "log"

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.size_bytes = self.path.stat().st_size
        self.info = SourceInfo(kind=self.kind, location=str(self.path))
        self._reorder = ReorderBuffer(REORDER_HORIZON_S)
        self._done = False
        self.messages_read = 0

    # subclasses: yield raw events in file order until exhausted; may raise SourceError
    def _next_events(self) -> list[Event] | None:
        raise NotImplementedError

    def _final_events(self) -> list[Event]:
        return []

    def offset(self) -> int:
        return 0

    def _read_message(self, read):
        """One message from the log's parser, or None at the end or when the parser fails on corrupt data."""
        try:
            msg = read()
        except Exception as err:  # noqa: BLE001 - pymavlink raises assorted errors on corrupt data
            self._parse_failed(err)
            return None
        if msg is not None:
            self.messages_read += 1
        return msg

    def _parse_failed(self, err: Exception) -> None:
        """pymavlink choked on a corrupt or truncated stretch: keep what was read, say where."""
        self.info.warnings.append(
            f"stopped reading at byte {self.offset()} of {self.size_bytes}: "
            f"{err.__class__.__name__}: {err} (file damaged or truncated?)"
        )

    def read_batch(self, n: int = 2000) -> list[Event]:
        out: list[Event] = []
        while len(out) < n and not self._done:
            evs = self._next_events()
            if evs is None:
                self._done = True
                for ev in self._final_events():
                    out += self._reorder.push(ev)
                out += self._reorder.flush()
                if self._reorder.duplicates:
                    self.info.warnings.append(f"dropped {self._reorder.duplicates} events: the same record repeated "
                                              "(same time, same values)")
                break
            for ev in evs:
                out += self._reorder.push(ev)
        return out

    def close(self) -> None:
        pass


class DataflashReader(LogReader):
    """A dataflash log read as a stream (companion.mavlink.dataflash_stream): memory bounded whatever its length."""

    kind = "dataflash"

    def __init__(self, path: str | os.PathLike) -> None:
        super().__init__(path)
        from companion.mavlink.dataflash import WANTED, DataflashDecoder
        from companion.mavlink.dataflash_stream import DataflashStream

        try:
            self._stream = DataflashStream(self.path, WANTED)
        except OSError as err:
            raise SourceError(f"{self.path}: cannot read ({err.strerror})") from None
        self._decoder = DataflashDecoder()
        self._pending: list[Event] = []
        try:  # the formats come first: read on until one is defined (a file without any is no log)
            while not self._stream.has_formats and not self._stream.done:
                self._pending += self._decoder.decode_block(self._stream.next_block())
        except OSError as err:
            self._stream.close()
            raise SourceError(f"{self.path}: cannot read ({err.strerror})") from None
        if not self._stream.has_formats:
            self._stream.close()
            raise SourceError(f"{self.path}: dataflash log without message formats (FMT); damaged or not a log")

    def offset(self) -> int:
        return self._stream.offset

    def _next_events(self) -> list[Event] | None:
        if self._pending:
            out, self._pending = self._pending, []
            return out
        try:
            block = self._stream.next_block()
        except Exception as err:  # noqa: BLE001 - an I/O error mid-file: keep what was read, say where
            self._parse_failed(err)
            return None
        if block is None:
            return None
        self.messages_read += len(block.order)
        return self._decoder.decode_block(block)

    def _final_events(self) -> list[Event]:
        evs = self._decoder.flush()
        st, warn = self._stream, self.info.warnings
        if len(st.segment_starts) > 1:
            warn.insert(0, f"{len(st.segment_starts)} logs one after another (a new FMT block at byte "
                           f"{', '.join(str(a) for a in st.segment_starts[1:])}): read in turn")
        if st.skipped_bytes:
            warn.append(f"skipped {st.skipped_bytes} bytes in {st.skipped_stretches} stretches that are no dataflash "
                        "records (a bad record header or type); reading went on at the next record")
        if st.unfit:
            which = ", ".join(f"{n} {name}" for name, n in sorted(st.unfit.items()))
            warn.append(f"skipped records that could not be parsed ({which}): a format that does not fit its records "
                        "(a damaged FMT?)")
        if st.truncated is not None:
            at, length = st.truncated
            warn.append(f"truncated: the last record (at byte {at}) needs {length} bytes but the file ends after "
                        f"{self.size_bytes - at}")
        if st.trailing_garbage is not None:
            at, n = st.trailing_garbage
            warn.append(f"the last {n} bytes (from byte {at}) are not dataflash records")
        damage = ("without its time or axes", "malformed", "instance out of range")
        for why, n in sorted(self._decoder.dropped.items()):
            if any(d in why for d in damage):
                warn.append(f"skipped {n} rows that do not fit their format: {why}")
        if self._decoder.firmware:
            self.info.details["firmware"] = self._decoder.firmware
        for why, n in sorted(self._decoder.dropped.items()):
            warn.append(f"dropped {n} rows: {why}")
        return evs

    def close(self) -> None:
        self._stream.close()


class TlogReader(LogReader):
    kind = "tlog"

    def __init__(self, path: str | os.PathLike) -> None:
        super().__init__(path)
        from pymavlink import mavutil

        from companion.mavlink.decode import WANTED_TYPES, MavlinkDecoder

        try:
            self._log = mavutil.mavlogfile(str(self.path), notimestamps=False)
        except Exception as err:
            raise SourceError(f"{self.path}: not a readable telemetry log ({err.__class__.__name__}: {err})") from None
        self._wanted = set(WANTED_TYPES)
        self._decoder = MavlinkDecoder()
        self._msg_end = 0  # file offset just after the last frame the parser returned

    def offset(self) -> int:
        try:
            return self._log.f.tell()
        except (OSError, ValueError):
            return self.size_bytes

    def _next_events(self) -> list[Event] | None:
        while True:
            msg = self._read_message(self._log.recv_msg)
            if msg is None:
                return None
            self._msg_end = self.offset()
            mtype = msg.get_type()
            if mtype in self._wanted or mtype == "BAD_DATA":
                return self._decoder.decode(msg, msg._timestamp)

    def _final_events(self) -> list[Event]:
        try:
            pending = int(self._log.mav.buf_len())  # bytes of a frame the parser was still waiting for the rest of
        except (AttributeError, TypeError, ValueError):
            pending = 0
        if pending:
            self.info.warnings.append(
                f"truncated: the file ends {pending} bytes into a MAVLink frame (at byte {self.size_bytes - pending})")
        elif 0 < self.size_bytes - self._msg_end and self.offset() >= self.size_bytes:
            # pymavlink reads a record's 8-byte time stamp and stops quietly when fewer are left (or no frame follows)
            self.info.warnings.append(f"truncated: the file ends {self.size_bytes - self._msg_end} bytes into a record "
                                      f"(its time stamp, at byte {self._msg_end})")
        bad = self._decoder.dropped.get("bad frame", 0)
        if bad:
            self.info.warnings.append(f"skipped {bad} corrupt frames (bad CRC or garbage between frames)")
        for why, n in sorted(self._decoder.dropped.items()):
            self.info.warnings.append(f"dropped {n} messages: {why}")
        if self._decoder.target_system is not None:
            self.info.details["autopilot"] = f"system {self._decoder.target_system} component {self._decoder.target_component}"
        return []

    def close(self) -> None:
        try:
            self._log.close()
        except Exception:  # noqa: BLE001 - closing a half-broken log must not mask the real error
            pass


def open_reader(path: str | os.PathLike) -> LogReader:
    kind = detect_format(path)
    return DataflashReader(path) if kind == "dataflash" else TlogReader(path)


def read_events(path: str | os.PathLike) -> list[Event]:
    """Every event of a log file, time ordered, on the vehicle clock (synchronous)."""
    reader = open_reader(path)
    try:
        events: list[Event] = []
        while True:
            batch = reader.read_batch(5000)
            if not batch:
                break
            events += batch
    finally:
        reader.close()
    if not events:
        raise SourceError(f"{path}: no usable messages (no IMU, GNSS, attitude or time messages found)")
    return events


class FileSource(Source):
    """A log file as an async iterator; parsing runs in a worker thread, in batches."""

    def __init__(self, path: str | os.PathLike, batch_size: int = 2000) -> None:
        self._reader = open_reader(path)
        self.info = self._reader.info
        self._batch_size = batch_size
        self.events_out = 0
        self._reading = threading.Lock()  # held by the worker thread while it reads a batch
        self._closed = False

    def progress(self) -> tuple[int, int] | None:
        return (self._reader.offset(), self._reader.size_bytes)

    async def _iterate(self) -> AsyncIterator[Event]:
        while True:
            batch = await asyncio.to_thread(self._read_batch)
            if not batch:
                break
            for ev in batch:
                self.events_out += 1
                yield ev
        if self.events_out == 0:
            raise SourceError(f"{self.info.location}: no usable messages (no IMU, GNSS, attitude or time messages found)")

    def __aiter__(self) -> AsyncIterator[Event]:
        return self._iterate()

    def _read_batch(self) -> list[Event]:
        with self._reading:
            return [] if self._closed else self._reader.read_batch(self._batch_size)

    async def aclose(self) -> None:
        """Close once the batch being read (a stop cancels the wait for it, not the thread) is done."""
        await asyncio.to_thread(self._close)

    def _close(self) -> None:
        with self._reading:
            self._closed = True
            self._reader.close()
