"""A replayed real log opens with its real UTC date in independent readers; every message validates
against the JSON schema embedded in the record (standard ``jsonschema``), and every schema has the shape
Foxglove's JSON-schema reader takes (one type per field: see companion.record.schemas)."""

from __future__ import annotations

import calendar
import datetime
import json

import pytest
from mcap.reader import make_reader

from companion.cli import main
from companion.record.clock import RecordClock, gps_minus_utc_s, gps_to_unix_s
from tests.conftest import LOG_ERLE, require
from tests.record.test_record import assert_foxglove_parsable


def test_leap_seconds_by_date():
    assert gps_minus_utc_s(calendar.timegm((2014, 11, 6, 0, 0, 0))) == 16
    assert gps_minus_utc_s(calendar.timegm((2016, 1, 1, 0, 0, 0))) == 17
    assert gps_minus_utc_s(calendar.timegm((2020, 3, 3, 0, 0, 0))) == 18
    # GPS week 2095, 1 s into it: 2020-03-01 00:00:01 GPS = 2020-02-29 23:59:43 UTC
    assert gps_to_unix_s(2095, 1.0) == calendar.timegm((2020, 2, 29, 23, 59, 43))


def test_clock_before_and_after_utc():
    from companion.events import SystemTime

    c = RecordClock()
    assert c.log_ns(5_000) == 5_000  # boot time until the UTC is known
    c.observe(SystemTime(t_s=10.0, unix_time_s=1_600_000_000.0))
    assert c.log_ns(11 * 10**9) == 1_600_000_001 * 10**9
    c.observe(SystemTime(t_s=10.0, unix_time_s=1_700_000_000.0))  # taken once: deterministic
    assert c.log_ns(11 * 10**9) == 1_600_000_001 * 10**9
    assert c.metadata()["log_time"].startswith("UTC") and "1 earlier" in c.metadata()["before_utc"]
    live = RecordClock(host_fallback=True)
    assert live.log_ns(0) > 1_600_000_000 * 10**9  # link events before any vehicle time: host UTC, not 0
    live.observe(SystemTime(t_s=10.0, unix_time_s=1_600_000_000.0))  # a vehicle clock far from the host's
    assert live.host_minus_vehicle_s > 10**7 and float(live.metadata()["host_clock_minus_vehicle_utc_s"]) > 10**7


def _log_times(path):
    with open(path, "rb") as f:
        return [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]


def test_a_live_record_never_mixes_clocks(tmp_path):
    """Link events and samples before the vehicle's UTC is known are held and written in UTC with the rest (the host's
    clock, a Raspberry Pi's before NTP or a 2025 simulator's against today, is not in the record)."""
    from companion.events import ImuSample, SystemTime
    from companion.mavlink.link import LinkStatus
    from companion.record import Recorder
    from companion.record.clock import UtcHold

    clock = RecordClock()
    rec = UtcHold(Recorder(tmp_path / "live.mcap", clock=clock), clock)
    rec.write(LinkStatus(0.0, "opened", "tcp:x"))  # before any vehicle message: t_s 0
    for k in range(300):  # 3 s of IMU before the first SYSTEM_TIME
        rec.write(ImuSample(t_s=20.0 + 0.01 * k, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0))
    rec.write(SystemTime(t_s=23.0, unix_time_s=1_750_000_000.0))
    rec.write(ImuSample(t_s=23.01, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0))
    rec.close()
    times = _log_times(tmp_path / "live.mcap")
    assert len(times) == 303
    assert max(times) - min(times) == round(23.01 * 1e9)  # the vehicle's own span: one clock (UTC)
    assert min(times) == (1_750_000_000 - 23) * 10**9  # the link event at its vehicle time, in UTC
    assert clock.metadata()["log_time"].startswith("UTC")


def test_a_live_record_without_vehicle_utc_is_in_boot_time_throughout(tmp_path):
    from companion.events import ImuSample, SystemTime
    from companion.record import Recorder
    from companion.record.clock import UtcHold

    clock = RecordClock()
    rec = UtcHold(Recorder(tmp_path / "live.mcap", clock=clock), clock, hold_s=5.0)
    for k in range(1000):  # 10 s without GPS time or SYSTEM_TIME, then it comes: too late to change the clock
        rec.write(ImuSample(t_s=20.0 + 0.01 * k, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0))
    rec.write(SystemTime(t_s=30.0, unix_time_s=1_750_000_000.0))
    rec.close()
    times = _log_times(tmp_path / "live.mcap")
    assert min(times) == 20 * 10**9 and max(times) == 30 * 10**9  # boot time, every message
    assert clock.metadata()["log_time"].startswith("vehicle boot time ns (the vehicle's UTC was not known within 5")


@pytest.fixture(scope="module")
def erle_record(tmp_path_factory):
    log = require(LOG_ERLE)
    out = tmp_path_factory.mktemp("utc") / "erle.mcap"
    assert main(["replay", "--quiet", "--out", str(out), str(log)]) in (0, 3)
    return out


def test_replayed_log_has_its_utc_date(erle_record, capsys):
    with open(erle_record, "rb") as f:
        stats = make_reader(f).get_summary().statistics
    start = datetime.datetime.fromtimestamp(stats.message_start_time / 1e9, datetime.timezone.utc)
    assert start.date() == datetime.date(2014, 11, 6), start  # the flight's day (from its GPS week/time)
    assert stats.message_end_time - stats.message_start_time < 200 * 10**9
    capsys.readouterr()
    assert main(["inspect", str(erle_record)]) == 0
    text = capsys.readouterr().out
    assert "span      2014-11-06T" in text and "log_time = UTC, Unix epoch ns" in text


def test_every_message_validates_against_its_schema(erle_record):
    import jsonschema

    validators, n = {}, 0
    with open(erle_record, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            v = validators.get(schema.id)
            if v is None:
                s = json.loads(schema.data)
                jsonschema.Draft202012Validator.check_schema(s)
                assert_foxglove_parsable(s, channel.topic)
                v = validators[schema.id] = jsonschema.Draft202012Validator(s)
            payload = json.loads(message.data)
            errors = list(v.iter_errors(payload))
            assert not errors, f"{channel.topic}: {errors[0].message}"
            assert not _has_null(payload), f"{channel.topic}: a null value (unknowns are left out)"
            n += 1
    assert n > 1000 and len(validators) >= 5


def _has_null(v) -> bool:
    if isinstance(v, dict):
        return any(_has_null(x) for x in v.values())
    if isinstance(v, list):
        return any(_has_null(x) for x in v)
    return v is None


def test_utc_offset_keeps_the_whole_microsecond():
    from companion.events import SystemTime

    c = RecordClock()
    c.observe(SystemTime(t_s=0.123, unix_time_s=1_742_002_200.123))  # boot at 2025-03-15T01:30:00Z, to the us
    assert c.log_ns(0) == 1_742_002_200 * 10**9
