"""Every message of a log into MCAP (``companion convert``): what Foxglove cannot open (.bin, .tlog) as it can.

Unlike a replay, which records the pipeline's events, this writes each message of the log as it is, one JSON topic
per message type with a JSON schema made from the log's own definition:

* dataflash ``.bin``: topic ``/dataflash/NAME`` (FMT records too: ``/dataflash/FMT``), the schema from the type's FMT
  record (format characters -> integer, number, string or an array of integers), the values DFReader gives
  (companion.mavlink.dataflash_stream: the scaled types divided out, strings cut at their NUL). Log time: the row's
  boot time (``TimeUS``; ``TimeMS``; AC 3.x GPS rows ``T``) on the replay's vehicle clock (continued through reboots),
  in UTC once the log gives GPS time, as a replay's record; a row without one takes the time of the row before it.
* telemetry ``.tlog``: topic ``/mavlink/NAME``, the schema from the dialect's message definition (char arrays ->
  string, other arrays -> arrays), plus ``_sysid`` and ``_compid`` (the sender: Foxglove filters on them, e.g.
  ``/mavlink/HEARTBEAT{_sysid==1}.custom_mode``). Log time: the tlog's own time stamp (UTC).

Unknown values (NaN) are left out of the payload like everywhere in the record, so a float field is not ``required``.
The same speed and memory rules as replay: the .bin is read as a stream (its blocks decoded with numpy), the .tlog
message by message, and the MCAP is written in chunks, so memory does not grow with the log's length.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion.record.recorder import Recorder
from companion.sources.base import SourceError
from companion.sources.files import detect_format

DATAFLASH_PREFIX = "/dataflash/"
MAVLINK_PREFIX = "/mavlink/"
#: dataflash format characters -> JSON schema of the value (pymavlink's DFReader.FORMAT_TO_STRUCT)
_DF_JSON = {
    **dict.fromkeys("bBhHiIMqQ", {"type": "integer"}),
    **dict.fromkeys("fdgcCeEL", {"type": "number"}),
    **dict.fromkeys("nNZ", {"type": "string"}),
    "a": {"type": "array", "items": {"type": "integer"}, "minItems": 32, "maxItems": 32},
}
_MAV_INTEGER = {"int8_t", "uint8_t", "int16_t", "uint16_t", "int32_t", "uint32_t", "int64_t", "uint64_t",
                "uint8_t_mavlink_version"}


class Conversion:
    """What one conversion did: messages per type, what could not be read, and what stopped it."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.counts: Counter[str] = Counter()
        self.warnings: list[str] = []
        self.damaged = False
        self.stopped_by: str | None = None

    @property
    def messages(self) -> int:
        return sum(self.counts.values())


class _Stopped(Exception):
    pass


def convert_log(log: str | os.PathLike, out: str | os.PathLike, *, on_progress: Callable[[int, int], None] | None = None,
                stop_requested: Callable[[], str | None] = lambda: None, flush_interval_s: float = 10.0) -> Conversion:
    """Write every message of ``log`` (dataflash or tlog, recognised by content) to the MCAP file ``out``.

    ``on_progress(bytes read, file size)`` is called once per block (dataflash) or every 4096 messages (tlog).
    ``stop_requested()`` is asked between messages: a reason (e.g. a signal's name) stops the conversion there, the
    record finalised with what was read and ``stopped_by`` saying so. SourceError when the file is no log.
    """
    kind = detect_format(log)
    conv = Conversion(kind)
    clock = None
    if kind == "dataflash":
        from companion.record.clock import RecordClock

        utc = _dataflash_utc_offset(Path(log))
        clock = RecordClock(*utc) if utc else RecordClock()
    rec = Recorder(out, clock=clock, raise_errors=True, flush_interval_s=flush_interval_s)
    try:
        try:
            (_dataflash if kind == "dataflash" else _tlog)(Path(log), rec, conv, on_progress, stop_requested)
        except _Stopped as why:
            conv.stopped_by = str(why)
        meta = {"kind": kind, "location": str(log), "messages": str(conv.messages)}
        meta.update({f"count.{name}": str(n) for name, n in sorted(conv.counts.items())})
        meta.update({f"warning.{i}": w for i, w in enumerate(conv.warnings)})
        meta["stopped_by"] = conv.stopped_by or "end of input"
        rec.add_metadata("source", meta)
    finally:
        rec.close()
    return conv


# ------------------------------------------------------------------------------------------------ dataflash

def dataflash_schema(fmt) -> dict:
    """JSON schema of a dataflash format (companion.mavlink.dataflash_stream.Format)."""
    props = {col: dict(_DF_JSON[ch]) for col, ch in zip(fmt.columns, fmt.chars)}
    required = [col for col, ch in zip(fmt.columns, fmt.chars) if _DF_JSON[ch]["type"] != "number"]
    return {"title": f"ardupilot.dataflash.{fmt.name}", "type": "object", "properties": props, "required": required,
            "description": f"dataflash {fmt.name} (format {fmt.format})"}


def _dataflash_utc_offset(log: Path) -> tuple[int, str] | None:
    """The replay's look-ahead (companion.record.clock.find_utc_offset) on the GPS rows alone, decoded as the replay
    decodes them: the same UTC offset, without reading the log's other records twice."""
    from companion.mavlink.dataflash import DataflashDecoder
    from companion.mavlink.dataflash_stream import DataflashStream
    from companion.record.clock import _unix_ns, utc_of

    stream = DataflashStream(log, ["GPS", "GPS2", "GPA", "GPA2"])
    decoder = DataflashDecoder()
    try:
        while (block := stream.next_block()) is not None:
            for ev in decoder.decode_block(block) + (decoder.flush() if stream.done else []):
                got = utc_of(ev)
                if got is not None:
                    return _unix_ns(got[0]) - round(ev.t_s * 1e9), got[1]
    except OSError:
        return None  # the conversion itself says what is wrong with the file
    finally:
        stream.close()
    return None


def _boot_time_column(fmt) -> tuple[int, float] | None:
    """(column index, seconds per unit) of a format's boot time: TimeUS, AC 3.x GPS rows' T, TimeMS; None: none."""
    cols = fmt.columns
    if "TimeUS" in cols:
        return cols.index("TimeUS"), 1e-6
    if fmt.name.startswith("GPS") and "T" in cols and "TimeMS" in cols:  # AC 3.x: TimeMS is the GPS time of week
        return cols.index("T"), 1e-3
    if "TimeMS" in cols:
        return cols.index("TimeMS"), 1e-3
    return None


def _dataflash(log: Path, rec: Recorder, conv: Conversion, on_progress, stop_requested) -> None:
    from companion.mavlink.dataflash_stream import DataflashStream
    from companion.timebase import VehicleClock

    try:
        stream = DataflashStream(log, None)
    except OSError as err:
        raise SourceError(f"{log}: cannot read ({err.strerror})") from None
    vclock = VehicleClock()
    channels: dict[int, tuple] = {}  # id(format) -> (topic, schema name, schema, columns, time column, array columns)
    defined: dict[tuple, tuple] = {}  # a format's definition -> its channel (logs one after another share them)
    names_used: Counter[str] = Counter()
    alive: list = []
    t_s = 0.0
    try:
        while (block := stream.next_block()) is not None:
            tuples: dict[int, list] = {}
            for rows, k in block.order:
                if rows is None:  # another log starts: its own formats (and maybe a reboot of the clock)
                    continue
                fmt = rows.fmt
                key = id(fmt)
                entry = channels.get(key)
                if entry is None:
                    definition = (fmt.name, fmt.format, tuple(fmt.columns))
                    entry = defined.get(definition)
                    if entry is None:
                        entry = defined[definition] = _df_channel(fmt, names_used)
                    channels[key] = entry
                    alive.append(fmt)  # (its id stays its own while it is a key here)
                if (why := stop_requested()) is not None:
                    raise _Stopped(why)
                topic, schema_name, schema, cols, tcol, arrays = entry
                tup = tuples.get(id(rows))
                if tup is None:
                    tup = tuples[id(rows)] = list(zip(*rows.cols.values())) if rows.cols else []
                values = tup[k]
                if tcol is not None:
                    boot = values[tcol[0]]
                    if isinstance(boot, (int, float)) and boot > 0:
                        t, _reboot = vclock.to_vehicle(boot * tcol[1])
                        if t is not None:
                            t_s = t
                payload = dict(zip(cols, values))
                for c in arrays:  # (array.array -> a JSON array)
                    payload[c] = list(payload[c])
                rec.write_dict(topic, schema_name, schema, payload, t_s)
                conv.counts[fmt.name] += 1
            if on_progress is not None:
                on_progress(block.end_offset, stream.size)
    finally:
        stream.close()
    _dataflash_damage(stream, conv)


def _df_channel(fmt, names_used: Counter) -> tuple:
    """Topic, schema name, schema, columns and boot-time column of a new format definition; a type defined again
    differently (logs one after another) gets a topic of its own (``NAME_2``)."""
    names_used[fmt.name] += 1
    suffix = "" if names_used[fmt.name] == 1 else f"_{names_used[fmt.name]}"
    schema = dataflash_schema(fmt)
    arrays = tuple(c for c, ch in zip(fmt.columns, fmt.chars) if ch == "a")
    return (f"{DATAFLASH_PREFIX}{fmt.name}{suffix}", f"ardupilot.dataflash.{fmt.name}{suffix}", schema,
            list(fmt.columns), _boot_time_column(fmt), arrays)


def _dataflash_damage(stream, conv: Conversion) -> None:
    if stream.skipped_bytes:
        conv.warnings.append(f"skipped {stream.skipped_bytes} bytes in {stream.skipped_stretches} stretches that are no "
                             "dataflash records")
        conv.damaged = True
    if stream.unfit:
        which = ", ".join(f"{n} {name}" for name, n in sorted(stream.unfit.items()))
        conv.warnings.append(f"skipped records whose format does not fit them ({which})")
        conv.damaged = True
    if stream.truncated is not None:
        at, length = stream.truncated
        conv.warnings.append(f"truncated: the last record (at byte {at}) needs {length} bytes but the file ends after "
                             f"{stream.size - at}")
        conv.damaged = True
    if stream.trailing_garbage is not None:
        at, n = stream.trailing_garbage
        conv.warnings.append(f"the last {n} bytes (from byte {at}) are not dataflash records")
        conv.damaged = True


# ------------------------------------------------------------------------------------------------ tlog

def mavlink_schema(msg) -> dict:
    """JSON schema of a MAVLink message type (its dialect class's fields), with the sender's ids."""
    props: dict[str, Any] = {"_sysid": {"type": "integer"}, "_compid": {"type": "integer"}}
    required = ["_sysid", "_compid"]
    names = getattr(msg, "fieldnames", None)
    if names is None:  # a message the dialect does not know: its payload bytes
        props["data"] = {"type": "array", "items": {"type": "integer"}}
        required.append("data")
    else:
        lengths = dict(zip(msg.ordered_fieldnames, msg.array_lengths))  # (both in wire order; fieldnames: XML's)
        for name, ftype in zip(names, msg.fieldtypes):
            n = lengths.get(name, 0)
            base = {"type": "integer"} if ftype in _MAV_INTEGER else {"type": "number"}
            if ftype == "char":
                props[name] = {"type": "string"}
            elif n:
                props[name] = {"type": "array", "items": base}
            else:
                props[name] = base
            if ftype == "char" or base["type"] == "integer":
                required.append(name)
    return {"title": f"mavlink.{msg.get_type()}", "type": "object", "properties": props, "required": required}


def _mav_payload(msg) -> dict:
    d: dict[str, Any] = {"_sysid": msg.get_srcSystem(), "_compid": msg.get_srcComponent()}
    names = getattr(msg, "fieldnames", None)
    if names is None:
        d["data"] = list(bytes(getattr(msg, "data", b"") or b""))
        return d
    for name in names:
        v = getattr(msg, name)
        if isinstance(v, (bytes, bytearray)):
            v = list(v)
        elif isinstance(v, float) and not math.isfinite(v):
            v = None  # left out (unknown), as everywhere in the record
        d[name] = v
    return d


def _tlog(log: Path, rec: Recorder, conv: Conversion, on_progress, stop_requested) -> None:
    from pymavlink import mavutil

    try:
        mlog = mavutil.mavlogfile(str(log), notimestamps=False)
    except Exception as err:  # noqa: BLE001 - pymavlink's assorted errors for an unreadable file
        raise SourceError(f"{log}: not a readable telemetry log ({err.__class__.__name__}: {err})") from None
    size = log.stat().st_size
    schemas: dict[str, dict] = {}
    bad = 0
    try:
        while True:
            try:
                msg = mlog.recv_msg()
            except Exception as err:  # noqa: BLE001 - a corrupt stretch pymavlink chokes on
                conv.warnings.append(f"stopped reading at byte {mlog.f.tell()} of {size}: {err.__class__.__name__}: "
                                     f"{err} (file damaged or truncated?)")
                conv.damaged = True
                break
            if msg is None:
                break
            if (why := stop_requested()) is not None:
                raise _Stopped(why)
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                bad += 1
                continue
            schema = schemas.get(mtype)
            if schema is None:
                schema = schemas[mtype] = mavlink_schema(msg)
            rec.write_dict(f"{MAVLINK_PREFIX}{mtype}", schema["title"], schema, _mav_payload(msg), msg._timestamp)
            conv.counts[mtype] += 1
            if on_progress is not None and not conv.messages & 4095:
                on_progress(mlog.f.tell(), size)
    finally:
        mlog.close()
    if bad:
        conv.warnings.append(f"skipped {bad} corrupt frames (bad CRC or garbage between frames)")
        conv.damaged = True


# ------------------------------------------------------------------------------------------------ command

def run_convert(log: Path, out: Path, *, quiet: bool = False) -> str:
    """``companion convert``: the conversion with a progress bar refreshed a few times a second, SIGINT/SIGTERM
    stopping it with the record finalised, and a summary (``-q``: only the warnings). Returns "ok", "damaged" or
    "stopped"; SourceError when the file is no log or holds no message."""
    import signal
    import time

    from companion.console import progress_bar, summary_line, warn_quietly

    detect_format(log)  # not a log: one line, before an output is made
    out.parent.mkdir(parents=True, exist_ok=True)
    bar = progress_bar(log.stat().st_size, f"convert {log.name}", quiet)
    shown = [0.0]

    def on_progress(done: int, total: int) -> None:
        now = time.monotonic()
        if now - shown[0] >= 0.25 or done >= total:
            shown[0] = now
            bar.n = done
            bar.refresh()

    stop: list[str] = []
    handlers = {sig: signal.signal(sig, lambda signum, _frame: stop.append(signal.Signals(signum).name))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    t0 = time.perf_counter()
    try:
        conv = convert_log(log, out, on_progress=on_progress, stop_requested=lambda: stop[0] if stop else None)
    finally:
        for sig, h in handlers.items():
            signal.signal(sig, h)
        bar.close()
    if not conv.messages and not conv.stopped_by:
        out.unlink(missing_ok=True)
        raise SourceError(f"{log}: no message could be read")
    if quiet:
        warn_quietly(conv.warnings, "companion.convert")
    else:
        print(f"source       {conv.kind} {log}")
        print(f"converted    {conv.messages} messages of {len(conv.counts)} types in "
              f"{time.perf_counter() - t0:.2f} s wall time")
        for w in conv.warnings:
            print(summary_line("warning:", w))
        if conv.stopped_by:
            print(f"stopped by   {conv.stopped_by}: record finalised with what was read so far")
        print(f"record       {out}")
    return "stopped" if conv.stopped_by else "damaged" if conv.damaged else "ok"
