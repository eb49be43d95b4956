"""Reproducers: damaged logs through `companion replay` (and the records it writes through `companion inspect`).

Each test pins one failure of the fault-tolerance requirements on a minimal input built from a shared real log
with replay/fuzz (a record's time moved, a FMT field changed, two logs end to end, ...). The ones that fail today
are xfail(strict): they must start passing with the fix (and then lose the mark).
"""

from __future__ import annotations

import hashlib
import os
import time

import pytest

from replay.fuzz.mutate import TWO64_NS_AS_US, _put_fmt
from replay.fuzz.properties import check_mcap
from tests.fuzz.conftest import one_line_error, replay_bytes, run_cli


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _moved(clean_input, name: str, seconds: float, *, rest: bool = False, frac: float = 0.5) -> bytes:
    """``clean_input`` with the boot time of one ``name`` record (or of every timed record from it on) + ``seconds``."""
    log = clean_input.parsed()
    ks = log.records_named([name])
    k0 = ks[int(frac * len(ks))]
    buf = bytearray(clean_input.data)
    r0 = log.records[k0]
    targets = [k for k in log.timed() if k >= k0] if rest else [k0]
    for k in targets:
        r = log.records[k]
        col = log.fmt(r).time_column()
        v = log.get(r, col)
        if col == "T" and v == 0:
            continue
        log.put(buf, r, col, v + int(round(seconds / log.time_scale_s(r))))
    assert log.get(r0, log.fmt(r0).time_column(), bytes(buf)) != log.get(r0, log.fmt(r0).time_column())
    return bytes(buf)


def _events(stdout: str) -> dict[str, int]:
    """Event counts of a replay summary ("  ImuSample[0]   574")."""
    out = {}
    for line in stdout.splitlines():
        parts = line.split()
        if len(parts) == 2 and line.startswith("  ") and parts[1].isdigit():
            out[parts[0]] = int(parts[1])
    return out


# ----------------------------------------------------------------------------------------------- time
def test_forward_time_jump_bounded_work(clean, tmp_path):
    c = clean["ac33dev-inflight-gps-loss@45%"]
    t0 = time.monotonic()
    ok, _, _ = replay_bytes(tmp_path, c.data, name="clean")
    clean_s = time.monotonic() - t0
    assert ok.returncode == 0
    limit = 3 * clean_s + 10
    try:
        res, _, out = replay_bytes(tmp_path, _moved(c, "IMU", 1e5), name="jump", timeout=limit)
    except Exception as exc:  # subprocess.TimeoutExpired: the work is not bounded
        raise AssertionError(f"replay of a log with one record 1e5 s ahead still running after {limit:.0f} s "
                             f"(clean: {clean_s:.1f} s)") from exc
    assert res.returncode in (0, 3) and not check_mcap(out)


def test_single_future_record_is_an_outlier_not_a_reboot_or_gap(clean, tmp_path):
    c = clean["ac33dev-log171@45%"]
    ref, _, _ = replay_bytes(tmp_path, c.data, name="clean")
    res, _, _ = replay_bytes(tmp_path, _moved(c, "IMU", 1e3), name="future")
    assert ref.returncode == 0 and "gaps         0" in ref.stdout
    assert "Reboot" not in _events(res.stdout), res.stdout
    assert "gaps         0" in res.stdout, res.stdout  # no false gap
    dur = [line for line in res.stdout.splitlines() if line.startswith("duration")]
    assert dur and dur[0] == [x for x in ref.stdout.splitlines() if x.startswith("duration")][0], dur


def test_time_beyond_2_64_ns_no_traceback(clean, tmp_path):
    c = clean["ac402-no-imu@0%"]  # AC 4.0: 64-bit TimeUS
    log = c.parsed()
    k = log.records_named(["GPS"])[len(log.records_named(["GPS"])) // 2]
    buf = bytearray(c.data)
    log.put(buf, log.records[k], "TimeUS", TWO64_NS_AS_US)
    res, _, out = replay_bytes(tmp_path, bytes(buf))
    assert "Traceback" not in res.stderr, res.stderr[-800:]
    assert res.returncode in (0, 3) and not check_mcap(out)


# ----------------------------------------------------------------------------------------------- formats
def _fmt_of(c, name):
    log = c.parsed()
    return next(f for f in log.formats.values() if f.name == name)


def test_renamed_fmt_column_no_traceback(clean, tmp_path):
    c = clean["ac33dev-inflight-gps-loss@45%"]
    f = _fmt_of(c, "IMU")
    buf = bytearray(c.data)
    _put_fmt(buf, f.offset, cols=",".join(f.columns).replace("GyrY", "Gyr1").encode())
    res, _, out = replay_bytes(tmp_path, bytes(buf))
    assert "Traceback" not in res.stderr, res.stderr[-800:]
    assert res.returncode in (2, 3), res.returncode  # the IMU rows cannot be decoded: damaged, and said so
    assert res.returncode == 2 or not check_mcap(out)


@pytest.mark.parametrize("name", ["IMU", "ATT"])
@pytest.mark.parametrize("length", [0, 2, 3, 4])
def test_header_only_fmt_then_a_record_is_a_clean_exit_3(clean, tmp_path, name, length):
    """An FMT redefining IMU or ATT with an empty Format and Columns and Length 0-4, then a record of that type (its
    header): Length 3 was an IndexError in the decoder (exit 1); 0-2 and 4 already exited 3."""
    from replay.fuzz.logs import FMT_BODY, FMT_TYPE

    c = clean["ac313-joeydouglas@0%"]
    log = c.parsed()
    f = _fmt_of(c, name)
    at = log.records[len(log.records) // 2].offset
    fmt = bytes((0xA3, 0x95, FMT_TYPE)) + FMT_BODY.pack(f.type, length, name.encode(), b"", b"")
    data = c.data[:at] + fmt + bytes((0xA3, 0x95, f.type)) + c.data[at:]
    res, _, out = replay_bytes(tmp_path, data)
    assert "Traceback" not in res.stderr, res.stderr[-800:]
    assert res.returncode == 3, (res.returncode, res.stderr[-400:])
    assert not check_mcap(out)


def test_imu_float_1e22_no_traceback(clean, tmp_path):
    c = clean["ac313-joeydouglas@0%"]
    log = c.parsed()
    imus = log.records_named(["IMU"])
    buf = bytearray(c.data)
    for frac in (0.3, 0.5, 0.7):  # three records (whether one reaches the filter depends on what it does then)
        log.put(buf, log.records[imus[int(frac * len(imus))]], "AccZ", 1e22)
    res, _, out = replay_bytes(tmp_path, bytes(buf))
    assert "Traceback" not in res.stderr, res.stderr[-800:]
    assert res.returncode in (0, 3) and not check_mcap(out)


def test_vanished_message_type_is_reported(clean, tmp_path):
    c = clean["ac33dev-log171@45%"]
    f = _fmt_of(c, "IMU")
    buf = bytearray(c.data)
    _put_fmt(buf, f.offset, length=f.length + 1)
    ref, _, _ = replay_bytes(tmp_path, c.data, name="clean")
    res, _, _ = replay_bytes(tmp_path, bytes(buf), name="bad")
    assert "ImuSample[0]" in _events(ref.stdout)
    lost = "ImuSample[0]" not in _events(res.stdout)
    if lost:  # allowed only as "damaged", naming what was lost
        assert res.returncode == 3, f"IMU lost and exit {res.returncode}: {res.stdout[-600:]}"
        assert any("IMU" in line for line in res.stdout.splitlines() if line.startswith("warning")), res.stdout


def test_bad_record_type_byte_resynchronises(clean, tmp_path):
    c = clean["ac33dev-log171@45%"]
    log = c.parsed()
    recs = [r for r in log.records if r.type != 0x80]
    r = recs[len(recs) // 2]
    buf = bytearray(c.data)
    buf[r.offset + 2] = next(t for t in range(255, 0, -1) if t not in log.formats)
    ref, _, _ = replay_bytes(tmp_path, c.data, name="clean")
    res, _, _ = replay_bytes(tmp_path, bytes(buf), name="bad")
    want, got = _events(ref.stdout), _events(res.stdout)
    assert res.returncode == 3 and "Traceback" not in res.stderr
    for k, n in want.items():
        assert got.get(k, 0) >= n - 2, f"{k}: {got.get(k, 0)} of {n} after one bad byte"


def test_concatenated_logs_replay_both(clean, tmp_path):
    a, b = clean["ac33dev-log171@0%"], clean["ac402-no-imu@45%"]
    res, _, out = replay_bytes(tmp_path, a.data + b.data)
    assert len(res.stderr.strip().splitlines()) <= 1, f"{len(res.stderr.splitlines())} lines on stderr"
    assert res.returncode in (0, 3), res.stderr[-300:]
    ev = _events(res.stdout)
    assert ev.get("ImuSample[0]", 0) > 0 and ev.get("GnssFix[1]", 0) > 0  # IMU from the first, GPS2 from the second
    assert not check_mcap(out)


@pytest.mark.parametrize("into", [13, 3, 8], ids=["frame", "time_stamp", "after_time_stamp"])
def test_tlog_cut_mid_record_exits_3(clean, tmp_path, into):
    """Cut 5 bytes into a frame, 3 bytes into a record's 8-byte time stamp, or right after it: pymavlink ends quietly
    on a short time stamp (the fuzz found exit 0 there)."""
    c = clean["ac357-phoenix-mission2@45%"]
    f = c.parsed().frames[len(c.parsed().frames) // 2]
    res, _, out = replay_bytes(tmp_path, c.data[:f.offset + into], suffix=".tlog")
    assert res.returncode == 3, (res.returncode, res.stdout[-400:])
    assert "truncated" in res.stdout, res.stdout[-400:]
    assert not check_mcap(out)


def test_exit_2_prints_one_line_only(clean, tmp_path):
    a, b = clean["ac33dev-log171@0%"], clean["ac402-no-imu@45%"]
    res, _, _ = replay_bytes(tmp_path, a.data + b.data)
    if res.returncode == 2:
        assert one_line_error(res), f"{len(res.stderr.splitlines())} lines: {res.stderr[:300]}"
    # a bad header between records: replayed, but pymavlink still writes to our stderr
    c = clean["ac33dev-log171@45%"]
    log = c.parsed()
    r = [r for r in log.records if r.type != 0x80][len(log.records) // 2]
    buf = bytearray(c.data)
    buf[r.offset + 2] = next(t for t, f in log.formats.items() if f.name == "PARM")
    res2, _, _ = replay_bytes(tmp_path, bytes(buf), name="hdr")
    assert not res2.stderr.strip(), f"stderr of an exit {res2.returncode} replay: {res2.stderr[:300]}"


# ----------------------------------------------------------------------------------------------- the output
def test_replay_out_same_as_input_bin_refused(clean, tmp_path):
    log = tmp_path / "same.bin"
    log.write_bytes(clean["ac33dev-inflight-gps-loss@0%"].data)
    before = _sha(log)
    res = run_cli("replay", log, "--out", log, "--quiet")
    assert _sha(log) == before, f"input overwritten (exit {res.returncode})"
    assert one_line_error(res), res.stderr[-300:]


def test_replay_out_same_as_input_tlog_refused(clean, tmp_path):
    log = tmp_path / "same.tlog"
    log.write_bytes(clean["ac357-phoenix-mission2@0%"].data)
    before = _sha(log)
    link = tmp_path / "alias.mcap"
    os.symlink(log, link)  # the same file by another name
    res = run_cli("replay", log, "--out", link, "--quiet")
    assert log.exists(), f"input deleted (exit {res.returncode})"
    assert _sha(log) == before, "input overwritten"
    assert one_line_error(res), res.stderr[-300:]


def test_disk_error_names_the_path(clean, tmp_path):
    log = tmp_path / "a.bin"
    log.write_bytes(clean["ac33dev-inflight-gps-loss@0%"].data)
    res = run_cli("replay", log, "--out", "/dev/full", "--quiet")
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "/dev/full" in res.stderr and "No space left" in res.stderr, res.stderr


def test_inspect_reports_chunk_crc_failure(clean, tmp_path):
    from mcap.reader import make_reader

    res, _, out = replay_bytes(tmp_path, clean["ac33dev-inflight-gps-loss@45%"].data)
    assert res.returncode == 0
    data = bytearray(out.read_bytes())
    with open(out, "rb") as f:
        ci = make_reader(f).get_summary().chunk_indexes
    ch = ci[len(ci) // 2]
    data[ch.chunk_start_offset + ch.chunk_length // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    assert check_mcap(bad), "the damage should make the chunk CRC fail"
    ins = run_cli("inspect", bad)
    first = ins.stdout.splitlines()[0] if ins.stdout else ""
    assert "Traceback" not in ins.stderr
    assert ", finalised)" not in first, first


@pytest.mark.parametrize("distinct", [False, True])
def test_repeated_timestamps_keep_memory_flat(clean, tmp_path, distinct):
    """One IMU record repeated 200,000 times in place (one time stamp; ``distinct``: each with its own AccX, so no
    copy is a duplicate): peak RSS within 1.5 x the clean input's + 20 MiB (it was 2 x: the reorder buffer held every
    event sharing the newest time, none ever older than its horizon)."""
    from replay.fuzz.runner import replay_args, run_subprocess

    c = clean["ac33dev-log171@45%"]
    log = c.parsed()
    r = log.records[log.records_named(["IMU"])[len(log.records_named(["IMU"])) // 2]]
    rec = c.data[r.offset:r.offset + log.formats[r.type].length]
    n = 200_000
    if distinct:
        buf = bytearray(rec * n)
        step = len(rec)
        for k in range(n):
            log.put(buf, type(r)(k * step, r.type), "AccX", float(k % 997) * 1e-3)
        reps = bytes(buf)
    else:
        reps = rec * n
    mutant = tmp_path / "rep.bin"
    mutant.write_bytes(c.data[:r.offset] + reps + c.data[r.offset:])
    base = tmp_path / "clean.bin"
    base.write_bytes(c.data)
    clean_run = run_subprocess(replay_args(base, tmp_path / "c.mcap"), timeout_s=300, workdir=tmp_path)
    res = run_subprocess(replay_args(mutant, tmp_path / "m.mcap"), timeout_s=300, workdir=tmp_path)
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-600:]
    assert not check_mcap(tmp_path / "m.mcap")
    assert res.maxrss_kb <= 1.5 * clean_run.maxrss_kb + 20 * 1024, (res.maxrss_kb // 1024, clean_run.maxrss_kb // 1024)
