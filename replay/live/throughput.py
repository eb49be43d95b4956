"""Replay throughput on a log next to pymavlink's own raw read of the same file, in one run.

    .venv/bin/python -m replay.live.throughput [LOG ...]

For each log: (1) pymavlink alone — ``mavutil.mavlink_connection(path)`` and ``recv_match()`` until the
end, every message decoded; (2) ``companion replay`` in-process — ingest + the full pipeline of
``build_pipeline`` + MCAP record to a temporary file. Prints messages/s for pymavlink and events/s for
the replay (events are what the replay emits: IMU, GNSS, attitude, ...), best of N repeats.
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path

from companion.pipeline.core import build_pipeline, run_source
from companion.record import Recorder
from companion.shared_data import shared_logs_dir
from companion.sources import FileSource

SHARED_LOGS = shared_logs_dir()


def pymavlink_raw(path: Path) -> tuple[int, float]:
    from pymavlink import mavutil

    t0 = time.perf_counter()
    m = mavutil.mavlink_connection(str(path))
    n = 0
    while m.recv_match() is not None:
        n += 1
    return n, time.perf_counter() - t0


def companion_replay(path: Path) -> tuple[int, int, float]:
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        rec = Recorder(Path(d) / "t.mcap")
        pipe = build_pipeline(rec)
        asyncio.run(run_source(FileSource(path), pipe))
        rec.close()
        dt = time.perf_counter() - t0
    return sum(pipe.stats.counts.values()), pipe.outputs, dt, pipe.stats.duration_s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, help="also write the table as Markdown to this file")
    args = ap.parse_args()
    logs = args.logs or [max(SHARED_LOGS.glob("*.bin"), key=lambda p: p.stat().st_size)]
    rows = [
        "| log | MB | pymavlink messages | pymavlink msgs/s | replay events | pipeline outputs | replay events/s | x real time |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for log in logs:
        raw = min((pymavlink_raw(log) for _ in range(args.repeat)), key=lambda r: r[1])
        rep = min((companion_replay(log) for _ in range(args.repeat)), key=lambda r: r[2])
        rows.append(
            f"| {log.name} | {log.stat().st_size / 1e6:.2f} | {raw[0]} | {raw[0] / raw[1]:,.0f} | {rep[0]} | "
            f"{rep[1]} | {rep[0] / rep[2]:,.0f} | {rep[3] / rep[2]:.0f} |"
        )
    table = "\n".join(rows)
    print(table)
    if args.out:
        args.out.write_text(
            "# Ingest and replay throughput\n\nCommand (repository root):\n\n"
            f"    .venv/bin/python -m replay.live.throughput --repeat {args.repeat} --out {args.out}\n\n"
            "pymavlink: `mavutil.mavlink_connection(path)` + `recv_match()` over every message (raw decode, "
            "nothing else). Replay: ingest + the full pipeline (KNN predictor, INS, Kalman integrator) + MCAP "
            "record, in-process, one run each, best of the repeats, same machine, same run.\n\n" + table + "\n"
        )


if __name__ == "__main__":
    main()
