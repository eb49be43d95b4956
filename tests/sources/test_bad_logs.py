"""Damaged logs: every defect is dropped and counted, reading goes on, the record is finalised, exit 3 -- never a
traceback, never pymavlink's own lines on stderr."""

from __future__ import annotations

import subprocess
import sys

import pytest

from companion.events import ImuSample
from companion.sources.files import open_reader
from replay.fuzz.logs import DataflashLog, Tlog
from tests.conftest import LOG171, LOG_AC402, SAMPLE_LOG, require

CUT = 400_000


def _read(path):
    r = open_reader(path)
    evs = []
    while True:
        b = r.read_batch(5000)
        if not b:
            break
        evs += b
    return evs, r.info.warnings


def _replay(path, out):
    p = subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(path), "--out", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=120)
    return p.returncode, p.stderr


def _log(path=LOG171, size=CUT) -> tuple[DataflashLog, bytearray]:
    data = require(path).read_bytes()[:size]
    return DataflashLog(data), bytearray(data)


def _mid(log: DataflashLog, name: str):
    idx = log.records_named([name])
    return log.records[idx[len(idx) // 2]]


def test_one_bad_record_type_byte_skips_that_record_and_reads_on(tmp_path):
    log, buf = _log()
    clean, _ = _read(_write(tmp_path / "clean.bin", buf))
    unknown = next(t for t in range(256) if t not in log.formats)
    rec = _mid(log, "IMU")
    buf[rec.offset + 2] = unknown
    path = _write(tmp_path / "bad.bin", buf)
    evs, warnings = _read(path)
    assert len(evs) >= 0.98 * len(clean)  # before: everything after the bad byte was gone
    assert any(w.startswith("skipped") and "next record" in w for w in warnings)
    code, err = _replay(path, tmp_path / "bad.mcap")
    # nothing of pymavlink's own on stderr: only the damage, as our warnings (-q: no summary)
    assert code == 3 and all(" WARNING companion.replay: " in line for line in err.splitlines()), err


def test_renamed_fmt_columns_and_a_non_physical_imu_value_are_dropped_and_counted(tmp_path):
    log, buf = _log()
    imu_fmt = next(f for f in log.formats.values() if f.name == "IMU")
    col_off = buf.find(b"AccX", imu_fmt.offset, imu_fmt.offset + 89)
    buf[col_off:col_off + 4] = b"AccQ"  # renamed column: no AccX any more
    path = _write(tmp_path / "renamed.bin", buf)
    evs, warnings = _read(path)
    assert not [e for e in evs if isinstance(e, ImuSample) and e.imu_index == 0]
    assert any("IMU without its time or axes" in w for w in warnings)
    log, buf = _log()
    rec = _mid(log, "IMU")
    log.put(buf, rec, "AccX", 1e22)
    evs, warnings = _read(_write(tmp_path / "huge.bin", buf))
    assert all(abs(e.accel_frd_mps2[0]) < 1000 for e in evs if isinstance(e, ImuSample))
    assert any("non-physical" in w for w in warnings)
    code, err = _replay(tmp_path / "huge.bin", tmp_path / "huge.mcap")
    assert code in (0, 3) and "Traceback" not in err


def test_a_time_beyond_2_64_ns_is_dropped_and_the_record_finalised(tmp_path):
    from companion.record import summarize

    log, buf = _log(LOG_AC402, 300_000)
    rec = _mid(log, next(n for n in ("IMU", "ATT", "GPS") if log.records_named([n])))
    col = log.fmt(rec).time_column()
    log.put(buf, rec, col, 2**63 if col == "TimeUS" else 2**31)
    path = _write(tmp_path / "late.bin", buf)
    code, err = _replay(path, tmp_path / "late.mcap")
    assert code in (0, 3) and "Traceback" not in err and "struct.error" not in err, err
    assert summarize(tmp_path / "late.mcap").finalised


def test_tlog_cut_mid_frame_exits_3(tmp_path):
    data = SAMPLE_LOG.read_bytes()
    t = Tlog(data[:200_000])
    f = t.frames[len(t.frames) // 2]
    path = _write(tmp_path / "cut.tlog", data[: f.start + 5])
    _, warnings = _read(path)
    assert any(w.startswith("truncated") for w in warnings)
    code, err = _replay(path, tmp_path / "cut.mcap")
    assert code == 3, err


def _write(path, data):
    path.write_bytes(bytes(data))
    return path


def test_dataflash_cut_mid_record_is_truncated(tmp_path):
    log, buf = _log(LOG_AC402, 100_000)
    rec = log.records[-5]
    _, warnings = _read(_write(tmp_path / "cut.bin", buf[: rec.offset + 5]))
    assert any(w.startswith("truncated") for w in warnings)
