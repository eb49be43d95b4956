"""MCAP record of every pipeline step (see :mod:`companion.record.recorder`) and reading it back."""

from companion.record.inspect import RecordError, Summary, TopicSummary, format_summary, iter_payloads, summarize
from companion.record.recorder import Recorder
from companion.record.rotating import RotatingRecorder
from companion.record.schemas import LOCATION_FIX_SCHEMA, LOCATION_FIX_SCHEMA_NAME, dataclass_schema, schema_name

__all__ = [
    "LOCATION_FIX_SCHEMA",
    "LOCATION_FIX_SCHEMA_NAME",
    "RecordError",
    "Recorder",
    "RotatingRecorder",
    "Summary",
    "TopicSummary",
    "dataclass_schema",
    "format_summary",
    "iter_payloads",
    "schema_name",
    "summarize",
]
