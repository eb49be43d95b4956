"""Log files as sources: dataflash ``.bin`` and telemetry ``.tlog``, recognised by content, not name.

A synchronous :class:`LogReader` does the parsing (pymavlink) and hands out events in batches, time
ordered through a short reorder buffer; :class:`FileSource` runs it in a worker thread so the asyncio
loop never blocks. :func:`read_events` is the synchronous whole-file shortcut for tools and tests.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
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
                break
            for ev in evs:
                out += self._reorder.push(ev)
        return out

    def close(self) -> None:
        pass


class DataflashReader(LogReader):
    kind = "dataflash"

    def __init__(self, path: str | os.PathLike) -> None:
        super().__init__(path)
        from companion.mavlink.dataflash import PYMAVLINK_SAID, WANTED, DataflashDecoder, log_starts

        self._wanted = WANTED
        self._said = PYMAVLINK_SAID
        self._failed_before = {k: v for k, v in PYMAVLINK_SAID.items() if k.startswith("Failed")}
        # logs one after another in one file: each is read with its own formats, on one vehicle clock (the second's
        # time going back is a reboot, forward a gap)
        starts = log_starts(str(self.path))
        self._segments = [(a, b) for a, b in zip(starts, starts[1:] + [self.size_bytes])]
        self._base = 0
        if len(self._segments) > 1:
            self.info.warnings.append(f"{len(self._segments)} logs one after another (a new FMT block at byte "
                                      f"{', '.join(str(a) for a, _ in self._segments[1:])}): read in turn")
        self._open_segment(0)
        self._decoder = DataflashDecoder()

    def _open_segment(self, k: int) -> None:
        from companion.mavlink.dataflash import resync_reader

        start, end = self._segments[k]
        self._segment, self._base = k, start
        noise = io.StringIO()  # DFReader prints "bad header" lines on stderr; count them instead
        window = None if len(self._segments) == 1 else (start, end)
        try:
            with contextlib.redirect_stderr(noise), contextlib.redirect_stdout(noise):
                self._log = resync_reader(str(self.path), window)
        except Exception as err:  # pymavlink raises assorted errors on garbage
            raise SourceError(f"{self.path}: not a readable dataflash log ({err.__class__.__name__}: {err})") from None
        if not getattr(self._log, "formats", None) or len(self._log.formats) <= 1:
            raise SourceError(f"{self.path}: dataflash log without message formats (FMT); damaged or not a log")
        bad = noise.getvalue().count("bad header")
        skipped = getattr(self._log, "skipped_bytes", 0)
        if skipped:
            self.info.warnings.append(
                f"skipped {skipped} bytes in {self._log.skipped_stretches} stretches that are no dataflash records "
                f"(a bad record header or type); reading went on at the next record")
        elif bad:
            self.info.warnings.append(f"skipped {bad} corrupt bytes between records")
        if k == len(self._segments) - 1:
            self._check_tail()

    def _check_tail(self) -> None:
        """Say when the last record is cut short or an unparsable stretch ends the file."""
        log = self._log
        formats = log.formats
        last_start, last_end = 0, 0
        for mtype, offs in enumerate(getattr(log, "offsets", [])):
            if offs and mtype in formats and offs[-1] + self._base >= last_start:
                last_start, last_end = offs[-1] + self._base, offs[-1] + self._base + formats[mtype].len
        tail = self.size_bytes - last_end
        if 0 < tail <= 528 and last_end + 3 <= self.size_bytes:
            with open(self.path, "rb") as f:
                f.seek(last_end)
                head = f.read(3)
            fmt = formats.get(head[2]) if head[:2] == DATAFLASH_MAGIC else None
            if fmt is not None and fmt.len > tail:
                last_start, last_end = last_end, last_end + fmt.len
        elif 0 < tail < 3:
            last_start, last_end = last_end, last_end + 3
        if last_end > self.size_bytes:
            self.info.warnings.append(
                f"truncated: the last record (at byte {last_start}) needs {last_end - last_start} bytes but the "
                f"file ends after {self.size_bytes - last_start}"
            )
        elif self.size_bytes - last_end > 528:  # DFReader's own allowance for block-log padding
            self.info.warnings.append(
                f"the last {self.size_bytes - last_end} bytes (from byte {last_end}) are not dataflash records"
            )

    def offset(self) -> int:
        return self._base + int(getattr(self._log, "offset", 0))

    def _next_events(self) -> list[Event] | None:
        try:
            msg = self._log.recv_match(type=self._wanted)
        except Exception as err:  # noqa: BLE001 - pymavlink raises assorted errors on corrupt data
            self._parse_failed(err)
            return None
        if msg is None:
            if self._segment + 1 < len(self._segments):
                self._log.close()
                self._open_segment(self._segment + 1)
                return self._decoder.flush()  # a GPS row waiting for its GPA does not wait across logs
            return None
        self.messages_read += 1
        return self._decoder.decode(msg)

    def _final_events(self) -> list[Event]:
        evs = self._decoder.flush()
        failed = {k[len("Failed "):]: n - self._failed_before.get(k, 0) for k, n in self._said.items()
                  if k.startswith("Failed ") and n > self._failed_before.get(k, 0)}
        if failed:
            which = ", ".join(f"{n} {name}" for name, n in sorted(failed.items()))
            self.info.warnings.append(f"skipped records pymavlink could not parse ({which}): a format that does not "
                                      "fit its records (a damaged FMT?)")
        damage = ("without its time or axes", "malformed", "instance out of range")
        for why, n in sorted(self._decoder.dropped.items()):
            if any(d in why for d in damage):
                self.info.warnings.append(f"skipped {n} rows that do not fit their format: {why}")
        if self._decoder.firmware:
            self.info.details["firmware"] = self._decoder.firmware
        for why, n in sorted(self._decoder.dropped.items()):
            self.info.warnings.append(f"dropped {n} rows: {why}")
        return evs


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

    def progress(self) -> tuple[int, int] | None:
        return (self._reader.offset(), self._reader.size_bytes)

    async def _iterate(self) -> AsyncIterator[Event]:
        while True:
            batch = await asyncio.to_thread(self._reader.read_batch, self._batch_size)
            if not batch:
                break
            for ev in batch:
                self.events_out += 1
                yield ev
        if self.events_out == 0:
            raise SourceError(f"{self.info.location}: no usable messages (no IMU, GNSS, attitude or time messages found)")

    def __aiter__(self) -> AsyncIterator[Event]:
        return self._iterate()

    async def aclose(self) -> None:
        self._reader.close()
