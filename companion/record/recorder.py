"""MCAP recorder: every pipeline step on its own JSON topic, positions as Foxglove LocationFix.

Time: a message's log_time and publish_time are the vehicle time ``t_s`` of what it records, in integer
nanoseconds (``round(t_s * 1e9)``), plus the UTC offset once a :class:`~companion.record.clock.RecordClock`
knows it (UTC, Unix epoch ns: see that module); the payloads keep ``t_s``. A ``clock`` metadata record
says which clock the log times are on. Payloads are
the compact JSON of the dataclass's ``to_dict()`` with every unknown value (None, NaN) left out
(:func:`companion.record.schemas.drop_unknown`), encoded by orjson (the standard library's ``json`` for what orjson
refuses: integers beyond 64 bits), so the same input gives byte-identical payloads (and, with the same software
versions, a byte-identical file). orjson spells some floats differently from ``json`` (``1e-7`` for ``1e-07``); the
values are the same (tests/record/test_fast_messages.py).

Durability. A killed process (SIGKILL, OOM, power cut after the OS wrote its cache) loses only the chunk in progress:

* A chunk is closed with ``Writer.flush()`` (public API: finalises the chunk, writes it and its message
  indexes, flushes the stream) when ``flush_interval_s`` of *message* time has passed since its first
  message or when about ``chunk_size`` bytes of messages fill it, whichever comes first. The Writer's
  own size trigger is switched off (its chunk_size is set to "never"): that one writes a chunk without
  flushing the stream, and the recorder alone deciding chunk boundaries keeps every closed chunk on disk.
* The Writer gets an unbuffered file (:class:`_DirectFile`), so records written outside chunks (header,
  metadata) reach the OS at once too, not when the next chunk closes. A live process that is
  killed thus loses at most ~``flush_interval_s`` of data; :meth:`Recorder.flush` closes the chunk on
  demand (e.g. from a wall-clock timer in the live loop when messages stop arriving).
* ``close()`` writes the summary section and footer (``Writer.finish()``); it is idempotent and runs from
  ``finally`` / ``with`` blocks, so SIGTERM/SIGINT handled by cancelling the asyncio task finalise the file.
* A write error (full disk, read-only or removed drive) cuts the file back to its last whole record, so it
  reads to its end like a killed writer's, and stops the recording: by default with one line on stderr
  naming the file and nothing raised (the live companion navigates on), with ``raise_errors`` as one OSError
  naming it (a replay, whose product is the record).

:func:`companion.record.inspect.summarize` reads a finalised file through its summary section and a
killed one by streaming records up to the truncation point.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import orjson
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

import companion
from companion.events import Event
from companion.extras import DISTRIBUTION
from companion.logsetup import stderr_line
from companion.record.clock import RecordClock
from companion.record.fast_messages import fast_add_message
from companion.record.inspect import RecordError
from companion.record.payload import _ORJSON_OPTS, _dumps, _dumps_jsonable
from companion.record.schemas import (
    COV_DIAGONAL_KNOWN,
    COV_KNOWN,
    COV_UNKNOWN,
    JSON_MESSAGE_ENCODING,
    JSON_SCHEMA_ENCODING,
    LOCATION_FIX_SCHEMA,
    LOCATION_FIX_SCHEMA_NAME,
    LOG_SCHEMA,
    LOG_SCHEMA_NAME,
    _plain,
    dataclass_schema,
    schema_name,
)

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
_NEVER = 1 << 62  # Writer chunk_size that never triggers: the recorder decides chunk boundaries
_MESSAGE_OVERHEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, record length, channel, sequence, log/publish time


def _time_ns(t_s: Any) -> int:
    """Vehicle time in integer nanoseconds; raises ValueError for None/NaN/negative times."""
    try:
        t = round(t_s * 1e9)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"cannot record a message with time t_s={t_s!r}: need a finite number of seconds") from None
    if t < 0:
        raise ValueError(f"cannot record a message with negative time t_s={t_s!r} (MCAP times are unsigned)")
    return t


class _DirectFile:
    """Write-only file whose writes go straight to the OS (no Python-level buffer).

    Not an ``io.RawIOBase`` on purpose: the mcap Writer would wrap one in a BufferedWriter again.
    """

    def __init__(self, path: Path):
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._pos = 0  # bytes written in full

    def write(self, data) -> int:
        n = len(data)
        view = memoryview(data)
        while view:
            view = view[os.write(self._fd, view):]
        self._pos += n
        return n

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:  # nothing is buffered here
        pass

    def fsync(self) -> None:
        os.fsync(self._fd)

    def cut(self, pos: int) -> None:
        """Best effort: drop what a failed write left after ``pos`` (a half-written chunk), freeing its space."""
        try:
            os.ftruncate(self._fd, pos)
        except OSError:
            pass

    def close(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)


class _Nowhere:
    """Where the Writer writes when the file could not even be created (the recorder has stopped): nothing."""

    def write(self, data) -> int:
        return len(data)

    def tell(self) -> int:
        return 0

    def flush(self) -> None:
        pass


class Recorder:
    """Writes an MCAP file: one JSON topic per recorded type, LocationFix topics for the Map panel.

    :param path: output file (created or truncated).
    :param chunk_size: close a chunk when its messages reach about this many bytes (uncompressed).
    :param flush_interval_s: close a chunk when this much *message* time has passed since its first message.
    :param compression: "zstd" (default; ``zstandard`` is a dependency of ``mcap``), "lz4" or "none".
    :param fsync: also ``os.fsync`` whenever a chunk closes (survives power loss, costs SD-card writes).
    :param clock: log times in UTC once known (:class:`~companion.record.clock.RecordClock`); None: boot time.
    :param live_view: also publish every message (same topic, schema, bytes and log time) to this
        :class:`~companion.record.live_view.LiveView` (Foxglove WebSocket server).
    :param raise_errors: a write error (full disk, removed drive) raises OSError naming the file, once (a replay,
        whose product is the record). By default (the live companion) it stops the recording instead: one line on
        stderr naming the file, every later message dropped and counted, nothing raised -- also when the file
        cannot even be created, so navigation and injection go on whatever the disk does.
    :param announce_errors: False: not even that line (a caller that retries says it itself).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        chunk_size: int = 512 * 1024,
        flush_interval_s: float = 1.0,
        compression: str = "zstd",
        fsync: bool = False,
        clock: RecordClock | None = None,
        live_view: Any = None,
        raise_errors: bool = False,
        announce_errors: bool = True,
    ):
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, not {compression!r}")
        if chunk_size <= 0 or not flush_interval_s > 0:
            raise ValueError("chunk_size and flush_interval_s must be positive")
        self.path = Path(path)
        self._raise = raise_errors
        self.announce_errors = announce_errors
        self.chunks_written = 0  # chunks with messages that reached the file whole
        self._closed = True  # until the file is open, close() has nothing to do
        #: the OS error that stopped recording (a full disk, a removed drive): the recorder then drops every
        #: later message (counted in ``dropped_after_error``) and never raises again, so a write error does not stop
        #: what it records (navigation, injection); it says so once, on stderr, naming the file
        self.write_error: OSError | None = None
        self.dropped_after_error = 0
        try:
            self._file: _DirectFile | None = _DirectFile(self.path)
        except OSError as err:
            self._file = None
            self._failed(err)
        self._writer = Writer(self._file if self._file is not None else _Nowhere(),
                              chunk_size=_NEVER, compression=_COMPRESSION[compression])
        # the Writer's add_message in one pack and two writes (None: an mcap whose internals differ; its own then)
        self._add_message = fast_add_message(self._writer) or self._writer.add_message
        self._chunk_size = int(chunk_size)
        self._interval_ns = max(1, round(flush_interval_s * 1e9))
        self._fsync = fsync
        self.clock = clock
        self.live_view = live_view  # companion.record.live_view.LiveView: gets every message written
        self._chunk_bytes = 0
        self._chunk_t0: int | None = None  # log time of the open chunk's first message
        self._busy = False
        self._close_requested = False
        # (class, topic) -> (channel id, True when the dataclass is encoded as it is (no own to_dict), to_dict)
        self._dc_channels: dict[tuple[type, str | None], tuple[int, Any, Any]] = {}
        self._named_channels: dict[str, int] = {}
        self._schemas: dict[str, tuple[int, bytes]] = {}  # schema name -> (id, schema bytes)
        self._channel_topic: dict[int, str] = {}
        self._channel_schema: dict[int, str] = {}
        self._topic_channel: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._closed = False
        version_ = _companion_version()
        try:
            self._io(self._writer.start, "", f"companion/{version_}; {LIBRARY_IDENTIFIER}")
            self.add_metadata("companion", {"version": version_, "mcap": _dist_version("mcap")})
        except BaseException:  # raise_errors: no recorder to close later
            self._closed = True
            if self._file is not None:
                self._file.close()
            raise

    # ------------------------------------------------------------------ writing

    def write(self, item: Any, topic: str | None = None) -> None:
        """Record a frozen dataclass (an event, a predictor output, filter state, ...).

        ``topic`` defaults to the class's ``topic`` attribute; the log time is ``item.t_s``.
        """
        if self.write_error is not None and self.live_view is None:  # recording stopped: not even encoded
            self.dropped_after_error += 1
            return
        entry = self._dc_channels.get((type(item), topic))
        if entry is None:
            entry = self._register_dataclass(type(item), topic)
        channel_id, fast, to_json = entry
        t_ns = _time_ns(item.t_s)
        if self.clock is not None:
            self.clock.observe(item)
        if fast:
            # the dataclass straight to orjson: its fields in order, the same values as to_dict() (tuples -> arrays,
            # IntEnum -> int). An unknown value to leave out ("null": NaN/inf/None, or "null" inside a string) or a
            # value orjson refuses -> the to_dict() path.
            try:
                data = orjson.dumps(item, option=_ORJSON_OPTS)
            except TypeError:
                data = None
            if data is None or b"null" in data:
                data = _dumps_jsonable(to_json(item))
        else:
            data = _dumps_jsonable(to_json(item))
        self._add(channel_id, t_ns, data)

    def write_dict(self, topic: str, schema_name: str, json_schema: Mapping, payload: Mapping, t_s: float) -> None:
        """Record a plain dict on ``topic`` under an explicitly given JSON schema (registered once per topic)."""
        if self.write_error is not None and self.live_view is None:
            self.dropped_after_error += 1
            return
        channel_id = self._named_channels.get(topic)
        if channel_id is None or self._channel_schema[channel_id] != schema_name:
            channel_id = self._register_named(topic, schema_name, json_schema)
        self._add(channel_id, _time_ns(t_s), _dumps(payload))

    def write_location(
        self,
        topic: str,
        t_s: float,
        lat_deg: float,
        lon_deg: float,
        alt_m: float,
        cov_enu_m2: Any = None,
        frame_id: str | None = None,
        *,
        cov_type: int | None = None,
        color_rgba: Sequence[float] | None = None,
        heading_rad: float | None = None,
    ) -> None:
        """Record a position as ``foxglove.LocationFix`` (one topic per track, e.g. "/map/fused").

        ``cov_enu_m2`` is the 3x3 position covariance in m^2 in the local East-North-Up frame (as in ROS
        NavSatFix; note: ENU, not the NED used elsewhere in companion), nested rows or 9 numbers
        row-major, or None when unknown. ``cov_type`` defaults to DIAGONAL_KNOWN (2) for a diagonal
        matrix, KNOWN (3) otherwise, UNKNOWN (0) for None. ``color_rgba`` (0..1) sets the track colour;
        ``heading_rad`` is clockwise from north. Non-finite lat/lon/alt raise ValueError. ``timestamp`` is the
        message's log time (UTC once the clock knows it); ``frame_id`` defaults to the topic's last part ("fused" for
        "/map/fused"), so every track has its own.
        """
        if self.write_error is not None and self.live_view is None:
            self.dropped_after_error += 1
            return
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and math.isfinite(alt_m)):
            raise ValueError(f"{topic}: non-finite position lat={lat_deg} lon={lon_deg} alt={alt_m}")
        t_ns = _time_ns(t_s)
        log_ns = self._log_ns(t_ns)
        if cov_enu_m2 is None:
            cov = [0.0] * 9
            ctype = COV_UNKNOWN
        else:
            cov = _flatten_cov(cov_enu_m2)
            ctype = COV_DIAGONAL_KNOWN if all(cov[i] == 0.0 for i in (1, 2, 3, 5, 6, 7)) else COV_KNOWN
        if cov_type is not None:
            if cov_type not in (0, 1, 2, 3):
                raise ValueError(f"cov_type must be 0..3, not {cov_type!r}")
            ctype = int(cov_type)
        msg: dict[str, Any] = {
            "timestamp": _stamp(log_ns),
            "frame_id": frame_id if frame_id is not None else topic.rpartition("/")[2],
            "latitude": float(lat_deg),
            "longitude": float(lon_deg),
            "altitude": float(alt_m),
            "position_covariance": cov,
            "position_covariance_type": ctype,
        }
        if heading_rad is not None and math.isfinite(heading_rad):
            msg["heading"] = float(heading_rad)
        if color_rgba is not None:
            r, g, b, a = (float(c) for c in color_rgba)
            msg["color"] = {"r": r, "g": g, "b": b, "a": a}
        channel_id = self._named_channels.get(topic)
        if channel_id is None or self._channel_schema[channel_id] != LOCATION_FIX_SCHEMA_NAME:
            channel_id = self._register_named(topic, LOCATION_FIX_SCHEMA_NAME, LOCATION_FIX_SCHEMA)
        self._add(channel_id, t_ns, _dumps(msg), log_ns)

    def write_log(self, topic: str, t_s: float, level: int, message: str, name: str = "") -> None:
        """Record a text message as ``foxglove.Log`` (what Foxglove's Log panel shows); ``level`` is a foxglove.LogLevel
        (companion.record.schemas.LOG_*), ``timestamp`` the message's log time."""
        if self.write_error is not None and self.live_view is None:
            self.dropped_after_error += 1
            return
        t_ns = _time_ns(t_s)
        log_ns = self._log_ns(t_ns)
        msg = {"timestamp": _stamp(log_ns), "level": int(level), "message": str(message), "name": name, "file": "",
               "line": 0}
        channel_id = self._named_channels.get(topic)
        if channel_id is None or self._channel_schema[channel_id] != LOG_SCHEMA_NAME:
            channel_id = self._register_named(topic, LOG_SCHEMA_NAME, LOG_SCHEMA)
        self._add(channel_id, t_ns, _dumps(msg), log_ns)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Add a metadata record (source, configuration, ...). Keys and values must be str."""
        if self.write_error is not None:
            return
        self._check_open()
        bad = [(k, v) for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise TypeError(f"metadata {name!r}: keys and values must be str, got {bad[:3]!r}")
        self._io(self._writer.add_metadata, name, dict(data))

    def flush(self) -> None:
        """Close the chunk in progress now, so everything written so far is in the file.

        For a live link, call it from a wall-clock timer (e.g. every second) so a quiet link still has its
        last messages on disk; the timer only decides when to flush, no wall time enters the record.
        A no-op once the recorder is closed.
        """
        if self._closed or self._busy or self.write_error is not None:
            return
        self._close_chunk()

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far per topic."""
        return {self._channel_topic[c]: n for c, n in self._seq.items()}

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def size_bytes(self) -> int:
        """Bytes in the file so far plus those of the chunk in progress (uncompressed): what it will take at least."""
        return (self._file.tell() if self._file is not None else 0) + self._chunk_bytes

    # ------------------------------------------------------------------ finishing

    def close(self) -> None:
        """Finalise the file (summary section, footer); safe to call more than once.

        Called while a write is in progress (a signal handler interrupting ``write``), it is deferred
        until that write has finished so the chunk in progress is not corrupted.
        """
        if self._closed:
            return
        if self._busy:
            self._close_requested = True
            return
        try:
            if self.write_error is None:
                self.add_metadata("clock", self.clock.metadata() if self.clock is not None else RecordClock().metadata())
            if self.write_error is None and self._io(self._writer.finish) and self._fsync:
                self._io(self._file.fsync)
        finally:
            self._closed = True
            if self._file is not None:
                self._file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ internals

    def _check_open(self) -> None:
        if self._closed:
            raise RecordError(f"{self.path}: the recorder is closed")

    def _io(self, op, *args) -> bool:
        """Run one writer operation that writes to the file; on an OS error cut off what it half wrote (so the file
        ends at a whole record and reads back to its end) and stop recording. False when it failed."""
        if self.write_error is not None or self._file is None:
            return False
        mark = self._file.tell()
        try:
            op(*args)
            return True
        except OSError as err:
            self._file.cut(mark)
            self._failed(err)
            return False

    def _failed(self, err: OSError) -> None:
        """A write failed: recording stops here (one message naming the file); nothing else is affected."""
        if self.write_error is not None:
            return
        why = err.strerror or err.__class__.__name__
        self.write_error = OSError(err.errno, why, str(self.path))
        if self._raise:
            raise self.write_error from err
        if self.announce_errors:
            stderr_line(f"companion: error: recording stopped, cannot write {self.path}: {why} "
                        f"(navigation and injection go on; {self.path} is not finalised)")

    def _log_ns(self, t_ns: int) -> int:
        return self.clock.log_ns(t_ns) if self.clock is not None else t_ns

    def _add(self, channel_id: int, t_ns: int, data: bytes, log_ns: int | None = None) -> None:
        """Write one message at vehicle time ``t_ns``; ``log_ns``: its log time when the caller already took it from
        the clock (a payload that carries it), else taken here."""
        if self.write_error is not None:  # the live view (Foxglove) goes on without the file
            self.dropped_after_error += 1
            if self.live_view is not None and not self._closed:
                self._publish(channel_id, self._log_ns(t_ns) if log_ns is None else log_ns, data)
            return
        if self._closed:
            raise RecordError(f"{self.path}: the recorder is closed")
        self._busy = True
        try:
            seq = self._seq[channel_id]
            self._seq[channel_id] = seq + 1
            if log_ns is not None:
                t_ns = log_ns
            elif self.clock is not None:
                t_ns = self.clock.log_ns(t_ns)
            self._add_message(channel_id, t_ns, data, t_ns, seq & 0xFFFFFFFF)
            if self.live_view is not None:
                self._publish(channel_id, t_ns, data)
            self._chunk_bytes += _MESSAGE_OVERHEAD + len(data)
            t0 = self._chunk_t0
            if t0 is None:
                self._chunk_t0 = t0 = t_ns
            if self._chunk_bytes >= self._chunk_size or abs(t_ns - t0) >= self._interval_ns:
                self._close_chunk()
        finally:
            self._busy = False
        if self._close_requested:
            self.close()

    def _publish(self, channel_id: int, t_ns: int, data: bytes) -> None:
        name = self._channel_schema[channel_id]
        self.live_view.publish(self._channel_topic[channel_id], name, self._schemas[name][1], t_ns, data)

    def _close_chunk(self) -> None:
        # finalises the chunk (if it has messages) and writes it and its indexes
        had = self._chunk_t0 is not None
        if self._io(self._writer.flush) and self._fsync:
            self._io(self._file.fsync)
        if had and self.write_error is None:
            self.chunks_written += 1
        self._chunk_bytes = 0
        self._chunk_t0 = None

    def _register_schema(self, name: str, schema: Mapping) -> int:
        data = json.dumps(schema, separators=(",", ":"), sort_keys=False).encode()
        known = self._schemas.get(name)
        if known is not None:
            if known[1] != data:
                raise ValueError(f"schema {name!r} is already registered with a different definition")
            return known[0]
        schema_id = self._writer.register_schema(name, JSON_SCHEMA_ENCODING, data)
        self._schemas[name] = (schema_id, data)
        self._chunk_bytes += len(data) + len(name) + 32
        return schema_id

    def _register_channel(self, topic: str, schema_name_: str, schema_id: int) -> int:
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"topic must be a non-empty string, not {topic!r}")
        existing = self._topic_channel.get(topic)
        if existing is not None:
            raise ValueError(
                f"topic {topic!r} already carries {self._channel_schema[existing]!r}; "
                f"cannot also record {schema_name_!r} on it"
            )
        channel_id = self._writer.register_channel(topic, JSON_MESSAGE_ENCODING, schema_id)
        self._chunk_bytes += len(topic) + 32
        self._channel_topic[channel_id] = topic
        self._channel_schema[channel_id] = schema_name_
        self._topic_channel[topic] = channel_id
        self._seq[channel_id] = 0
        return channel_id

    def _register_dataclass(self, cls: type, topic: str | None) -> tuple[int, Any, Any]:
        self._check_open()
        schema = dataclass_schema(cls)  # raises TypeError for non-dataclasses
        if "t_s" not in schema["properties"]:
            raise TypeError(f"{cls.__qualname__} has no t_s field: cannot give its messages a log time")
        resolved = topic if topic is not None else getattr(cls, "topic", None)
        if not isinstance(resolved, str):
            raise ValueError(f"{cls.__qualname__} has no `topic` class attribute: pass topic=...")
        name = schema_name(cls)
        existing = self._topic_channel.get(resolved)
        if existing is not None and self._channel_schema[existing] == name:
            channel_id = existing  # same class reached with topic=None and with its explicit topic
        else:
            channel_id = self._register_channel(resolved, name, self._register_schema(name, schema))
        to_dict = getattr(cls, "to_dict", None)
        fast = to_dict is None or to_dict is Event.to_dict  # a class's own to_dict() is always honoured
        entry = (channel_id, fast, to_dict if callable(to_dict) else _plain)
        self._dc_channels[(cls, topic)] = entry
        return entry

    def _register_named(self, topic: str, name: str, json_schema: Mapping) -> int:
        self._check_open()
        if not isinstance(json_schema, Mapping):
            raise TypeError(f"json_schema for {topic!r} must be a dict, not {type(json_schema).__name__}")
        channel_id = self._register_channel(topic, name, self._register_schema(name, json_schema))
        self._named_channels[topic] = channel_id
        return channel_id


def _stamp(log_ns: int) -> dict[str, int]:
    """Foxglove's time (``sec``, ``nsec``) of a log time in ns."""
    return {"sec": log_ns // 1_000_000_000, "nsec": log_ns % 1_000_000_000}


def _flatten_cov(cov: Any) -> list[float]:
    if type(cov) is list and len(cov) == 3 and all(type(r) is list and len(r) == 3 for r in cov):
        flat = [float(x) for r in cov for x in r]  # the pipeline's nested lists: the common case
        if math.isfinite(sum(flat)):  # a finite sum: every entry finite (else the check below says which way not)
            return flat
    rows = cov.tolist() if hasattr(cov, "tolist") else cov
    flat = []
    for r in rows:
        if isinstance(r, (list, tuple)):
            flat.extend(float(x) for x in r)
        else:
            flat.append(float(r))
    if len(flat) != 9:
        raise ValueError(f"cov_enu_m2 must be 3x3 (or 9 numbers), got {len(flat)} numbers")
    if not all(math.isfinite(x) for x in flat):
        raise ValueError("cov_enu_m2 has non-finite entries")
    return flat


def _companion_version() -> str:
    # companion.__version__; the distribution's version if the package was imported as a bare namespace
    # (a stale editable install run from outside the checkout does that).
    return getattr(companion, "__version__", None) or _dist_version(DISTRIBUTION)


def _dist_version(dist: str) -> str:
    try:
        return version(dist)
    except PackageNotFoundError:
        return "unknown"
