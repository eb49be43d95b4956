"""`companion convert` against replay's rules: CPU time against pymavlink's own parse of the same log (target: ratio
>= 0.5) and peak memory flat with the log's length (target: a 3 h log <= 1.2x a 5 min one).

    .venv-test/bin/python -m replay.live.convert_speed [--repeat 3] [--hours 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from companion.record.convert import convert_log
from companion.shared_data import shared_logs_dir
from replay.harness.results import md_table, publish, results_file
from replay.live.throughput import LOG171, extend_log, peak_rss_mib, pymavlink_raw


def speed_table(logs: list[Path], repeat: int, tmp: Path) -> str:
    rows = []
    for log in logs:
        ours, theirs, n = [], [], 0
        for _ in range(repeat):  # interleaved, in one process
            n, dt = pymavlink_raw(log)
            theirs.append(dt)
            t0 = time.process_time()
            conv = convert_log(log, tmp / "all.mcap")
            ours.append(time.process_time() - t0)
            assert conv.messages == n, (log, conv.messages, n)
        ratio = statistics.median(t / o for t, o in zip(theirs, ours))
        rows.append([log.name[:40], f"{log.stat().st_size / 1e6:.2f}", n, f"{statistics.median(theirs):.3f}",
                     f"{statistics.median(ours):.3f}", f"{n / statistics.median(ours):,.0f}", f"{ratio:.2f}"])
    return md_table(["log", "MB", "messages", "pymavlink CPU s", "convert CPU s", "convert msgs/s",
                     "ratio (pymavlink / convert)"], rows)


def memory_table(hours: float, tmp: Path) -> str:
    rows = []
    for label, target in (("5 min", 300.0), (f"{hours:g} h", hours * 3600)):
        log = tmp / "long.bin"
        span = extend_log(LOG171, log, target)
        rss, cpu = peak_rss_mib(log, tmp / "long.mcap", "convert")
        rows.append([label, f"{span:.0f}", f"{log.stat().st_size / 1e6:.1f}", f"{rss:.0f}", f"{cpu:.1f}"])
        log.unlink()
    ratio = float(rows[1][3]) / float(rows[0][3])
    return md_table(["convert of log171 extended to", "flight s", "MB", "peak RSS MiB", "CPU s"], rows) + \
        f"\n\nPeak RSS of the long conversion / the 5 min one: {ratio:.2f}"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m replay.live.convert_speed", description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--hours", type=float, default=3.0)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    logs = sorted(p for p in shared_logs_dir().iterdir() if p.suffix in (".bin", ".tlog"))
    with tempfile.TemporaryDirectory() as d:
        speed = speed_table(logs, args.repeat, Path(d))
        memory = memory_table(args.hours, Path(d))
    cmd = f"    .venv-test/bin/python -m replay.live.convert_speed --repeat {args.repeat} --hours {args.hours:g}"
    head = (f"Load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the end (other jobs running); CPU "
            "time, medians; the ratio is the median of the interleaved pairs. Targets: ratio >= 0.5, the long log's "
            "peak RSS <= 1.2x the short one's.")
    text = (f"## Log conversion (`companion convert`)\n\n{cmd}\n\n{head}\n\n{speed}\n\n{memory}\n")
    publish(text, results_file("ingest"), "convert", "Ingest and replay throughput", write=not args.no_write)


if __name__ == "__main__":
    main()
