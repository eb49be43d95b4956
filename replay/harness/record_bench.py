"""Recorder throughput: ``python -m replay.harness.record_bench [N]`` writes N ImuSample (default 200 000).

Prints messages/s for each compression, the file size, the time to summarise the finalised file
(summary section) and to recover the same file with its summary cut off (streaming every record).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from companion.events import ImuSample
from companion.record.inspect import summarize
from companion.record.recorder import Recorder


def main(n: int = 200_000) -> None:
    events = [
        ImuSample(i / 400, (0.01 * (i % 100), -0.02, -9.81), (1e-3, 2e-3 * (i % 5), -3e-3), i % 2) for i in range(n)
    ]
    print(f"{n} ImuSample at 400 Hz of message time ({n / 400:.0f} s), chunks closed every 1 s of message time")
    print(f"{'compression':<11}  {'write s':>7}  {'msg/s':>9}  {'file MB':>7}  {'summarize s':>11}  {'recover s':>9}")
    with tempfile.TemporaryDirectory() as d:
        for comp in ("zstd", "lz4", "none"):
            path = Path(d) / f"{comp}.mcap"
            t0 = time.perf_counter()
            with Recorder(path, compression=comp) as rec:
                for ev in events:
                    rec.write(ev)
            dt = time.perf_counter() - t0
            t1 = time.perf_counter()
            s = summarize(path)
            ds = time.perf_counter() - t1
            assert s.finalised and s.message_count == n
            cut = Path(d) / f"{comp}-killed.mcap"
            data = path.read_bytes()
            cut.write_bytes(data[: int(len(data) * 0.9)])  # a killed writer: no summary, no footer
            t2 = time.perf_counter()
            r = summarize(cut)
            dr = time.perf_counter() - t2
            assert r.recovered and 0 < r.message_count < n
            print(f"{comp:<11}  {dt:7.2f}  {n / dt:9,.0f}  {path.stat().st_size / 1e6:7.1f}  {ds:11.3f}  {dr:9.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 200_000)
