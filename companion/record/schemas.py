"""JSON schemas for the MCAP record: derived from dataclasses, plus Foxglove's LocationFix.

Every recorded type gets one JSON schema (MCAP schema encoding ``jsonschema``), derived once per class
from its dataclass fields and type hints and cached:

====================================  ==========================================================
field type                            JSON schema
====================================  ==========================================================
``float``                             ``{"type": "number"}``, not required (NaN/inf: left out)
``int`` / ``IntEnum``                 ``{"type": "integer"}``
``bool``                              ``{"type": "boolean"}``
``str``                               ``{"type": "string"}``
``X | None``                          schema of X, not required (None: left out)
``tuple[float, float, float]``        array of numbers with minItems = maxItems = 3
``tuple[float, ...]``, ``list[X]``    array of X
``dict[str, X]``                      object (no fixed properties) whose values are X
nested dataclass                      object (recursively)
====================================  ==========================================================

Unknown values are left out, never ``null``. JSON has no NaN, and a standard validator (Python
``jsonschema``) accepts ``null`` only where the schema's ``type`` lists ``"null"``; Foxglove's JSON-schema
reader accepts only a single ``type`` string per field (``parseJsonSchema`` in mcap-support, the code
Foxglove Studio opened and Lichtblick continues: a type list throws "Unsupported type", and the player
drops the whole topic with "Error in topic ..."). So a payload leaves out a ``None`` or non-finite value
(a field that may be unknown is not ``required``), and an array that holds one is left out whole. Every
payload then validates against its embedded schema with ``jsonschema`` (draft 2020-12), and every schema
has the shape Foxglove reads (``tests/record/test_record.py::assert_foxglove_parsable``). Checked once with that
reader itself (Lichtblick's parseJsonSchema.ts at 9554e1e, compiled with tsc, run with node over the schemas of
replayed real logs): every schema accepted.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from enum import Enum
from functools import lru_cache
from typing import Any, Union

JSON_SCHEMA_ENCODING = "jsonschema"
JSON_MESSAGE_ENCODING = "json"

LOCATION_FIX_SCHEMA_NAME = "foxglove.LocationFix"
LOG_SCHEMA_NAME = "foxglove.Log"

def schema_name(cls: type) -> str:
    """MCAP schema name of a dataclass: its module-qualified class name."""
    return f"{cls.__module__}.{cls.__qualname__}"


@lru_cache(maxsize=None)
def dataclass_schema(cls: type) -> dict:
    """JSON schema of a dataclass's payload; cached per class. Do not mutate the result.

    Raises TypeError for a non-dataclass or for a field type with no JSON mapping.
    """
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise TypeError(f"{cls!r} is not a dataclass type")
    try:
        hints = typing.get_type_hints(cls)
    except Exception as exc:  # unresolvable forward reference
        raise TypeError(f"cannot resolve the type hints of {cls.__qualname__}: {exc}") from exc
    props: dict[str, Any] = {}
    required: list[str] = []
    for f in dataclasses.fields(cls):
        try:
            props[f.name] = _type_schema(hints[f.name])
        except TypeError as exc:
            raise TypeError(f"{cls.__qualname__}.{f.name}: {exc}") from None
        if f.name == "t_s" or not _may_be_unknown(hints[f.name]):  # the recorder refuses a non-finite t_s
            required.append(f.name)
    schema: dict[str, Any] = {
        "title": schema_name(cls),
        "type": "object",
        "properties": props,
        "required": required,
        "additionalProperties": False,
    }
    doc = (cls.__doc__ or "").strip()
    if doc and not doc.startswith(cls.__name__ + "("):  # skip dataclass's auto-generated signature doc
        schema["description"] = doc.split("\n\n")[0].replace("\n", " ")
    return schema


def _may_be_unknown(tp: Any) -> bool:
    """A field whose value may be left out of a payload: ``X | None``, a float (NaN/inf), or an array of floats."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Union or origin is types.UnionType:
        return True
    if tp is float:
        return True
    if origin in (tuple, list):
        return any(_may_be_unknown(a) for a in args if a is not Ellipsis)
    return False


def _type_schema(tp: Any) -> dict:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is Union or origin is types.UnionType:
        non_null = [a for a in args if a is not type(None)]
        if len(non_null) != 1:
            raise TypeError(f"unsupported union {tp!r}: only `X | None` is recorded")
        return dict(_type_schema(non_null[0]))  # None: the field is left out of the payload
    if tp is bool:
        return {"type": "boolean"}
    if isinstance(tp, type) and issubclass(tp, Enum):
        if issubclass(tp, int):
            return {"type": "integer"}
        raise TypeError(f"unsupported enum {tp!r}: only IntEnum is recorded")
    if tp is int:
        return {"type": "integer"}
    if tp is float:
        return {"type": "number"}  # NaN/inf: the field is left out of the payload
    if tp is str:
        return {"type": "string"}
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return {"type": "array", "items": _type_schema(args[0])}
        if args and all(a == args[0] for a in args):
            n = len(args)
            return {"type": "array", "items": _type_schema(args[0]), "minItems": n, "maxItems": n}
        raise TypeError(f"unsupported tuple {tp!r}: items must all have one type (else use a nested dataclass)")
    if origin is list:
        if not args:
            raise TypeError(f"unsupported bare list {tp!r}: give the item type")
        return {"type": "array", "items": _type_schema(args[0])}
    if origin is dict:
        if not args or args[0] is not str:
            raise TypeError(f"unsupported dict {tp!r}: keys must be str")
        # "properties": {} so readers that walk properties (Foxglove) accept the field
        return {"type": "object", "properties": {}, "additionalProperties": _type_schema(args[1])}
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        nested = dict(dataclass_schema(tp))
        nested.pop("description", None)
        return nested
    raise TypeError(f"unsupported field type {tp!r}")


def to_jsonable(obj: Any) -> Any:
    """Plain JSON value of a dataclass instance (or anything inside one).

    Uses the object's own ``to_dict()`` when it has one (companion.events.Event). NaN/inf -> None,
    tuples -> lists, IntEnum -> int, numpy scalars/arrays -> Python numbers/lists.
    """
    to_dict = getattr(obj, "to_dict", None)
    if to_dict is not None and dataclasses.is_dataclass(obj):
        return to_dict()
    return _plain(obj)


def _plain(v: Any) -> Any:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if v is None or isinstance(v, (bool, str)):
        return v
    if isinstance(v, Enum):
        return v.value
    if isinstance(v, int):
        return int(v)
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        to_dict = getattr(v, "to_dict", None)
        if to_dict is not None:
            return _plain(to_dict())
        return {f.name: _plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (tuple, list)):
        return [_plain(x) for x in v]
    tolist = getattr(v, "tolist", None)  # numpy arrays and scalars
    if tolist is not None:
        return _plain(tolist())
    raise TypeError(f"cannot record a value of type {type(v).__name__}: {v!r}")


_UNKNOWN = object()


def drop_unknown(value: Any) -> Any:
    """A plain JSON value (:func:`to_jsonable`) as recorded: every ``None`` left out -- a dict's key whose value is
    None, and an array holding one as a whole (see the module doc). A top-level None gives None."""
    out = _drop(value)
    return None if out is _UNKNOWN else out


def _drop(v: Any) -> Any:
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            x = _drop(x)
            if x is not _UNKNOWN:
                out[k] = x
        return out
    if isinstance(v, list):
        items = [_drop(x) for x in v]
        return _UNKNOWN if any(x is _UNKNOWN for x in items) else items
    return _UNKNOWN if v is None else v


def _number(description: str) -> dict:
    return {"type": "number", "description": description}


#: Foxglove's ``foxglove.LocationFix`` JSON schema (foxglove/foxglove-sdk, schemas/jsonschema/LocationFix.json),
#: the message the Map panel draws. ``position_covariance`` is ENU (East, North, Up), m^2, row-major,
#: as in ROS sensor_msgs/NavSatFix. A copy, kept because Foxglove ships its JSON schemas on npm only: the
#: foxglove-sdk Python package has LocationFix as protobuf, and a protobuf message in the record would be the one
#: topic ``jsonschema`` cannot validate and ``companion inspect`` cannot read without protobuf.
#: tests/record/test_location_fix.py checks this copy field by field against the SDK's schema.
LOCATION_FIX_SCHEMA: dict = {
    "title": LOCATION_FIX_SCHEMA_NAME,
    "description": "A navigation satellite fix for any Global Navigation Satellite System",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
            "description": "Timestamp of the message",
        },
        "frame_id": {
            "type": "string",
            "description": "Frame for the sensor. Latitude and longitude readings are at the origin of the frame.",
        },
        "latitude": _number("Latitude in degrees"),
        "longitude": _number("Longitude in degrees"),
        "altitude": _number("Altitude in meters"),
        "position_covariance": {
            "type": "array",
            "items": {"type": "number"},
            "minItems": 9,
            "maxItems": 9,
            "description": "Position covariance (m^2) defined relative to a tangential plane through the "
            "reported position. The components are East, North, and Up (ENU), in row-major order.",
        },
        "position_covariance_type": {
            "title": "foxglove.PositionCovarianceType",
            "description": "If `position_covariance` is available, `position_covariance_type` must be set "
            "to indicate the type of covariance.",
            "oneOf": [
                {"title": "UNKNOWN", "const": 0, "description": "Unknown position covariance type"},
                {"title": "APPROXIMATED", "const": 1, "description": "Position covariance is approximated"},
                {
                    "title": "DIAGONAL_KNOWN",
                    "const": 2,
                    "description": "Position covariance is per-axis, so put it along the diagonal",
                },
                {"title": "KNOWN", "const": 3, "description": "Position covariance of the fix is known"},
            ],
        },
        "heading": _number("Heading (yaw angle), in radians, measured clockwise from north"),
        "velocity": {
            "title": "foxglove.Vector3",
            "description": "Velocity in local East-North-Up (ENU) frame in m/s",
            "type": "object",
            "properties": {
                "x": _number("x coordinate length"),
                "y": _number("y coordinate length"),
                "z": _number("z coordinate length"),
            },
            "required": ["x", "y", "z"],
        },
        "color": {
            "title": "foxglove.Color",
            "description": "Color used to visualize the location",
            "type": "object",
            "properties": {
                "r": _number("Red value between 0 and 1"),
                "g": _number("Green value between 0 and 1"),
                "b": _number("Blue value between 0 and 1"),
                "a": _number("Alpha value between 0 and 1"),
            },
            "required": ["r", "g", "b", "a"],
        },
        "metadata": {
            "type": "array",
            "items": {
                "title": "foxglove.KeyValuePair",
                "description": "A key with its associated value",
                "type": "object",
                "properties": {
                    "key": {"type": "string", "description": "Key"},
                    "value": {"type": "string", "description": "Value"},
                },
                "required": ["key", "value"],
            },
            "description": "Additional user-provided metadata associated with the location fix. Keys must be unique.",
        },
    },
    "required": [
        "timestamp",
        "frame_id",
        "latitude",
        "longitude",
        "altitude",
        "position_covariance",
        "position_covariance_type",
    ],
}

#: foxglove.PositionCovarianceType values.
COV_UNKNOWN = 0
COV_APPROXIMATED = 1
COV_DIAGONAL_KNOWN = 2
COV_KNOWN = 3


def _time_schema(description: str) -> dict:
    return {
        "type": "object",
        "title": "time",
        "properties": {
            "sec": {"type": "integer", "minimum": 0},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
        },
        "description": description,
    }


#: Foxglove's ``foxglove.Log`` JSON schema (foxglove/foxglove-sdk, schemas/jsonschema/Log.json), what the Log panel
#: shows; a copy for the same reason as LOCATION_FIX_SCHEMA's, checked the same way (tests/record/test_location_fix.py).
LOG_SCHEMA: dict = {
    "title": LOG_SCHEMA_NAME,
    "description": "A log message",
    "type": "object",
    "properties": {
        "timestamp": _time_schema("Timestamp of log message"),
        "level": {
            "title": "foxglove.LogLevel",
            "description": "Log level",
            "oneOf": [
                {"title": "UNKNOWN", "const": 0, "description": "Unknown log level"},
                {"title": "DEBUG", "const": 1, "description": "Debug log level"},
                {"title": "INFO", "const": 2, "description": "Info log level"},
                {"title": "WARNING", "const": 3, "description": "Warning log level"},
                {"title": "ERROR", "const": 4, "description": "Error log level"},
                {"title": "FATAL", "const": 5, "description": "Fatal log level"},
            ],
        },
        "message": {"type": "string", "description": "Log message"},
        "name": {"type": "string", "description": "Process or node name"},
        "file": {"type": "string", "description": "Filename"},
        "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"},
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}

#: foxglove.LogLevel values.
LOG_UNKNOWN, LOG_DEBUG, LOG_INFO, LOG_WARNING, LOG_ERROR, LOG_FATAL = range(6)
