"""Read an MCAP record back: summary of topics, counts and times, metadata; recovery of killed writes.

A finalised file is read through its summary section (statistics, chunk and message indexes); its chunks are
then streamed once to check their CRCs (:mod:`companion.record.chunks`), so damaged data is not called whole.
A file whose writer was killed has no summary: it is streamed record by record
up to the truncation point, and everything in complete chunks is reported (``Summary.recovered``).
"""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import SeekingReader
from mcap.records import Channel, Footer, Header, Message, MessageIndex, Metadata, Schema
from mcap.stream_reader import StreamReader

from companion.record.chunks import chunk_damage

MCAP_MAGIC = b"\x89MCAP0\r\n"
_FOOTER_RECORD_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, crc


class RecordError(Exception):
    """The file is not a readable MCAP record (missing, empty, not MCAP), or the recorder is closed."""


@dataclass(frozen=True)
class TopicSummary:
    topic: str
    schema_name: str
    message_encoding: str
    count: int
    first_ns: int | None  # log time of the earliest message, ns of vehicle time
    last_ns: int | None

    @property
    def span_s(self) -> float:
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9

    @property
    def rate_hz(self) -> float | None:
        """Mean message rate over the topic's span; None with fewer than two messages or zero span."""
        span = self.span_s
        return (self.count - 1) / span if self.count > 1 and span > 0 else None


@dataclass(frozen=True)
class Summary:
    path: Path
    size_bytes: int
    finalised: bool  # summary section and footer present: the writer closed the file
    library: str
    profile: str
    topics: tuple[TopicSummary, ...]  # sorted by topic
    metadata: tuple[tuple[str, dict[str, str]], ...]  # (name, data) in file order
    message_count: int
    chunk_count: int
    start_ns: int | None
    end_ns: int | None
    note: str = ""  # why the file was read by streaming / where it ends
    readable_bytes: int = 0  # bytes up to the end of the last complete record read
    damaged_chunks: tuple[str, ...] = ()  # "byte OFFSET: what is wrong" for every chunk failing its check
    _by_topic: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def damaged(self) -> bool:
        """A chunk's CRC or compression fails: some of the messages counted cannot be read back."""
        return bool(self.damaged_chunks)

    @property
    def recovered(self) -> bool:
        """True when the file was not finalised and was read back up to its truncation point."""
        return not self.finalised

    @property
    def span_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    def topic(self, name: str) -> TopicSummary:
        for t in self.topics:
            if t.topic == name:
                return t
        raise KeyError(f"no topic {name!r} in {self.path}; topics: {[t.topic for t in self.topics]}")

    def metadata_dict(self, name: str) -> dict[str, str] | None:
        """The last metadata record called ``name``, or None."""
        found = None
        for n, d in self.metadata:
            if n == name:
                found = d
        return found


def _check_mcap(path: Path) -> int:
    """Size of the file; RecordError when it is missing, empty or does not start with MCAP magic."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except FileNotFoundError:
        raise RecordError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise RecordError(f"{path}: is a directory, not an MCAP file") from None
    except OSError as exc:
        raise RecordError(f"{path}: cannot read: {exc}") from None
    if size == 0:
        raise RecordError(f"{path}: empty file (the recorder wrote nothing)")
    if head != MCAP_MAGIC:
        raise RecordError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
    return size


def summarize(path: str | os.PathLike, *, check_crcs: bool = True) -> Summary:
    """Summarise an MCAP file: per-topic schema, count, first/last log time; metadata; finalised or not; damaged
    chunks (``check_crcs``: a finalised file's chunks are streamed once; a killed one's are always checked).

    Raises RecordError for a missing, empty or non-MCAP file; never raises for a truncated one.
    """
    path = Path(path)
    size = _check_mcap(path)
    note = ""
    if size >= 2 * len(MCAP_MAGIC) + _FOOTER_RECORD_SIZE:
        with open(path, "rb") as f:
            f.seek(-len(MCAP_MAGIC), io.SEEK_END)
            tail_ok = f.read() == MCAP_MAGIC
        if tail_ok:
            try:
                return _from_summary_section(path, size, check_crcs)
            except _NoSummary as exc:
                note = str(exc)
            except Exception as exc:  # damaged summary section: fall back to reading the data
                note = f"summary section unreadable ({type(exc).__name__}: {exc})"
    return _from_stream(path, size, note)


class _NoSummary(Exception):
    pass


def _from_summary_section(path: Path, size: int, check_crcs: bool) -> Summary:
    with open(path, "rb") as f:
        reader = SeekingReader(f, record_size_limit=size)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise _NoSummary("finalised without statistics; counted by reading the data")
        header = reader.get_header()
        stats = summary.statistics
        bounds = _channel_bounds_from_indexes(f, summary, size)
        if bounds is None:
            raise _NoSummary("no message indexes; counted by reading the data")
        metadata = tuple((m.name, dict(m.metadata)) for m in reader.iter_metadata())
        damaged = []
        for c in summary.chunk_indexes if check_crcs else ():
            why = chunk_damage(f, c.chunk_start_offset, size)
            if why:
                damaged.append(f"byte {c.chunk_start_offset}: {why}")
    per_channel = {
        cid: (stats.channel_message_counts.get(cid, 0),) + bounds.get(cid, (None, None)) for cid in summary.channels
    }
    return _build(
        path,
        size,
        finalised=True,
        header=header,
        schemas=summary.schemas,
        channels=summary.channels,
        per_channel=per_channel,
        metadata=metadata,
        chunk_count=stats.chunk_count,
        note="",
        readable_bytes=size,
        damaged_chunks=tuple(damaged),
    )


def _read_message_index(f, offset: int, size: int) -> MessageIndex:
    f.seek(offset)
    rec = next(StreamReader(f, skip_magic=True, record_size_limit=size).records)
    if not isinstance(rec, MessageIndex):
        raise ValueError(f"expected a message index at byte {offset}, found {type(rec).__name__}")
    return rec


def _channel_bounds_from_indexes(f, summary, size: int) -> dict[int, tuple[int, int]] | None:
    """First/last log time per channel from the message indexes of as few chunks as needed."""
    chunks = summary.chunk_indexes
    if any(not c.message_index_offsets for c in chunks):
        return None
    cache: dict[tuple[int, int], tuple[int, int]] = {}

    def times(chunk, cid) -> tuple[int, int]:
        key = (chunk.chunk_start_offset, cid)
        if key not in cache:
            recs = _read_message_index(f, chunk.message_index_offsets[cid], size).records
            ts = [t for t, _ in recs]
            cache[key] = (min(ts), max(ts)) if ts else (None, None)
        return cache[key]

    by_start = sorted(chunks, key=lambda c: c.message_start_time)
    by_end = sorted(chunks, key=lambda c: c.message_end_time, reverse=True)
    out: dict[int, tuple[int, int]] = {}
    for cid in summary.channels:
        first = last = None
        for c in by_start:  # a later-starting chunk cannot hold an earlier message than `first`
            if cid not in c.message_index_offsets:
                continue
            if first is not None and c.message_start_time > first:
                break
            lo, _ = times(c, cid)
            if lo is not None and (first is None or lo < first):
                first = lo
        for c in by_end:
            if cid not in c.message_index_offsets:
                continue
            if last is not None and c.message_end_time < last:
                break
            _, hi = times(c, cid)
            if hi is not None and (last is None or hi > last):
                last = hi
        out[cid] = (first, last)
    return out


def _records_until_damage(path: Path, size: int, f) -> Iterator:
    """Records in file order; stops quietly at the first truncated or corrupt record.

    Yields the records, then a final ``(_END, readable_bytes, reason)`` tuple.
    """
    reader = StreamReader(f, validate_crcs=True, record_size_limit=size)
    good = len(MCAP_MAGIC)
    try:
        for rec in reader.records:
            good = f.tell()
            yield rec
        reason = ""
    except Exception as exc:  # truncated/corrupt tail: everything before it has been yielded
        reason = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    yield (_END, good, reason)


_END = object()


def _from_stream(path: Path, size: int, note: str) -> Summary:
    header = None
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    per_channel: dict[int, list] = {}
    metadata: list[tuple[str, dict[str, str]]] = []
    finalised = False
    readable = len(MCAP_MAGIC)
    reason = ""
    with open(path, "rb") as f:
        for rec in _records_until_damage(path, size, f):
            if isinstance(rec, Message):
                pc = per_channel.get(rec.channel_id)
                t = rec.log_time
                if pc is None:
                    per_channel[rec.channel_id] = [1, t, t]
                else:
                    pc[0] += 1
                    if t < pc[1]:
                        pc[1] = t
                    if t > pc[2]:
                        pc[2] = t
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                metadata.append((rec.name, dict(rec.metadata)))
            elif isinstance(rec, Header):
                header = rec
            elif isinstance(rec, Footer):
                finalised = True
            elif isinstance(rec, tuple) and rec and rec[0] is _END:
                _, readable, reason = rec
    finalised = finalised and not reason  # footer and closing magic read without error
    if finalised:
        readable = size
    if not finalised:
        lost = size - readable
        where = f"readable up to byte {readable} of {size}" + (f" ({lost} bytes lost)" if lost else "")
        note = "; ".join(x for x in (note, f"not finalised (writer killed or file truncated): {where}") if x)
        if reason and lost:
            note += f"; stopped at: {reason}"
    for cid in per_channel:
        channels.setdefault(cid, Channel(id=cid, topic=f"<channel {cid}>", message_encoding="", schema_id=0, metadata={}))
    full = {cid: tuple(per_channel.get(cid, (0, None, None))) for cid in channels}
    return _build(
        path,
        size,
        finalised=finalised,
        header=header,
        schemas=schemas,
        channels=channels,
        per_channel=full,
        metadata=tuple(metadata),
        chunk_count=-1,
        note=note,
        readable_bytes=readable,
    )


def _build(path, size, *, finalised, header, schemas, channels, per_channel, metadata, chunk_count, note, readable_bytes,
           damaged_chunks=()):
    merged: dict[str, list] = {}
    for cid, ch in channels.items():
        count, first, last = per_channel.get(cid, (0, None, None))
        schema = schemas.get(ch.schema_id)
        name = schema.name if schema is not None else ("" if ch.schema_id == 0 else f"<schema {ch.schema_id}>")
        m = merged.get(ch.topic)
        if m is None:
            merged[ch.topic] = [name, ch.message_encoding, count, first, last]
        else:  # several channels on one topic (not written by this recorder): combine them
            if name not in m[0].split(" | "):
                m[0] = f"{m[0]} | {name}"
            m[2] += count
            m[3] = first if m[3] is None else (m[3] if first is None else min(m[3], first))
            m[4] = last if m[4] is None else (m[4] if last is None else max(m[4], last))
    topics = tuple(TopicSummary(t, *merged[t]) for t in sorted(merged))
    firsts = [t.first_ns for t in topics if t.first_ns is not None]
    lasts = [t.last_ns for t in topics if t.last_ns is not None]
    return Summary(
        path=path,
        size_bytes=size,
        finalised=finalised,
        library=header.library if header is not None else "",
        profile=header.profile if header is not None else "",
        topics=topics,
        metadata=metadata,
        message_count=sum(t.count for t in topics),
        chunk_count=chunk_count,
        start_ns=min(firsts) if firsts else None,
        end_ns=max(lasts) if lasts else None,
        note=note,
        readable_bytes=readable_bytes,
        damaged_chunks=tuple(damaged_chunks),
    )


def iter_payloads(path: str | os.PathLike, topic: str | None = None) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log_time_ns, payload bytes) of every message in file order; stops quietly at truncation.

    Raises RecordError for a missing, empty or non-MCAP file.
    """
    path = Path(path)
    size = _check_mcap(path)
    channels: dict[int, str] = {}
    with open(path, "rb") as f:
        for rec in _records_until_damage(path, size, f):
            if isinstance(rec, Message):
                t = channels.get(rec.channel_id, f"<channel {rec.channel_id}>")
                if topic is None or t == topic:
                    yield t, rec.log_time, rec.data
            elif isinstance(rec, Channel):
                channels[rec.id] = rec.topic
            elif isinstance(rec, Footer):
                return


_YEAR_2001_NS = 978307200 * 10**9  # log times past this are Unix epoch times, not boot times


def _fmt_utc(ns: int | None) -> str:
    if ns is None:
        return "-"
    import datetime

    t = datetime.datetime.fromtimestamp(ns // 10**9, tz=datetime.timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S") + f".{ns % 10**9 // 10**6:03d}Z"


def _fmt_t(ns: int | None) -> str:
    return "-" if ns is None else f"{ns / 1e9:.3f}"


def _fmt_size(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n} B"


def format_summary(summary: Summary, *, max_value_chars: int = 160) -> str:
    """Readable table for ``companion inspect``: topics (schema, count, rate, first/last time), span, metadata."""
    s = summary
    state = "finalised" if s.finalised else "RECOVERED (not finalised)"
    if s.damaged:
        of = f" of {s.chunk_count}" if s.chunk_count >= 0 else ""
        state += f", {len(s.damaged_chunks)}{of} chunks DAMAGED: their messages cannot be read"
    lines = [
        f"file      {s.path}  ({_fmt_size(s.size_bytes)}, {state})",
    ]
    for d in s.damaged_chunks[:10]:
        lines.append(f"damaged   chunk at {d}")
    if len(s.damaged_chunks) > 10:
        lines.append(f"damaged   ... and {len(s.damaged_chunks) - 10} more chunks")
    if s.note:
        lines.append(f"note      {s.note}")
    if s.library:
        lines.append(f"writer    {s.library}")
    chunks = f", {s.chunk_count} chunks" if s.chunk_count >= 0 else ""
    clock = s.metadata_dict("clock") or {}
    utc = clock.get("log_time", "").startswith(("UTC", "host UTC")) or (s.start_ns or 0) > _YEAR_2001_NS
    base = s.start_ns if utc and s.start_ns is not None else 0
    if utc:
        span = f"{_fmt_utc(s.start_ns)} .. {_fmt_utc(s.end_ns)} ({s.span_s:.3f} s)"
    else:
        span = f"{_fmt_t(s.start_ns)} s .. {_fmt_t(s.end_ns)} s vehicle time ({s.span_s:.3f} s)"
    lines.append(f"span      {span}, {s.message_count} messages on {len(s.topics)} topics{chunks}")
    lines.append("")
    head = ("topic", "schema", "count", "rate Hz", "first s", "last s") if not utc else (
        "topic", "schema", "count", "rate Hz", "first +s", "last +s")
    rows = [
        (
            t.topic,
            t.schema_name or "-",
            str(t.count),
            "-" if t.rate_hz is None else f"{t.rate_hz:.2f}",
            _fmt_t(None if t.first_ns is None else t.first_ns - base),
            _fmt_t(None if t.last_ns is None else t.last_ns - base),
        )
        for t in s.topics
    ]
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    left = (True, True, False, False, False, False)

    def fmt(r):
        return "  ".join(c.ljust(w) if lf else c.rjust(w) for c, w, lf in zip(r, widths, left)).rstrip()

    lines.append(fmt(head))
    lines.append("  ".join("-" * w for w in widths))
    lines.extend(fmt(r) for r in rows)
    if not rows:
        lines.append("(no messages)")
    lines.append("")
    lines.append(f"metadata  ({len(s.metadata)} records)")
    for name, data in s.metadata:
        lines.append(f"  {name}")
        for k, v in data.items():
            if len(v) > max_value_chars:
                v = v[:max_value_chars] + f"... ({len(v)} chars)"
            lines.append(f"    {k} = {v}")
    return "\n".join(lines)
