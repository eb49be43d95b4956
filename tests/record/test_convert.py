"""`companion convert`: every message of every shared log into MCAP with its schema; counts per type equal pymavlink's,
every payload valid against its schema in the shape Foxglove reads, log times in UTC; a stop finalises the record."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter

import pytest

from companion.record import iter_payloads, summarize
from companion.record.convert import convert_log
from tests.conftest import LOG171, LOG_AC402, LOG_TLOG, REAL_LOGS, require
from tests.record.test_record import assert_foxglove_parsable, validate_all

#: payloads validated per topic (jsonschema is slow; the schemas are the same for every message of a topic)
VALIDATED_PER_TOPIC = 50


def _pymavlink_counts(log) -> Counter:
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(str(log))
    counts: Counter = Counter()
    while (msg := m.recv_msg()) is not None:
        counts[msg.get_type()] += 1
    m.close()
    counts.pop("BAD_DATA", None)  # corrupt frames: counted in a warning, not converted
    return counts


@pytest.mark.parametrize("log", REAL_LOGS, ids=lambda p: p.stem[:24])
def test_every_message_of_every_shared_log(log, tmp_path):
    out = tmp_path / "all.mcap"
    res = subprocess.run([sys.executable, "-m", "companion.cli", "convert", str(require(log)), "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert "Traceback" not in res.stderr, res.stderr
    assert res.returncode == (3 if log == LOG_AC402 else 0), res.stdout + res.stderr  # AC 4.0.2: a cut last record
    s = summarize(out)
    assert s.finalised
    prefix = "/mavlink/" if log == LOG_TLOG else "/dataflash/"
    got = {t.topic.removeprefix(prefix): t.count for t in s.topics}
    assert got == dict(_pymavlink_counts(log))
    assert dict(s.metadata)["source"]["messages"] == str(sum(got.values()))
    seen: Counter = Counter()
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if seen[channel.topic] >= VALIDATED_PER_TOPIC:
                continue
            seen[channel.topic] += 1
            js = json.loads(schema.data)
            if seen[channel.topic] == 1:
                assert_foxglove_parsable(js, channel.topic)
            validate_all(json.loads(message.data), js)
            assert message.log_time > 1_400_000_000 * 10**9  # UTC (GPS time, or the tlog's own stamps)
    assert set(seen) == {t.topic for t in s.topics}


def test_dataflash_times_are_the_replays_utc(tmp_path):
    """A .bin's log times are the replay's: the same UTC for the same boot time (its GPS rows carry both)."""
    out = tmp_path / "all.mcap"
    convert_log(require(LOG171), out)
    from companion.sources.files import read_events
    from companion.record.clock import find_utc_offset

    offset_ns = find_utc_offset(LOG171)[0]
    imu_t = [e.t_s for e in read_events(LOG171) if type(e).__name__ == "ImuSample" and e.imu_index == 0][:100]
    conv_t = [ns for _t, ns, _d in iter_payloads(out, "/dataflash/IMU")][:100]
    assert conv_t == [round(t * 1e9) + offset_ns for t in imu_t]


def test_a_stop_finalises_the_record_with_what_was_read(tmp_path):
    out = tmp_path / "stopped.mcap"
    asked = [0]

    def stop():
        asked[0] += 1
        return "SIGTERM" if asked[0] > 5000 else None

    conv = convert_log(require(LOG171), out, stop_requested=stop)
    assert conv.stopped_by == "SIGTERM" and conv.messages == 5000
    s = summarize(out)
    assert s.finalised and sum(t.count for t in s.topics) == 5000
    assert dict(s.metadata)["source"]["stopped_by"] == "SIGTERM"


def test_not_a_log_is_one_line_and_no_output(tmp_path):
    bad = tmp_path / "x.bin"
    bad.write_bytes(b"hello\n" * 100)
    res = subprocess.run([sys.executable, "-m", "companion.cli", "convert", str(bad), "--out", str(tmp_path / "o.mcap")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and res.stderr.startswith("companion: error:") and res.stderr.count("\n") == 1
    assert not (tmp_path / "o.mcap").exists()
