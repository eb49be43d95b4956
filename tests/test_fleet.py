"""Fleet replay: `companion replay FOLDER` (local process pool) and `--scheduler` (a Dask cluster): one MCAP per log,
the same record as the log's own replay, a summary row per log, one bad log never stopping the rest."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

from companion.fleet import find_logs, record_paths, write_summary
from companion.record import iter_payloads, summarize
from tests.conftest import LOG_ERLE, SAMPLE_LOG, require

COMPANION = [sys.executable, "-m", "companion.cli"]


def run_cli(*args, timeout=600):
    return subprocess.run([*COMPANION, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def _rows(out: Path) -> list[dict]:
    with open(out / "fleet_summary.csv", newline="") as f:
        return list(csv.DictReader(f))


def _fleet_dir(tmp_path: Path) -> Path:
    """Two flights (links, as a fleet is usually a folder of them) and two bad logs: garbage, and an empty file."""
    d = tmp_path / "logs"
    (d / "sub").mkdir(parents=True)
    (d / "a_sample.tlog").symlink_to(SAMPLE_LOG.resolve())
    (d / "sub" / "b_erle.bin").symlink_to(require(LOG_ERLE).resolve())
    (d / "c_garbage.bin").write_bytes(bytes(range(256)) * 40)
    (d / "d_empty.tlog").write_bytes(b"")
    (d / "notes.txt").write_text("not a log")
    return d


def test_fleet_replay_of_a_folder_on_local_workers(tmp_path):
    logs, out = _fleet_dir(tmp_path), tmp_path / "out"
    res = run_cli("replay", logs, "--out", out, "--workers", "2")
    assert "Traceback" not in res.stderr
    assert res.returncode == 3, res.stderr  # some logs bad: the others replayed all the same
    rows = _rows(out)
    assert [Path(r["log"]).name for r in rows] == ["a_sample.tlog", "c_garbage.bin", "d_empty.tlog", "b_erle.bin"]
    by = {Path(r["log"]).name: r for r in rows}
    for bad in ("c_garbage.bin", "d_empty.tlog"):
        assert by[bad]["exit_code"] == "2" and by[bad]["error"], by[bad]
        assert not Path(by[bad]["record"]).exists()  # no empty record left behind
    sample, erle = by["a_sample.tlog"], by["b_erle.bin"]
    assert sample["exit_code"] == erle["exit_code"] == "0"
    assert erle["vehicle"] == "copter" and erle["firmware"].startswith("ArduCopter V3.3")
    assert sample["vehicle"] == "quadrotor"  # from the tlog's HEARTBEAT
    assert abs(float(erle["imu_hz"]) - 50) < 1 and abs(float(erle["gnss_hz"]) - 5.56) < 0.1
    # the Erle log loses GNSS in flight until its end (its manifest): an outage of ~32 s, in the row
    assert int(erle["gnss_gaps"]) >= 1 and float(erle["gnss_gap_s"]) > 30
    assert 100 < float(erle["duration_s"]) < 120
    # each good log's record is the one `companion replay LOG` writes (the same payloads, in the same order)
    for row in (sample, erle):
        single = tmp_path / f"single_{Path(row['log']).stem}.mcap"
        assert run_cli("replay", row["log"], "--out", single, "-q").returncode == 0
        assert list(iter_payloads(Path(row["record"]))) == list(iter_payloads(single))
        assert summarize(Path(row["record"])).finalised
    md = (out / "fleet_summary.md").read_text()
    assert "| b_erle.bin | 0 |" in md and "4 logs: 2 replayed, 0 damaged but replayed, 2 not replayed" in md
    assert "4 logs on 2 local worker(s): 2 replayed cleanly, 2 with problems" in res.stdout


def test_fleet_replay_on_a_dask_cluster(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "one.tlog").symlink_to(SAMPLE_LOG.resolve())
    (logs / "two.tlog").symlink_to(SAMPLE_LOG.resolve())
    (logs / "bad.bin").write_bytes(b"\xa3\x95" + bytes(500))
    out = tmp_path / "out"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        res = run_cli("replay", logs, "--out", out, "--scheduler", cluster.scheduler_address, "-q")
    assert "Traceback" not in res.stderr
    assert res.returncode == 3, res.stderr
    rows = {Path(r["log"]).name: r for r in _rows(out)}
    assert rows["bad.bin"]["exit_code"] == "2"
    assert rows["one.tlog"]["exit_code"] == rows["two.tlog"]["exit_code"] == "0"
    # the same flight twice gives the same record on the cluster
    assert list(iter_payloads(out / "one.mcap")) == list(iter_payloads(out / "two.mcap"))
    assert rows["one.tlog"]["events"] == rows["two.tlog"]["events"] != "0"


def test_find_logs_and_record_names(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "y").mkdir()
    for p in ("x/f.BIN", "y/f.bin", "x/g.tlog", "x/h.mcap"):
        (tmp_path / p).write_bytes(b"")
    logs = find_logs([tmp_path, tmp_path / "x" / "g.tlog"])  # named twice: replayed once
    assert [p.relative_to(tmp_path).as_posix() for p in logs] == ["x/f.BIN", "x/g.tlog", "y/f.bin"]
    assert [p.name for p in record_paths(logs, tmp_path)] == ["f.mcap", "g.mcap", "f-2.mcap"]
    with pytest.raises(FileNotFoundError):
        find_logs([tmp_path / "missing"])


def test_fleet_usage_errors(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    res = run_cli("replay", empty, "--out", tmp_path / "o")
    assert res.returncode == 2 and "no logs" in res.stderr and "Traceback" not in res.stderr
    res = run_cli("replay", SAMPLE_LOG, SAMPLE_LOG, "--realtime")
    assert res.returncode == 2 and "--realtime" in res.stderr


def test_summary_of_no_rows_and_a_row_with_an_error(tmp_path):
    csv_path, md_path = write_summary([{"log": "/a/b|c.bin", "exit_code": 2, "error": "bad\nthing"}], tmp_path)
    assert "b\\|c.bin" in md_path.read_text() and "bad thing" in md_path.read_text()
    assert _rows(tmp_path)[0]["error"] == "bad\nthing"
