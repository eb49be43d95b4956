"""The MCAP writer's per-message path in one struct.pack and two buffer writes, the same bytes as mcap's own.

``mcap.writer.Writer.add_message`` builds a ``Message`` dataclass and writes it field by field through its record
builder (a dozen Python calls a message: a third of a replay's time). :func:`fast_add_message` returns a function
that does what it does for a chunked writer -- file statistics, the chunk's message index and time range, the
Message record -- straight into the chunk's buffer, and writes the chunk's message indexes in one pack each. It reaches into the Writer's private state, so it checks that
state first and returns None when it is not what it expects (another mcap version): the caller then keeps the
library's own ``add_message``. tests/record/test_fast_messages.py compares the files byte for byte.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from io import BytesIO

from mcap.records import MessageIndex
from mcap.writer import Writer

_MESSAGE_OPCODE = 0x05
_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel id, sequence, log time, publish time
_FIXED = 2 + 4 + 8 + 8  # the record's length before its data
_INDEX_OPCODE = 0x07
_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, record length, channel id, bytes of (log time, offset) pairs


class _MessageIndex(MessageIndex):
    """mcap's MessageIndex written in one pack instead of two calls a message (the same bytes)."""

    def write(self, stream) -> None:
        n = len(self.records)
        flat = [v for pair in self.records for v in pair]
        stream.write(_INDEX_HEAD.pack(_INDEX_OPCODE, 2 + 4 + 16 * n, self.channel_id, 16 * n)
                     + struct.pack(f"<{2 * n}Q", *flat))


def fast_add_message(writer: Writer) -> Callable[[int, int, bytes, int, int], None] | None:
    """``add(channel_id, log_time, data, publish_time, sequence)`` for a chunked Writer whose chunk size the caller
    manages (it never finalises a chunk itself); None when the Writer's internals are not the known ones."""
    stats = getattr(writer, "_Writer__statistics", None)
    builder = getattr(writer, "_Writer__chunk_builder", None)
    if stats is None or builder is None:
        return None
    rw = getattr(builder, "record_writer", None)
    needed = ("message_count", "message_start_time", "message_end_time", "channel_message_counts")
    if (not all(hasattr(stats, a) for a in needed) or not isinstance(getattr(rw, "_buffer", None), BytesIO)
            or not isinstance(getattr(builder, "message_indices", None), dict)
            or not hasattr(builder, "num_messages") or not hasattr(builder, "message_start_time")):
        return None
    pack = _HEAD.pack
    counts = stats.channel_message_counts
    indices = builder.message_indices

    def add(channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> None:
        if stats.message_count == 0:
            stats.message_start_time = log_time
        elif log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        counts[channel_id] += 1
        stats.message_count += 1
        if builder.num_messages == 0:
            builder.message_start_time = log_time
        elif log_time < builder.message_start_time:
            builder.message_start_time = log_time
        if log_time > builder.message_end_time:
            builder.message_end_time = log_time
        buf = rw._buffer  # the builder swaps in a new buffer at every chunk end
        index = indices.get(channel_id)
        if not index:  # (mcap's own test: a new or an empty index is (re)created)
            index = indices[channel_id] = _MessageIndex(channel_id=channel_id, records=[])
        index.records.append((log_time, buf.tell()))
        builder.num_messages += 1
        buf.write(pack(_MESSAGE_OPCODE, _FIXED + len(data), channel_id, sequence, log_time, publish_time))
        buf.write(data)

    return add
