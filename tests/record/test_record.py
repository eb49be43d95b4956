"""MCAP record: schemas, payloads, LocationFix, determinism, finalising and recovery after kill signals."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from mcap.reader import make_reader

from companion.events import EVENT_TYPES, GnssFix, ImuSample, StatusText
from companion.record import (
    LOCATION_FIX_SCHEMA,
    LOCATION_FIX_SCHEMA_NAME,
    Recorder,
    RecordError,
    dataclass_schema,
    format_summary,
    iter_payloads,
    summarize,
)
from companion.record.schemas import drop_unknown

REPO = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------- a small JSON-schema check


def validate(value, schema: dict, where: str = "$") -> None:
    """Check ``value`` against the JSON-schema keywords the recorder uses; AssertionError on mismatch."""
    if "oneOf" in schema:
        hits = 0
        for sub in schema["oneOf"]:
            try:
                validate(value, sub, where)
                hits += 1
            except AssertionError:
                pass
        assert hits == 1, f"{where}: {value!r} matches {hits} of oneOf"
    if "const" in schema:
        assert value == schema["const"] and type(value) is type(schema["const"]), f"{where}: {value!r} != const"
    if "type" in schema:
        types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        ok = {
            "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
            "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
            "boolean": lambda v: isinstance(v, bool),
            "string": lambda v: isinstance(v, str),
            "null": lambda v: v is None,
            "array": lambda v: isinstance(v, list),
            "object": lambda v: isinstance(v, dict),
        }
        assert any(ok[t](value) for t in types), f"{where}: {value!r} is not {types}"
    if isinstance(value, dict):
        for k in schema.get("required", []):
            assert k in value, f"{where}: missing required {k!r}"
        props = schema.get("properties", {})
        for k, v in value.items():
            if k in props:
                validate(v, props[k], f"{where}.{k}")
            elif schema.get("additionalProperties") is False:
                raise AssertionError(f"{where}: unexpected property {k!r}")
            elif isinstance(schema.get("additionalProperties"), dict):
                validate(v, schema["additionalProperties"], f"{where}.{k}")
    if isinstance(value, list):
        assert len(value) >= schema.get("minItems", 0), f"{where}: too few items"
        assert len(value) <= schema.get("maxItems", math.inf), f"{where}: too many items"
        prefix = schema.get("prefixItems", [])
        for i, v in enumerate(value):
            if i < len(prefix):
                validate(v, prefix[i], f"{where}[{i}]")
            elif isinstance(schema.get("items"), dict):
                validate(v, schema["items"], f"{where}[{i}]")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        assert value >= schema.get("minimum", -math.inf) and value <= schema.get("maximum", math.inf), where


def validate_all(value, schema):
    """Hand check, then the standard validator (``jsonschema``, a test dependency)."""
    import jsonschema

    validate(value, schema)
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(value, schema, cls=jsonschema.Draft202012Validator)


def assert_foxglove_parsable(schema: dict, where: str = "$") -> None:
    """The rules of Foxglove's JSON-schema reader (@foxglove/mcap-support parseJsonSchema.ts): an object
    with ``properties``; each field an enum ``oneOf`` of numeric consts or a single ``type`` string among
    boolean/string/number/integer/object/array; array items a single type, objects recursively."""
    assert schema.get("type") == "object", f"{where}: expected type object, got {schema.get('type')!r}"
    assert isinstance(schema.get("properties"), dict), f"{where}: object without properties"
    for name, field in schema["properties"].items():
        w = f"{where}.{name}"
        if "oneOf" in field:
            assert all(isinstance(a.get("const"), (int, float)) for a in field["oneOf"]), w
            continue
        t = field.get("type")
        assert t in ("boolean", "string", "number", "integer", "object", "array"), f"{w}: type {t!r}"
        if t == "object":
            assert_foxglove_parsable(field, w)
        elif t == "array":
            it = field.get("items")
            assert isinstance(it, dict) and it.get("type") in ("boolean", "string", "number", "integer", "object"), w
            if it["type"] == "object":
                assert_foxglove_parsable(it, w + "[]")


def test_validator_rejects_wrong_payloads():
    """The hand-written check above must be able to fail, or the schema tests below prove nothing."""
    s = dataclass_schema(ImuSample)
    good = ImuSample(1.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0).to_dict()
    validate(good, s)
    for bad in (
        {**good, "imu_index": 1.5},
        {**good, "accel_frd_mps2": [0.0, 0.0]},
        {**good, "gyro_frd_radps": [0.0, "x", 0.0]},
        {k: v for k, v in good.items() if k != "t_s"},
        {**good, "extra": 1},
    ):
        with pytest.raises(AssertionError):
            validate(bad, s)


# ---------------------------------------------------------------------------- sample events


def _value(tp, variant: int, i: int):
    """A value of type ``tp``: variant 0 ordinary numbers, 1 None/NaN where allowed."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, __import__("types").UnionType):
        return None if variant == 1 else _value(next(a for a in args if a is not type(None)), variant, i)
    if tp is bool:
        return i % 2 == 0
    if tp is int:
        return 3 + i
    if tp is float:
        return math.nan if variant == 1 and i % 2 else 0.125 * (i + 1) - 7.0
    if tp is str:
        return f"text {i} \u00b0 \"quoted\""
    if origin is tuple:
        return tuple(_value(a, 0, i + k) for k, a in enumerate(args))
    raise TypeError(tp)


def sample(cls, variant: int = 0, t_s: float = 12.5):
    hints = typing.get_type_hints(cls)
    kw = {f.name: _value(hints[f.name], variant, i) for i, f in enumerate(dataclasses.fields(cls))}
    kw["t_s"] = t_s
    return cls(**kw)


# ---------------------------------------------------------------------------- schemas and payloads


@pytest.mark.parametrize("cls", EVENT_TYPES, ids=lambda c: c.__name__)
def test_event_schema_and_payloads(tmp_path, cls):
    schema = dataclass_schema(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    hints = typing.get_type_hints(cls)
    may_be_unknown = {n for n in names if n != "t_s" and (hints[n] is float or type(None) in typing.get_args(hints[n])
                                                          or float in typing.get_args(hints[n]))}
    assert schema["type"] == "object" and list(schema["properties"]) == names
    assert schema["required"] == [n for n in names if n not in may_be_unknown]
    assert schema["title"] == f"companion.events.{cls.__name__}"
    assert dataclass_schema(cls) is schema  # cached per class
    assert_foxglove_parsable(schema)
    evs = [sample(cls, 0, 1.0), sample(cls, 1, 2.0)]
    with Recorder(tmp_path / "a.mcap") as rec:
        for ev in evs:
            rec.write(ev)
    got = list(iter_payloads(tmp_path / "a.mcap"))
    assert [(t, ns) for t, ns, _ in got] == [(cls.topic, 1_000_000_000), (cls.topic, 2_000_000_000)]
    for ev, (_, _, data) in zip(evs, got):
        payload = json.loads(data)
        # the event's own to_dict() with its unknown values (None, NaN) left out, in orjson's compact encoding: the same
        # values; text as UTF-8, some floats spelt shorter (1e-7 for 1e-07): tests/record/test_fast_messages.py compares
        # whole replays value for value
        assert payload == drop_unknown(json.loads(json.dumps(ev.to_dict())))
        assert "null" not in data.decode() and b", " not in data
        validate_all(payload, schema)
    with open(tmp_path / "a.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    (sch,) = summary.schemas.values()
    (ch,) = summary.channels.values()
    assert (sch.name, sch.encoding, ch.message_encoding) == (schema["title"], "jsonschema", "json")
    assert json.loads(sch.data) == schema


def test_schema_type_mapping():
    imu = dataclass_schema(ImuSample)["properties"]
    num = {"type": "number"}  # one type per field: what Foxglove's reader takes; NaN is left out of the payload
    assert imu["accel_frd_mps2"] == {"type": "array", "items": num, "minItems": 3, "maxItems": 3}
    assert imu["imu_index"] == {"type": "integer"} and imu["t_s"] == num
    gnss_schema = dataclass_schema(GnssFix)
    gnss = gnss_schema["properties"]
    assert gnss["lat_deg"] == num and gnss["satellites"] == {"type": "integer"} and gnss["fix_type"] == {"type": "integer"}
    assert "lat_deg" not in gnss_schema["required"] and "satellites" not in gnss_schema["required"]
    assert "fix_type" in gnss_schema["required"] and "t_s" in gnss_schema["required"]
    assert dataclass_schema(StatusText)["properties"]["text"] == {"type": "string"}
    heartbeat = dataclass_schema(next(c for c in EVENT_TYPES if c.__name__ == "Heartbeat"))
    assert heartbeat["properties"]["armed"] == {"type": "boolean"}
    text = json.dumps(gnss_schema)
    assert "nullable" not in text and '"null"' not in text  # no non-standard keywords, no type lists


def test_unknown_values_are_left_out():
    assert drop_unknown({"a": 1.0, "b": None, "c": [1.0, None], "d": [1.0, 2.0], "e": {"x": None, "y": "s"}}) == {
        "a": 1.0, "d": [1.0, 2.0], "e": {"y": "s"}}
    assert drop_unknown([{"x": None}, {"x": 1}]) == [{}, {"x": 1}] and drop_unknown(None) is None
    fix = GnssFix(3.0, 1, None, None, None, None, None, None, None, None, 0, None, None, None, None, None, None, None)
    payload = drop_unknown(fix.to_dict())
    import jsonschema

    jsonschema.validate(payload, dataclass_schema(GnssFix), cls=jsonschema.Draft202012Validator)
    with pytest.raises(jsonschema.ValidationError):  # the schema still says what a known value must be
        jsonschema.validate({**payload, "lat_deg": "north"}, dataclass_schema(GnssFix),
                            cls=jsonschema.Draft202012Validator)
    with pytest.raises(jsonschema.ValidationError):  # and null is not a value
        jsonschema.validate({**payload, "lat_deg": None}, dataclass_schema(GnssFix), cls=jsonschema.Draft202012Validator)


@pytest.mark.parametrize("cls", EVENT_TYPES, ids=lambda c: c.__name__)
def test_schemas_are_standard(cls):
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(dataclass_schema(cls))


def test_foxglove_parsable_others():
    assert_foxglove_parsable(LOCATION_FIX_SCHEMA)  # the Map panel's topics


@dataclass(frozen=True)
class _Inner:
    x_m: float
    label: str


@dataclass(frozen=True)
class _FilterState:
    """A later pipeline step's output: nested dataclass, lists, optionals."""

    t_s: float
    state: list[float]
    cov_diag: tuple[float, ...]
    inner: _Inner
    best: _Inner | None
    gains: dict[str, float]
    ok: bool
    topic: ClassVar[str] = "/estimation/state"


def test_any_dataclass(tmp_path):
    schema = dataclass_schema(_FilterState)
    assert_foxglove_parsable(schema)
    assert schema["properties"]["inner"]["type"] == "object"
    assert schema["properties"]["best"]["type"] == "object" and "best" not in schema["required"]
    assert schema["properties"]["state"] == {"type": "array", "items": {"type": "number"}}
    assert schema["required"] == ["t_s", "inner", "gains", "ok"]
    items = [
        _FilterState(0.5, [1.0, math.nan], (0.1, 0.2, 0.3), _Inner(2.0, "a"), None, {"k": 1.0}, True),
        _FilterState(1.5, [np.float64(3.0)], (), _Inner(math.inf, "b"), _Inner(1.0, "c"), {"k": math.nan}, False),
    ]
    with Recorder(tmp_path / "s.mcap") as rec:
        for it in items:
            rec.write(it)
        rec.write(items[0], topic="/estimation/other")
        assert rec.counts == {"/estimation/state": 2, "/estimation/other": 1}
    payloads = [json.loads(d) for _, _, d in iter_payloads(tmp_path / "s.mcap")]
    for p in payloads:
        validate_all(p, schema)
    # an array holding an unknown value is left out whole; None and NaN fields are left out
    assert "state" not in payloads[0] and "best" not in payloads[0] and payloads[0]["inner"] == {"x_m": 2.0, "label": "a"}
    assert payloads[1]["inner"] == {"label": "b"} and payloads[1]["best"] == {"x_m": 1.0, "label": "c"}
    assert payloads[1]["state"] == [3.0] and payloads[1]["gains"] == {}


def test_unsupported_types_are_clear_errors(tmp_path):
    @dataclass(frozen=True)
    class NoTime:
        x: float
        topic: ClassVar[str] = "/x"

    @dataclass(frozen=True)
    class Weird:
        t_s: float
        blob: object

    with Recorder(tmp_path / "e.mcap") as rec:
        with pytest.raises(TypeError, match="t_s"):
            rec.write(NoTime(1.0))
        with pytest.raises(TypeError, match="blob"):
            rec.write(Weird(1.0, None), topic="/w")
        with pytest.raises(TypeError, match="not a dataclass"):
            rec.write({"t_s": 1.0}, topic="/d")
        with pytest.raises(ValueError, match="t_s"):
            rec.write(ImuSample(math.nan, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0))
        with pytest.raises(ValueError, match="negative"):
            rec.write(ImuSample(-1.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0))
        rec.write(sample(GnssFix))
        with pytest.raises(ValueError, match="already carries"):
            rec.write(sample(ImuSample), topic=GnssFix.topic)


def test_write_dict(tmp_path):
    schema = {"type": "object", "properties": {"n": {"type": "integer"}, "v": {"type": "number"}}}
    with Recorder(tmp_path / "d.mcap") as rec:
        rec.write_dict("/gps_input", "companion.GpsInputSent", schema, {"n": 1, "v": 2.5}, 3.0)
        rec.write_dict("/gps_input", "companion.GpsInputSent", schema, {"n": 2, "v": math.nan}, 3.2)
        with pytest.raises(ValueError, match="already carries"):
            rec.write_dict("/gps_input", "other.Name", schema, {"n": 3}, 3.3)
    got = list(iter_payloads(tmp_path / "d.mcap"))
    assert got == [("/gps_input", 3_000_000_000, b'{"n":1,"v":2.5}'), ("/gps_input", 3_200_000_000, b'{"n":2}')]  # NaN left out
    assert summarize(tmp_path / "d.mcap").topic("/gps_input").schema_name == "companion.GpsInputSent"


# ---------------------------------------------------------------------------- LocationFix


def test_location_fix_and_log_stamped_with_the_log_time_each_track_its_own_frame(tmp_path):
    """LocationFix and Log ``timestamp`` are the message's log time (UTC once the clock knows it, like the MCAP log
    time), not the boot time; every track's frame_id is its own."""
    from companion.record.clock import RecordClock
    from companion.record.schemas import LOG_SCHEMA, LOG_WARNING

    path = tmp_path / "utc.mcap"
    offset_ns = 1_742_002_200 * 10**9  # 2025-03-15T01:30:00Z at boot time 0
    with Recorder(path, clock=RecordClock(offset_ns, "test")) as rec:
        rec.write_location("/map/gnss", 100.25, 47.1, 8.5, 420.0)
        rec.write_location("/map/autopilot", 100.25, 47.1, 8.5, 420.0)
        rec.write_log("/log/autopilot", 101.5, LOG_WARNING, "PreArm: GPS 2: Bad fix", "autopilot")
    got = [(t, ns, json.loads(d)) for t, ns, d in iter_payloads(path)]
    for topic, ns, p in got:
        validate_all(p, LOG_SCHEMA if topic.startswith("/log") else LOCATION_FIX_SCHEMA)
        assert p["timestamp"]["sec"] * 10**9 + p["timestamp"]["nsec"] == ns  # the log time, in UTC
    assert got[0][1] == offset_ns + 100_250_000_000
    assert [p["frame_id"] for _, _, p in got[:2]] == ["gnss", "autopilot"]
    assert got[2][2] == {"timestamp": {"sec": 1_742_002_301, "nsec": 500_000_000}, "level": LOG_WARNING,
                         "message": "PreArm: GPS 2: Bad fix", "name": "autopilot", "file": "", "line": 0}
    assert summarize(path).topic("/log/autopilot").schema_name == "foxglove.Log"


def test_location_fix(tmp_path):
    path = tmp_path / "loc.mcap"
    with Recorder(path) as rec:
        rec.write_location("/map/gnss", 100.25, 47.1, 8.5, 420.0, [[4.0, 0, 0], [0, 4.0, 0], [0, 0, 9.0]])
        rec.write_location("/map/fused", 100.3, 47.2, 8.6, 421.0, np.array([[1.0, 0.5, 0], [0.5, 2.0, 0], [0, 0, 3.0]]),
                           frame_id="fused", color_rgba=(1, 0, 0, 1), heading_rad=0.5)
        rec.write_location("/map/gnss", 101.0, 47.3, 8.7, 422.0, None)
        with pytest.raises(ValueError, match="non-finite"):
            rec.write_location("/map/gnss", 102.0, math.nan, 8.7, 422.0)
        with pytest.raises(ValueError, match="3x3"):
            rec.write_location("/map/gnss", 102.0, 47.0, 8.7, 422.0, [1.0, 2.0])
    got = [(t, ns, json.loads(d)) for t, ns, d in iter_payloads(path)]
    for _, _, p in got:
        validate_all(p, LOCATION_FIX_SCHEMA)
    (t0, ns0, p0), (t1, _, p1), (t2, _, p2) = got
    assert t0 == "/map/gnss" and ns0 == 100_250_000_000
    assert p0["timestamp"] == {"sec": 100, "nsec": 250_000_000}
    assert (p0["latitude"], p0["longitude"], p0["altitude"], p0["frame_id"]) == (47.1, 8.5, 420.0, "gnss")
    assert p0["position_covariance"] == [4.0, 0, 0, 0, 4.0, 0, 0, 0, 9.0] and p0["position_covariance_type"] == 2
    assert p1["position_covariance_type"] == 3 and p1["color"] == {"r": 1.0, "g": 0.0, "b": 0.0, "a": 1.0}
    assert p1["heading"] == 0.5 and p1["frame_id"] == "fused"
    assert p2["position_covariance"] == [0.0] * 9 and p2["position_covariance_type"] == 0
    s = summarize(path)
    assert {t.topic: (t.schema_name, t.count) for t in s.topics} == {
        "/map/gnss": (LOCATION_FIX_SCHEMA_NAME, 2),
        "/map/fused": (LOCATION_FIX_SCHEMA_NAME, 1),
    }
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert [(x.name, x.encoding) for x in summary.schemas.values()] == [("foxglove.LocationFix", "jsonschema")]


# ---------------------------------------------------------------------------- determinism, finalising


def _events(n: int, rate_hz: float = 1000.0, start_s: float = 0.0):
    """IMU at rate_hz with a GNSS fix every 100 samples and a status text every 1000."""
    out = []
    for i in range(n):
        t = start_s + i / rate_hz
        out.append(ImuSample(t, (0.001 * i, -0.02, -9.81), (1e-4 * (i % 7), 0.0, math.nan if i % 500 == 3 else 0.0), i % 2))
        if i % 100 == 0:
            out.append(sample(GnssFix, i % 200 == 0, t_s=t))
        if i % 1000 == 0:
            out.append(StatusText(t, 6, f"at {i}"))
    return out


def _write(path, events, **kw):
    with Recorder(path, **kw) as rec:
        rec.add_metadata("source", {"kind": "test", "n": str(len(events))})
        for ev in events:
            rec.write(ev)
            if isinstance(ev, GnssFix) and ev.has_position:
                rec.write_location("/map/gnss", ev.t_s, ev.lat_deg, ev.lon_deg, ev.alt_msl_m)
        return rec.counts


def test_deterministic_bytes(tmp_path):
    evs = _events(3000)
    _write(tmp_path / "a.mcap", evs)
    _write(tmp_path / "b.mcap", list(evs))
    a, b = list(iter_payloads(tmp_path / "a.mcap")), list(iter_payloads(tmp_path / "b.mcap"))
    assert len(a) == len(evs) + sum(isinstance(e, GnssFix) and e.has_position for e in evs) and a == b
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


def test_finalised_file(tmp_path):
    path = tmp_path / "f.mcap"
    evs = _events(4500)
    counts = _write(path, evs, chunk_size=16 * 1024)
    with Recorder(tmp_path / "g.mcap") as rec:
        rec.close()
        rec.close()  # idempotent
        with pytest.raises(RecordError, match="closed"):
            rec.write(evs[0])
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == sum(counts.values())
        msgs = list(reader.iter_messages(log_time_order=False))
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    imu = [e for e in evs if isinstance(e, ImuSample)]
    imu_msgs = [m for _, c, m in msgs if c.topic == "/input/imu"]
    assert [m.log_time for m in imu_msgs] == [round(e.t_s * 1e9) for e in imu]
    assert all(m.publish_time == m.log_time for _, _, m in msgs)
    import companion

    assert meta["companion"]["version"] == companion.__version__ and meta["source"]["kind"] == "test"
    s = summarize(path)
    assert s.finalised and not s.recovered and s.message_count == len(msgs) and s.chunk_count > 4
    by_topic: dict[str, list[int]] = {}
    for _, c, m in msgs:
        by_topic.setdefault(c.topic, []).append(m.log_time)
    assert {t.topic: (t.count, t.first_ns, t.last_ns) for t in s.topics} == {
        k: (len(v), min(v), max(v)) for k, v in by_topic.items()
    }
    assert s.topic("/input/imu").rate_hz == pytest.approx(1000.0)
    assert s.start_ns == 0 and s.end_ns == round(4499 / 1000 * 1e9)
    assert s.metadata_dict("source") == {"kind": "test", "n": str(len(evs))}
    text = format_summary(s)
    assert "/input/imu" in text and "companion.events.ImuSample" in text and "4500" in text and "finalised" in text


def test_chunks_close_by_message_time_and_size(tmp_path):
    path = tmp_path / "c.mcap"
    rec = Recorder(path, flush_interval_s=1.0)
    rec.add_metadata("source", {"kind": "live"})
    # Header and metadata reach the OS at once (unbuffered file), before any chunk is written.
    early = summarize(path)
    assert early.recovered and early.message_count == 0 and early.metadata_dict("source") == {"kind": "live"}
    for i in range(250):  # 100 Hz for 2.5 s
        rec.write(ImuSample(i / 100, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0))
    # Still open: closed chunks are in the file already. A chunk closes on the first message >= 1 s after
    # its first one: [0, 1.00] and [1.01, 2.01] -> 202 messages readable, the rest in the open chunk.
    live = summarize(path)
    assert live.recovered and live.message_count == 202 and live.topic("/input/imu").last_ns == 2_010_000_000
    rec.flush()
    assert summarize(path).message_count == 250
    rec.close()
    assert summarize(path).finalised

    small = tmp_path / "small.mcap"
    with Recorder(small, chunk_size=4096, flush_interval_s=1e6, compression="none") as rec:
        for ev in _events(2000):
            rec.write(ev)
    with open(small, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) > 10 and max(c.uncompressed_size for c in chunks) < 4096 + 1024


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_other_compressions(tmp_path, compression):
    evs = _events(1500)
    _write(tmp_path / "x.mcap", evs, compression=compression)
    _write(tmp_path / "z.mcap", evs)
    assert list(iter_payloads(tmp_path / "x.mcap")) == list(iter_payloads(tmp_path / "z.mcap"))
    with pytest.raises(ValueError, match="compression"):
        Recorder(tmp_path / "q.mcap", compression="gzip")


# ---------------------------------------------------------------------------- bad and damaged files


def test_bad_files_raise_record_error(tmp_path):
    (tmp_path / "empty.mcap").write_bytes(b"")
    (tmp_path / "random.mcap").write_bytes(np.random.default_rng(7).bytes(5000))
    (tmp_path / "text.mcap").write_text("this is a text file, not a record\n" * 20)
    (tmp_path / "dir.mcap").mkdir()
    for name, msg in [("empty", "empty"), ("random", "not an MCAP"), ("text", "not an MCAP"), ("missing", "no such"),
                      ("dir", "directory")]:
        with pytest.raises(RecordError, match=msg):
            summarize(tmp_path / f"{name}.mcap")
        with pytest.raises(RecordError, match=msg):
            list(iter_payloads(tmp_path / f"{name}.mcap"))


def test_every_truncation_is_read_without_error(tmp_path):
    """Cut a finalised file at many lengths: never a traceback, counts grow with length, payloads are a prefix."""
    path = tmp_path / "full.mcap"
    _write(path, _events(600), flush_interval_s=0.1)
    full = path.read_bytes()
    payloads = list(iter_payloads(path))
    cut = tmp_path / "cut.mcap"
    last = -1
    for n in list(range(0, len(full), max(1, len(full) // 150))) + [len(full) - 1]:
        cut.write_bytes(full[:n])
        if n < 8:
            with pytest.raises(RecordError):
                summarize(cut)
            continue
        s = summarize(cut)
        assert s.recovered and s.message_count >= last
        last = s.message_count
        assert list(iter_payloads(cut)) == payloads[: s.message_count]
        assert "RECOVERED" in format_summary(s)
    assert last > 0.9 * len(payloads)
    # garbage after a truncated write (e.g. zero-filled blocks after a power cut) is also tolerated
    cut.write_bytes(full[: len(full) // 2] + b"\0" * 4096)
    assert summarize(cut).recovered
    cut.write_bytes(full[: len(full) // 2] + np.random.default_rng(1).bytes(4096))
    assert summarize(cut).message_count <= len(payloads)


# ---------------------------------------------------------------------------- real processes and signals

WRITER = textwrap.dedent(
    """
    import asyncio, signal, sys, time
    from companion.events import ImuSample
    from companion.record import Recorder

    path, mode, stop_at = sys.argv[1], sys.argv[2], int(sys.argv[3])

    def ev(i):
        return ImuSample(i / 1000, (0.001 * i, 0.0, -9.81), (0.0, 0.0, 0.0), 0)

    async def main():
        rec = Recorder(path, flush_interval_s=1.0)
        i = 0
        try:
            while True:
                if i < stop_at:
                    for _ in range(100):
                        rec.write(ev(i))
                        i += 1
                    print(i, flush=True)
                await asyncio.sleep(0.02)
        finally:  # as the CLI does: cancellation by SIGTERM/SIGINT lands here
            rec.add_metadata("stop", {"written": str(i)})
            rec.close()
            rec.close()

    loop = asyncio.new_event_loop()
    task = loop.create_task(main())
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, task.cancel)
    try:
        loop.run_until_complete(task)
    except asyncio.CancelledError:
        pass
    """
)


def _spawn(tmp_path, mode: str, stop_at: int):
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    path = tmp_path / f"{mode}.mcap"
    proc = subprocess.Popen(
        [sys.executable, str(script), str(path), mode, str(stop_at)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=REPO,
    )
    return proc, path


def _wait_for_count(proc, n: int) -> int:
    while True:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError(f"writer exited early: {proc.wait()} {proc.stderr.read()}")
        if int(line) >= n:
            return int(line)


def test_normal_end_in_subprocess(tmp_path):
    proc, path = _spawn(tmp_path, "normal", 1500)
    _wait_for_count(proc, 1500)
    proc.send_signal(signal.SIGTERM)  # the loop idles after stop_at; a cancel ends it normally
    assert proc.wait(timeout=20) == 0, proc.stderr.read()
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        assert sum(1 for _ in reader.iter_messages()) == 1500


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_finalises(tmp_path, sig):
    proc, path = _spawn(tmp_path, sig.name, 10**9)  # keeps writing until signalled
    _wait_for_count(proc, 2500)
    proc.send_signal(sig)
    assert proc.wait(timeout=20) == 0, proc.stderr.read()
    with open(path, "rb") as f:
        assert make_reader(f).get_summary() is not None
    s = summarize(path)
    written = int(s.metadata_dict("stop")["written"])
    assert s.finalised and written >= 2500
    assert s.topic("/input/imu").count == written  # the open chunk was written too
    assert s.topic("/input/imu").last_ns == round((written - 1) / 1000 * 1e9)


def test_sigkill_recovers_closed_chunks(tmp_path):
    proc, path = _spawn(tmp_path, "kill", 5000)  # 5 s of 1 kHz message time, then idles unclosed
    seen = _wait_for_count(proc, 3500)
    proc.kill()
    proc.wait(timeout=20)
    rest = proc.stdout.read().split()
    reported = int(rest[-1]) if rest else seen  # lower bound on what was written before the kill
    # Chunk boundaries by the recorder's rule: a chunk closes on the first message >= 1 s after its first.
    boundaries, t0 = [], None
    for i in range(5000):
        t = round(i / 1000 * 1e9)
        t0 = t if t0 is None else t0
        if t - t0 >= 1_000_000_000:
            boundaries.append(i + 1)
            t0 = None
    s = summarize(path)
    assert s.recovered and not s.finalised
    n = s.topic("/input/imu").count
    assert n in boundaries and n >= max(b for b in boundaries if b <= 3500)
    assert n >= reported - 1001  # at most the open chunk (< 1 s of message time) was lost
    assert s.metadata_dict("companion") is not None
    expected = [
        json.dumps(ImuSample(i / 1000, (0.001 * i, 0.0, -9.81), (0.0, 0.0, 0.0), 0).to_dict(), separators=(",", ":")).encode()
        for i in range(n)
    ]
    assert [d for _, _, d in iter_payloads(path)] == expected
    assert "RECOVERED" in format_summary(s)


def test_close_from_signal_handler_during_write(tmp_path):
    """A Python signal handler may call close() in the middle of a write: the write completes, then the file is finalised."""
    old = signal.getsignal(signal.SIGALRM)
    try:
        for k in range(6):
            path = tmp_path / f"alarm{k}.mcap"
            rec = Recorder(path, chunk_size=2048)
            rec.write(ImuSample(0.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0))  # the timer starts after a first write
            written = 1
            signal.signal(signal.SIGALRM, lambda *_: rec.close())
            signal.setitimer(signal.ITIMER_REAL, 0.01 + 0.007 * k)
            with pytest.raises(RecordError, match="closed"):
                while written < 10**7:
                    rec.write(ImuSample(written / 1000, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0))
                    written += 1
            s = summarize(path)
            assert s.finalised and s.message_count == written > 0
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_rotating_recorder_segments_are_complete_and_carry_metadata(tmp_path):
    from companion.events import Attitude
    from companion.record import RotatingRecorder, iter_payloads, summarize

    rec = RotatingRecorder(tmp_path / "live.mcap", segment_s=10.0)
    rec.add_metadata("source", {"kind": "live"})
    n = 0
    for k in range(350):  # 35 s of message time at 10 Hz -> 4 segments
        rec.write(Attitude(t_s=100.0 + k * 0.1, roll_rad=0.0, pitch_rad=0.0, yaw_rad=float(k)))
        n += 1
    rec.write_location("/map/x", 134.95, 1.0, 2.0, 3.0)
    rec.add_metadata("summary", {"json": "{}"})
    rec.close()
    rec.close()  # idempotent
    assert [p.name for p in rec.paths] == [f"live-{i:03d}.mcap" for i in range(4)]
    total = 0
    for i, p in enumerate(rec.paths):
        s = summarize(p)
        assert s.finalised and dict(s.metadata)["source"] == {"kind": "live"}
        assert s.span_s < 10.0
        total += s.topic("/input/attitude").count
    assert total == n and rec.counts["/input/attitude"] == n and rec.counts["/map/x"] == 1
    assert "summary" in dict(summarize(rec.paths[-1]).metadata)
    yaws = [json.loads(b)["yaw_rad"] for p in rec.paths for _, _, b in iter_payloads(p, "/input/attitude")]
    assert yaws == [float(k) for k in range(350)]  # nothing lost or duplicated across segments
