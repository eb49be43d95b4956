"""The disk: a budget that deletes the oldest segments, write errors that stop the recording and nothing else."""

from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest

from companion.config import ConfigError, load_config
from companion.events import ImuSample
from companion.record import Recorder, RotatingRecorder, summarize

BUDGET_BYTES = 1_000_000


def _imu(rng, t_s: float) -> ImuSample:  # noisy values: the record does not compress to nothing
    a, g = rng.normal(0.0, 1.0, 3), rng.normal(0.0, 0.1, 3)
    return ImuSample(t_s=t_s, accel_frd_mps2=tuple(map(float, a)), gyro_frd_radps=tuple(map(float, g)), imu_index=0)


def _mcap_bytes(d) -> int:
    return sum(p.stat().st_size for p in d.glob("live-*.mcap"))


@pytest.mark.parametrize("segment_s", [0.0, 30.0])
def test_budget_deletes_the_oldest_segments_and_the_total_stays_under_it(tmp_path, segment_s):
    other = tmp_path / "live.bin"  # an input beside the record, and a file named like a record: never touched
    other.write_bytes(b"not ours")
    stranger = tmp_path / "live-x.mcap"
    stranger.write_bytes(b"nor this")
    rng = np.random.default_rng(1)
    rec = RotatingRecorder(tmp_path / "live.mcap", segment_s=segment_s, max_total_bytes=BUDGET_BYTES)
    rec.add_metadata("source", {"kind": "live"})
    n, worst = 30_000, 0  # 10 min at 50 Hz: about 4x the budget
    for k in range(n):
        rec.write(_imu(rng, k * 0.02))
        if k % 500 == 0:
            worst = max(worst, _mcap_bytes(tmp_path) - stranger.stat().st_size)
    rec.close()
    worst = max(worst, _mcap_bytes(tmp_path) - stranger.stat().st_size)
    written = [int(p.stem.rsplit("-", 1)[1]) for p in rec.paths + rec.deleted]
    assert sorted(written) == list(range(len(written))) and len(rec.deleted) >= 3, (rec.paths, rec.deleted)
    kept = [int(p.stem.rsplit("-", 1)[1]) for p in rec.paths]
    assert max(int(p.stem.rsplit("-", 1)[1]) for p in rec.deleted) < min(kept)  # the oldest went
    assert kept == list(range(min(kept), len(written)))  # the newest are all there
    assert all(not p.exists() for p in rec.deleted) and all(p.exists() for p in rec.paths)
    assert worst <= BUDGET_BYTES, f"{worst} bytes on disk with a budget of {BUDGET_BYTES}"
    assert other.read_bytes() == b"not ours" and stranger.read_bytes() == b"nor this"
    last = summarize(rec.paths[-1])
    assert last.finalised and last.end_ns == round((n - 1) * 0.02 * 1e9)  # the newest message is kept
    assert all(summarize(p).finalised and dict(summarize(p).metadata)["source"] == {"kind": "live"} for p in rec.paths)


def test_budget_setting_is_range_checked():
    base = {"link.connect": "udpin:127.0.0.1:14550"}
    assert load_config(None, {**base, "record.max_total_mb": 500}).record.max_total_mb == 500.0
    for bad in (-1, 0.5, 1e300, float("nan"), "big"):
        with pytest.raises(ConfigError, match="record.max_total_mb"):
            load_config(None, {**base, "record.max_total_mb": bad})


def test_a_file_that_cannot_be_written_from_the_start(tmp_path, capsys):
    rec = Recorder("/dev/full")  # the live default: stop recording, raise nothing
    for k in range(100):
        rec.write(_imu(np.random.default_rng(k), k * 0.02))
    rec.flush()
    rec.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/dev/full" in err[0] and "No space left" in err[0], err
    assert rec.write_error.filename == "/dev/full" and rec.dropped_after_error == 100
    missing = Recorder(tmp_path / "no" / "dir.mcap")
    assert missing.write_error is not None and str(tmp_path / "no" / "dir.mcap") in capsys.readouterr().err
    missing.close()
    with pytest.raises(OSError) as exc:  # a replay: the record is the product, the error is raised, with the path
        Recorder("/dev/full", raise_errors=True)
    assert exc.value.filename == "/dev/full" and exc.value.errno == 28


def test_a_full_disk_leaves_a_file_that_reads_to_its_end(tmp_path, capsys):
    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        rng = np.random.default_rng(2)
        rec = RotatingRecorder(mnt / "live.mcap", segment_s=10.0, chunk_size=4096)
        for k in range(20_000):
            rec.write(_imu(rng, k * 0.01))
        rec.close()
        assert rec.write_error is not None and rec.write_error.errno == 28 and rec.dropped_after_error > 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "recording stopped" in err[0] and str(rec.write_error.filename) in err[0], err
        s = summarize(rec.write_error.filename)
        assert not s.finalised and s.message_count > 0
        assert s.readable_bytes == s.size_bytes, s.note  # the half-written chunk was cut off
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_inspect_finds_a_damaged_chunk(tmp_path, compression):
    from mcap.reader import make_reader

    from companion.record import format_summary

    path = tmp_path / "r.mcap"
    rng = np.random.default_rng(3)
    with Recorder(path, compression=compression, chunk_size=20_000) as rec:
        for k in range(3000):
            rec.write(_imu(rng, k * 0.02))
    whole = summarize(path)
    assert whole.finalised and not whole.damaged and whole.chunk_count > 5
    with open(path, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    data = bytearray(path.read_bytes())
    for c in (chunks[1], chunks[-2]):  # a byte of the records (past the chunk's own header) flipped
        data[c.chunk_start_offset + c.chunk_length - 40] ^= 0x10
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    s = summarize(bad)
    assert s.finalised and len(s.damaged_chunks) == 2, s.damaged_chunks
    assert all(d.startswith(f"byte {c.chunk_start_offset}:") for d, c in zip(s.damaged_chunks, (chunks[1], chunks[-2])))
    first = format_summary(s).splitlines()[0]
    assert f"2 of {whole.chunk_count} chunks DAMAGED" in first and not first.endswith(", finalised)"), first
    assert not summarize(bad, check_crcs=False).damaged  # the check can be skipped


def test_the_live_view_goes_on_after_a_write_error(tmp_path, capsys):
    class View:
        def __init__(self):
            self.got = []

        def publish(self, topic, schema_name, schema, t_ns, data):
            self.got.append((topic, t_ns))

    view = View()
    rec = Recorder(tmp_path / "r.mcap", chunk_size=2000, live_view=view)
    rng = np.random.default_rng(4)
    for k in range(50):
        rec.write(_imu(rng, k * 0.02))
    full = os.open("/dev/full", os.O_WRONLY)  # from now on every write fails with ENOSPC
    os.dup2(full, rec._file._fd)
    os.close(full)
    for k in range(50, 200):
        rec.write(_imu(rng, k * 0.02))
    rec.write_location("/map/x", 4.0, 1.0, 2.0, 3.0)
    rec.close()
    assert rec.write_error is not None and rec.dropped_after_error > 100
    assert [t for _, t in view.got[:200]] == [round(k * 0.02 * 1e9) for k in range(200)]
    assert view.got[-1] == ("/map/x", 4_000_000_000)
    assert len([line for line in capsys.readouterr().err.splitlines() if "recording stopped" in line]) == 1


def test_run_with_a_budget_writes_segments(tmp_path):
    import socket
    import sys

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    res = subprocess.run([sys.executable, "-m", "companion.cli", "run", "--connect", f"udpin:127.0.0.1:{port}",
                          "--out", str(tmp_path / "live.mcap"), "--duration", "1", "--set", "record.max_total_mb=1",
                          "-q"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-600:]
    assert summarize(tmp_path / "live-000.mcap").finalised and not (tmp_path / "live.mcap").exists()


def test_a_segmented_record_resumes_once_the_disk_has_room(tmp_path, capsys, caplog):
    from companion.record.rotating import RETRY_MIN_S

    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        ballast = mnt / "ballast"  # somebody else's file fills the disk
        fd = os.open(ballast, os.O_WRONLY | os.O_CREAT)
        try:
            while os.write(fd, b"\0" * 4096):
                pass
        except OSError:
            pass
        finally:
            os.close(fd)
        os.truncate(ballast, max(0, ballast.stat().st_size - 40_000))  # room for a few chunks only
        rng = np.random.default_rng(5)
        rec = RotatingRecorder(mnt / "live.mcap", segment_s=60.0, chunk_size=4096)
        t_freed = None
        for k in range(30_000):  # 300 s at 100 Hz
            t = k * 0.01
            if rec.write_error is not None and t_freed is None:
                t_failed, t_freed = t, t + 25.0
            if t_freed is not None and ballast.exists() and t >= t_freed:
                ballast.unlink()  # the disk has room again
            rec.write(_imu(rng, t))
        rec.close()
        assert t_freed is not None and not ballast.exists(), "the disk did not fill"
        assert rec.write_error is None and len(rec.write_errors) == 1
        err = [line for line in capsys.readouterr().err.splitlines() if "recording stopped" in line]
        assert len(err) == 1, err  # the quiet retries say nothing; the resumption says so once
        assert [r.message for r in caplog.records if "resumed" in r.message][:1], caplog.text
        after = [summarize(p) for p in rec.paths[1:]]
        assert after and all(s.finalised for s in after)
        resumed_s = after[0].start_ns / 1e9
        assert t_freed <= resumed_s <= t_freed + 4 * RETRY_MIN_S  # tried again within the back-off
        assert after[-1].end_ns == round(29_999 * 0.01 * 1e9)  # recording to the end
        assert rec.dropped_after_error == round((resumed_s - t_failed) / 0.01)
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_earlier_records_count_in_the_budget_and_go_first(tmp_path):
    """A service restarted again and again: its record directory stays under the budget, earlier runs' oldest first."""
    rng = np.random.default_rng(2)
    earlier = []
    for k in range(4):  # four earlier runs of 300 kB each: 1.2 MB, over the 1 MB budget already
        q = tmp_path / f"companion-2026120{k + 1}T000000Z-000.mcap"
        q.write_bytes(rng.bytes(300_000))
        earlier.append(q)
    rec = RotatingRecorder(tmp_path / "companion-20261206T000000Z.mcap", segment_s=30.0, max_total_bytes=BUDGET_BYTES,
                           earlier=earlier)
    # at start: down to half the budget (500 kB), oldest first
    assert [q.exists() for q in earlier] == [False, False, False, True]
    worst = 0
    for k in range(30_000):
        rec.write(_imu(rng, k * 0.02))
        if k % 500 == 0:
            worst = max(worst, sum(p.stat().st_size for p in tmp_path.glob("companion-*.mcap")))
    rec.close()
    assert worst <= BUDGET_BYTES and not earlier[3].exists()
    assert rec.deleted[:4] == earlier  # the earlier runs went before any segment of this one
    assert all(p.exists() for p in rec.paths) and summarize(rec.paths[-1]).finalised


def test_run_into_a_directory_keeps_it_under_the_budget(tmp_path):
    import socket
    import sys

    rng = np.random.default_rng(3)
    old = [tmp_path / "companion-20250101T000000Z-000.mcap", tmp_path / "companion-20250102T000000Z.mcap"]
    for q in old:
        q.write_bytes(rng.bytes(600_000))
    mine = tmp_path / "companion-notes.mcap"  # not a name the service writes: never touched
    mine.write_bytes(b"keep")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    res = subprocess.run([sys.executable, "-m", "companion.cli", "run", "--connect", f"udpin:127.0.0.1:{port}",
                          "--out", f"{tmp_path}/", "--duration", "1", "--set", "record.max_total_mb=1"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-600:]
    assert not old[0].exists() and not old[1].exists()  # 1.2 MB of earlier runs: both over half of 1 MB
    assert mine.read_bytes() == b"keep"
    new = sorted(tmp_path.glob("companion-2*-000.mcap"))
    assert len(new) == 1 and summarize(new[0]).finalised and "2 oldest records deleted" in res.stdout


def test_resumed_only_when_a_chunk_reached_the_disk_and_no_unreadable_segment_is_left(tmp_path, caplog):
    """A disk with room for a new segment's header but not for a chunk (one free page) said "recording resumed" and
    left that segment behind unreadable; now the attempt is deleted, and the resumption is said once, when true."""
    import logging

    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    caplog.set_level(logging.INFO, "companion.record.rotating")
    try:
        ballast = mnt / "ballast"
        fd = os.open(ballast, os.O_WRONLY | os.O_CREAT)
        try:
            while os.write(fd, b"\1" * 4096):
                pass
        except OSError:
            pass
        finally:
            os.close(fd)
        rng = np.random.default_rng(7)
        rec = RotatingRecorder(mnt / "live.mcap", segment_s=600.0, chunk_size=65536)  # (a chunk: > 1 page)
        resumed_false = []
        for k in range(100_000):  # 1000 s at 100 Hz (the retries back off to minutes)
            t = k * 0.01
            if k == 2000:  # a page frees up: a header fits, a chunk does not
                os.truncate(ballast, ballast.stat().st_size - 4096)
            if k == 40_000:  # the disk has room again
                ballast.unlink()
            rec.write(_imu(rng, t))
            if k < 40_000 and any("resumed" in r.message for r in caplog.records):
                resumed_false.append(t)
                break
        rec.close()
        assert not resumed_false, f"'recording resumed' at {resumed_false[0]:.1f} s with the disk still full"
        assert [r.message for r in caplog.records if "resumed" in r.message][:1], caplog.text
        assert rec.paths and all(p.exists() for p in rec.paths)
        for p in mnt.glob("live-*.mcap"):
            assert p in rec.paths, f"{p.name} ({p.stat().st_size} bytes) left behind"
            got = summarize(p)  # finalised, or (stopped by a write error) whole chunks to its end
            assert got.message_count > 0 and got.readable_bytes == got.size_bytes, (p.name, got.size_bytes, got.note)
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)
