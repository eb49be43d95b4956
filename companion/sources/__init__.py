"""Event sources: log files and live MAVLink links behind one async-iterator interface."""

from companion.sources.base import Source, SourceError, SourceInfo
from companion.sources.files import FileSource, detect_format, open_reader, read_events

__all__ = ["Source", "SourceError", "SourceInfo", "FileSource", "detect_format", "open_reader", "read_events"]
