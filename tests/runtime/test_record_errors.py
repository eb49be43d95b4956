"""A write error (a full disk) stops the recording with one message naming the file; navigation and injection go on."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time

import pytest

from companion.config import load_config
from companion.events import ImuSample
from companion.mavlink.link import Batch
from companion.record import Recorder
from companion.runtime.runner import Runtime
from companion.sources.files import read_events
from tests.conftest import SAMPLE_LOG, free_port


def _disk_full(rec: Recorder) -> None:
    """From now on every write of ``rec`` fails with ENOSPC, as on a full file system."""
    full = os.open("/dev/full", os.O_WRONLY)
    os.dup2(full, rec._file._fd)
    os.close(full)


def test_recorder_write_error_stops_recording_once_and_never_raises(tmp_path, capsys):
    rec = Recorder(tmp_path / "r.mcap", chunk_size=1000)
    imu = [ImuSample(t_s=0.01 * i, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0) for i in range(500)]
    for s in imu[:100]:
        rec.write(s)
    _disk_full(rec)
    for s in imu[100:]:
        rec.write(s)
    rec.flush()
    rec.add_metadata("runtime", {"a": "b"})
    rec.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path / "r.mcap") in err[0] and "No space left" in err[0]
    assert isinstance(rec.write_error, OSError) and rec.dropped_after_error > 0


def test_runtime_keeps_injecting_after_the_disk_fills(tmp_path, capsys):
    events = read_events(SAMPLE_LOG)
    cfg = load_config(None, {"link.connect": f"udpin:127.0.0.1:{free_port()}", "inject.mode": "inject"})
    rec = Recorder(tmp_path / "r.mcap", chunk_size=10_000)
    rt = Runtime(cfg, rec, log=lambda _text: None)
    sent: list[float] = []
    rt.injector.sender = lambda _msg: sent.append(time.perf_counter()) or True
    full_at: list[float] = []

    def start(loop, put):
        def feed(i=0):
            if i >= len(events):
                return
            if i == 3000:
                _disk_full(rec)
                full_at.append(time.perf_counter())
            put(Batch(time.perf_counter(), events[i:i + 20], "RAW_IMU"))
            loop.call_later(0.001, feed, i + 20)
        feed()

    rt.link.start = start
    reason = asyncio.run(rt.run(duration_s=20.0))
    rec.close()
    assert reason.startswith("--duration")
    assert full_at and sum(t > full_at[0] for t in sent) > 10  # injection went on after the write error
    err = [line for line in capsys.readouterr().err.splitlines() if "recording stopped" in line]
    assert len(err) == 1 and "r.mcap" in err[0]


def test_run_on_a_full_file_system_goes_on(tmp_path):
    """A real, tiny tmpfs (needs root; skipped where mounting is not allowed)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        rec = Recorder(mnt / "r.mcap", chunk_size=4096)
        for i in range(20000):
            rec.write(ImuSample(t_s=0.001 * i, accel_frd_mps2=(0.1 * i, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0))
        rec.close()
        assert rec.write_error is not None and rec.write_error.errno == 28
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)
