"""A record payload's JSON: compact, every unknown value (None, NaN/inf) left out (see companion.record.schemas)."""

from __future__ import annotations

import json
from typing import Any

import orjson

from companion.record.schemas import _plain, drop_unknown

_ORJSON_OPTS = orjson.OPT_SERIALIZE_NUMPY


def _dumps(d: Any) -> bytes:
    """Compact JSON of a plain value, every unknown value (None, NaN/inf) left out; orjson, or the standard library
    for what orjson refuses (an integer beyond 64 bits, a value of another type)."""
    try:
        data = orjson.dumps(d, option=_ORJSON_OPTS)  # NaN/inf -> null, like None
    except TypeError:  # orjson.JSONEncodeError is a TypeError
        data = None
    if data is not None and b"null" not in data:
        return data
    plain = drop_unknown(_plain(d))
    try:
        return orjson.dumps(plain, option=_ORJSON_OPTS)
    except TypeError:
        return json.dumps(plain, separators=(",", ":"), allow_nan=False).encode()


def _dumps_jsonable(d: Any) -> bytes:
    """:func:`_dumps` of what ``to_jsonable`` made (plain already: NaN/inf are None): the unknowns dropped at once; a
    payload that still says null (inside a string, a value not plain after all) takes the general path."""
    try:
        data = orjson.dumps(drop_unknown(d), option=_ORJSON_OPTS)
    except TypeError:
        return _dumps(d)
    return data if b"null" not in data else _dumps(d)
