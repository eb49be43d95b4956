"""The record's foxglove.LocationFix and foxglove.Log JSON schemas are Foxglove's own, field for field: checked against
the schemas the maintained foxglove-sdk package ships (as protobuf descriptors; Foxglove publishes its JSON schemas on
npm only)."""

from __future__ import annotations

import warnings

import pytest

from companion.record import LOCATION_FIX_SCHEMA
from companion.record.schemas import LOG_SCHEMA

_JSON_TYPE = {1: "number", 2: "number", 9: "string", 8: "boolean", 3: "integer", 4: "integer", 5: "integer", 6: "integer", 7: "integer",
              13: "integer", 11: "object"}  # protobuf FieldDescriptorProto.Type -> JSON type


def _sdk_messages(name: str = "LocationFix") -> dict:
    from google.protobuf import descriptor_pb2  # the test extra's protobuf

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # foxglove.schemas -> foxglove.messages in later SDKs
        import foxglove.schemas as fs

        schema = getattr(fs, name).get_schema()
    assert schema.name == f"foxglove.{name}" and schema.encoding == "protobuf"
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    return {f"{f.package}.{m.name}": m for f in fds.file for m in f.message_type}


def _check(json_schema: dict, msg, messages: dict, where: str) -> None:
    props = json_schema["properties"]
    assert set(props) == {f.name for f in msg.field}, where
    for f in msg.field:
        field = props[f.name]
        w = f"{where}.{f.name}"
        if f.label == 3:  # repeated
            assert field["type"] == "array", w
            field = field["items"]
        if f.type == 14:  # enum: the JSON schema lists its values as numeric consts
            (enum,) = [e for e in msg.enum_type if f.type_name.endswith("." + e.name)]
            assert {(a["title"], a["const"]) for a in field["oneOf"]} == {(v.name, v.number) for v in enum.value}, w
        elif f.type_name == ".google.protobuf.Timestamp":  # Foxglove's JSON time: sec/nsec
            assert field["type"] == "object" and set(field["properties"]) == {"sec", "nsec"}, w
        else:
            assert field["type"] == _JSON_TYPE[f.type], w
            if f.type == 11:
                _check(field, messages[f.type_name.lstrip(".")], messages, w)


def test_location_fix_schema_is_foxglove_sdks():
    messages = _sdk_messages()
    _check(LOCATION_FIX_SCHEMA, messages["foxglove.LocationFix"], messages, "LocationFix")
    assert LOCATION_FIX_SCHEMA["title"] == "foxglove.LocationFix"


def test_log_schema_is_foxglove_sdks():
    messages = _sdk_messages("Log")
    _check(LOG_SCHEMA, messages["foxglove.Log"], messages, "Log")
    assert LOG_SCHEMA["title"] == "foxglove.Log"


def test_the_check_can_fail():
    messages = _sdk_messages()
    bad = {**LOCATION_FIX_SCHEMA, "properties": {k: v for k, v in LOCATION_FIX_SCHEMA["properties"].items()
                                                 if k != "heading"}}
    with pytest.raises(AssertionError):
        _check(bad, messages["foxglove.LocationFix"], messages, "LocationFix")
