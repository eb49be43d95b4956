"""Replay throughput next to pymavlink's own raw parse of the same file, memory against flight length, start-up.

    .venv/bin/python -m replay.live.throughput [LOG ...] [--repeat N] [--hours 3] [--no-write]

Speed, per log, interleaved in one process (CPU time: ``time.process_time``, all threads): (1) pymavlink alone --
``mavutil.mavlink_connection(path)`` and ``recv_match()`` until the end, every message decoded; (2) ``companion
replay`` in-process -- ingest, the navigator (KNN predictor, INS, Kalman integrator) and the MCAP record to a
temporary file; (3) the same with ``--navigator off``. Repeated ``--repeat`` times in turn; the ratio is pymavlink's
CPU time over ours for the same file (the rate of the file), the median of the pairs; x real time is the flight's
duration over our CPU time.

Memory: peak RSS of ``companion replay`` (a child process each) on log171 extended to 5 minutes and to ``--hours``:
its records repeated with boot and GPS times shifted to run on (:func:`extend_log`, in a temporary directory).
Start-up: CPU time of ``import companion.cli``, and of ``companion run`` (UDP link, systemd's NOTIFY_SOCKET) up to
READY=1, median of 5. Profile: cProfile of the replay of log171, the top 10 by own time. ``--compare-tree DIR``:
the same replay by another checkout's code, against this one's (before/after a change).
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import io
import os
import pstats
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from companion.replay_common import REPLAY_FLUSH_INTERVAL_S
from companion.pipeline.core import build_pipeline, run_source
from companion.record import Recorder
from companion.shared_data import shared_logs_dir
from companion.sources import FileSource
from replay.harness.results import md_table, publish, results_file

SHARED_LOGS = shared_logs_dir()
LOG171 = SHARED_LOGS / "ac33dev_pixhawk1_quad_2015-11-21_dronekit-la-testdata_log171.bin"


def pymavlink_raw(path: Path) -> tuple[int, float]:
    """(messages, CPU s) of pymavlink decoding every message of the file."""
    from pymavlink import mavutil

    t0 = time.process_time()
    m = mavutil.mavlink_connection(str(path))
    n = 0
    while m.recv_match() is not None:
        n += 1
    dt = time.process_time() - t0
    m.close()
    return n, dt


def companion_replay(path: Path, navigator: bool = True) -> tuple[int, float, float]:
    """(events, CPU s, flight duration s) of an in-process replay with the MCAP record."""
    with tempfile.TemporaryDirectory() as d:
        t0 = time.process_time()
        rec = Recorder(Path(d) / "t.mcap", flush_interval_s=REPLAY_FLUSH_INTERVAL_S)  # as `companion replay`
        pipe = build_pipeline(rec, navigator=navigator)
        asyncio.run(run_source(FileSource(path), pipe))
        rec.close()
        dt = time.process_time() - t0
    return sum(pipe.stats.counts.values()), dt, pipe.stats.duration_s


def speed_table(logs: list[Path], repeat: int) -> str:
    rows = []
    for log in logs:
        raw, full, off = [], [], []
        for _ in range(repeat):  # interleaved: a load change hits both sides of a pair
            raw.append(pymavlink_raw(log))
            full.append(companion_replay(log))
            off.append(companion_replay(log, navigator=False))
        n_raw, events, dur = raw[0][0], full[0][0], full[0][2]
        ratio = statistics.median(r[1] / f[1] for r, f in zip(raw, full))
        ratio_off = statistics.median(r[1] / f[1] for r, f in zip(raw, off))
        t_raw, t_full, t_off = (statistics.median(x[1] for x in xs) for xs in (raw, full, off))
        rows.append([log.name[:40], f"{log.stat().st_size / 1e6:.2f}", f"{dur:.0f}", n_raw, f"{n_raw / t_raw:,.0f}",
                     f"{t_raw:.3f}", events, f"{events / t_full:,.0f}", f"{t_full:.3f}", f"{ratio:.2f}",
                     f"{dur / t_full:.0f}", f"{t_off:.3f}", f"{ratio_off:.2f}", f"{dur / t_off:.0f}"])
    return md_table(["log", "MB", "flight s", "pymavlink msgs", "pymavlink msgs/s", "pymavlink CPU s", "replay events",
                     "replay events/s", "replay CPU s", "ratio", "x real time", "nav off CPU s", "nav off ratio",
                     "nav off x real time"], rows)


def parts_table(logs: list[Path]) -> str:
    """CPU s of the replay's parts, each alone on the log's events read beforehand (the second of two rounds): the
    read (decode to events), the stream statistics, the navigator, the pipeline with the record of the inputs, the
    record of the navigator's outputs, and all but the read together."""
    from companion.nav import Navigator
    from companion.sources.files import read_events
    from companion.stats import StreamStats

    def cpu(fn):
        t0 = time.process_time()
        out = fn()
        return time.process_time() - t0, out

    def record(feed) -> None:
        with tempfile.TemporaryDirectory() as d:
            rec = Recorder(Path(d) / "t.mcap", flush_interval_s=REPLAY_FLUSH_INTERVAL_S)
            feed(rec)
            rec.close()

    def navigate(evs):
        nav, out = Navigator(), []
        for e in evs:
            out += nav.process(e)
        return out + nav.finish()

    def replay(rec, evs, navigator):
        pipe = build_pipeline(rec, navigator=navigator)
        for e in evs:
            pipe.process(e)
        pipe.finish()

    def stats(evs):
        st = StreamStats()
        for e in evs:
            st.add(e)

    rows = []
    for log in logs:
        for _ in range(2):
            t_read, evs = cpu(lambda: read_events(log))
            t_stats, _ = cpu(lambda: stats(evs))
            t_nav, outs = cpu(lambda: navigate(evs))
            t_in, _ = cpu(lambda: record(lambda rec: replay(rec, evs, False)))
            t_out, _ = cpu(lambda: record(lambda rec: [build_pipeline(rec, navigator=False)._emit(o) for o in outs]))
            t_all, _ = cpu(lambda: record(lambda rec: replay(rec, evs, True)))
        rows.append([log.name[:40], len(evs), len(outs), f"{t_read:.3f}", f"{t_stats:.3f}", f"{t_nav:.3f}",
                     f"{t_in:.3f}", f"{t_out:.3f}", f"{t_all:.3f}", f"{100 * t_nav / (t_all + t_read):.0f}"])
    return md_table(["log", "events", "outputs", "read CPU s", "stats CPU s", "navigator CPU s",
                     "pipeline + record of inputs CPU s", "record of outputs CPU s", "all but the read CPU s",
                     "navigator % of read + all"], rows)


# ---------------------------------------------------------------------------------------------- long logs
def _records(data: bytes) -> tuple[list[tuple[int, object]], int]:
    """(offset, Format) of every record of a clean dataflash log, and where its first non-FMT record is."""
    from companion.mavlink.dataflash_stream import FMT_FORMAT, FMT_TYPE, Format, _FMT_BODY, _text

    formats = {FMT_TYPE: FMT_FORMAT}
    out, ofs, first = [], 0, None
    while ofs + 3 <= len(data):
        fmt = formats.get(data[ofs + 2]) if data[ofs:ofs + 2] == b"\xa3\x95" else None
        if fmt is None or ofs + fmt.length > len(data):
            break
        if fmt.type == FMT_TYPE:
            t, length, name, f, cols = _FMT_BODY.unpack(data[ofs + 3:ofs + fmt.length])
            formats[t] = Format(t, length, _text(name), _text(f), _text(cols))
        elif first is None:
            first = ofs
        out.append((ofs, fmt))
        ofs += fmt.length
    return out, first


def _field(fmt, column: str) -> tuple[int, str] | None:
    """(byte offset in the record, numpy dtype) of an integer column."""
    if column not in fmt.columns or fmt.dtype is None:
        return None
    i = fmt.columns.index(column)
    dt, off = fmt.dtype.fields[f"f{i}"]
    return (off, dt.str) if dt.kind in "iu" else None


def extend_log(src: Path, dst: Path, target_s: float) -> float:
    """Write ``src``'s records again and again after themselves, boot times (TimeUS, TimeMS; T of AC 3.x GPS rows)
    and GPS times of week shifted by the log's span each time, until ``target_s`` of flight; returns the span written.
    A flight of that length for memory measurements (the vehicle jumps back to the start at each repetition)."""
    data = src.read_bytes()
    recs, first = _records(data)
    body = np.frombuffer(data[first:], np.uint8)
    fields = []  # (index array into body, dtype, unit in s, is GPS time of week, week index array)
    by_fmt: dict[int, list[int]] = {}
    for ofs, fmt in recs:
        if ofs >= first:
            by_fmt.setdefault(id(fmt), [fmt]).append(ofs - first)
    lo, hi = np.inf, -np.inf
    for fmt, *offs in by_fmt.values():
        offs = np.array(offs)
        gps_ac3 = fmt.name.startswith("GPS") and "T" in fmt.columns and "TimeMS" in fmt.columns
        for col, unit, tow in (("TimeUS", 1e-6, False), ("TimeMS", 1e-3, gps_ac3), ("T", 1e-3, False), ("GMS", 1e-3, True)):
            f = _field(fmt, col) if col != "T" or gps_ac3 else None
            if f is None:
                continue
            idx = offs[:, None] + f[0] + np.arange(np.dtype(f[1]).itemsize)
            wk = _field(fmt, "Week") or _field(fmt, "GWk") if tow else None
            widx = offs[:, None] + wk[0] + np.arange(2) if wk else None
            fields.append((idx, f[1], unit, tow, widx))
            if not tow:
                v = body[idx].copy().view(f[1]).ravel() * unit
                lo, hi = min(lo, v.min()), max(hi, v.max())
    span = hi - lo + 0.02
    n = int(np.ceil(target_s / span))
    with open(dst, "wb") as out:
        out.write(data)
        for k in range(1, n):
            buf = body.copy()
            for idx, dt, unit, tow, widx in fields:
                v = buf[idx].copy().view(dt).ravel().astype(np.int64) + int(round(k * span / unit))
                if tow and widx is not None:
                    week_units = int(round(604800 / unit))
                    w = buf[widx].copy().view("<u2").ravel() + v // week_units
                    buf[widx] = w.astype("<u2").view(np.uint8).reshape(-1, 2)
                    v = v % week_units
                buf[idx] = v.astype(dt).view(np.uint8).reshape(idx.shape)
            if k == n - 1:  # the last repetition only as far as the target
                keep = (target_s - k * span) / span
                cut = next((o - first for o, _ in recs if o >= first and o - first >= keep * len(body)), len(body))
                buf = buf[:cut]
            out.write(buf.tobytes())
    return min(target_s, n * span)


_RSS = "import resource, subprocess, sys; subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL); " \
       "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)"


def peak_rss_mib(log: Path, out: Path, command: str = "replay") -> tuple[float, float]:
    """(peak RSS MiB, CPU s) of ``companion COMMAND LOG`` (replay, convert) in a child process."""
    t0 = os.times()
    res = subprocess.run([sys.executable, "-c", _RSS, sys.executable, "-m", "companion.cli", command, str(log),
                          "--out", str(out), "--quiet"], capture_output=True, text=True, check=True)
    t1 = os.times()
    return int(res.stdout.split()[-1]) / 1024, (t1.children_user - t0.children_user) + (t1.children_system - t0.children_system)


def memory_table(hours: float) -> str:
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for label, target in (("5 min", 300.0), (f"{hours:g} h", hours * 3600)):
            log = Path(d) / "long.bin"
            span = extend_log(LOG171, log, target)
            rss, cpu = peak_rss_mib(log, Path(d) / "long.mcap")
            rows.append([label, f"{span:.0f}", f"{log.stat().st_size / 1e6:.1f}", f"{rss:.0f}", f"{cpu:.1f}"])
            log.unlink()
    ratio = float(rows[1][3]) / float(rows[0][3])
    return md_table(["replay of log171 extended to", "flight s", "MB", "peak RSS MiB", "CPU s"], rows) + \
        f"\n\nPeak RSS of the long replay / the 5 min one: {ratio:.2f}"


# ---------------------------------------------------------------------------------------------- start-up
_IMPORT = "import time; t = time.process_time(); import companion.cli; print(time.process_time() - t)"


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


def startup_to_ready(tmp: Path) -> tuple[float, float]:
    """(CPU s, wall s) of ``companion run`` on a UDP link from exec to systemd's READY=1."""
    sock_path = str(tmp / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(sock_path)
    srv.settimeout(60)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, NOTIFY_SOCKET=sock_path)
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--connect", f"udpin:127.0.0.1:{port}",
                             "--out", str(tmp / "run.mcap"), "--duration", "60"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while not srv.recv(4096).startswith(b"READY=1"):
            pass
        wall = time.monotonic() - t0
        cpu = _cpu_s(proc.pid)
    finally:
        proc.terminate()
        proc.wait(30)
        srv.close()
        os.unlink(sock_path)
    return cpu, wall


def startup_table(n: int = 5) -> str:
    imp = [float(subprocess.run([sys.executable, "-c", _IMPORT], capture_output=True, text=True, check=True).stdout)
           for _ in range(n)]
    with tempfile.TemporaryDirectory() as d:
        ready = [startup_to_ready(Path(d)) for _ in range(n)]
    return md_table(["what", "CPU s (median of 5)", "wall s (median of 5)"], [
        ["import companion.cli", f"{statistics.median(imp):.3f}", "-"],
        ["companion run: exec to READY=1", f"{statistics.median(c for c, _ in ready):.3f}",
         f"{statistics.median(w for _, w in ready):.3f}"],
    ])


def profile_table(log: Path, top: int = 10) -> str:
    _, cpu, _ = companion_replay(log)
    pr = cProfile.Profile(time.process_time)
    pr.enable()
    companion_replay(log)
    pr.disable()
    st = pstats.Stats(pr, stream=io.StringIO())
    total = sum(v[2] for v in st.stats.values())
    rows = []
    for (file, line, func), (_, ncalls, tt, ct, _) in sorted(st.stats.items(), key=lambda kv: -kv[1][2])[:top]:
        where = func if file == "~" else f"{'/'.join(Path(file).parts[-2:])}:{line} {func}"
        rows.append([where, ncalls, f"{tt:.3f}", f"{100 * tt / total:.1f}", f"{ct:.3f}"])
    return md_table(["function", "calls", "own s", "own %", "cumulative s"], rows) + \
        f"\n\n(under cProfile, which slows small calls most: {total:.2f} s of own time in all; the same replay without " \
        f"the profiler: {cpu:.2f} s of CPU)"


_CHILD_REPLAY = """
import asyncio, sys, tempfile, time
from pathlib import Path
from companion.pipeline.core import build_pipeline, run_source
from companion.record import Recorder
from companion.sources import FileSource
with tempfile.TemporaryDirectory() as d:
    t0 = time.process_time()
    rec = Recorder(Path(d) / "t.mcap")
    pipe = build_pipeline(rec)
    asyncio.run(run_source(FileSource(sys.argv[1]), pipe))
    rec.close()
    print(time.process_time() - t0, pipe.stats.duration_s)
"""


def _child_replay(tree: Path, log: Path) -> tuple[float, float]:
    """(CPU s, flight s) of the replay (navigator and record, imports excluded) by the companion of ``tree``."""
    res = subprocess.run([sys.executable, "-c", _CHILD_REPLAY, str(log)], env=dict(os.environ, PYTHONPATH=str(tree)),
                         capture_output=True, text=True, cwd=tempfile.gettempdir(), check=True)
    cpu, dur = res.stdout.split()[-2:]
    return float(cpu), float(dur)


def compare_table(logs: list[Path], other: Path, repeat: int) -> str:
    """This tree's replay against another checkout's (e.g. the commit before a change), child processes in turn."""
    here = Path(__file__).resolve().parents[2]
    rows = []
    for log in logs:
        pairs = [(_child_replay(other, log), _child_replay(here, log)) for _ in range(repeat)]
        b, a = (statistics.median(p[i][0] for p in pairs) for i in (0, 1))
        dur = pairs[0][1][1]
        rows.append([log.name[:40], f"{b:.2f}", f"{a:.2f}", f"{statistics.median(x[0] / y[0] for x, y in pairs):.2f}",
                     f"{dur / b:.0f}", f"{dur / a:.0f}"])
    return md_table(["log", "other CPU s", "this CPU s", "speed-up", "other x real time", "this x real time"], rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--hours", type=float, default=3.0, help="the long replay of the memory table (default 3)")
    ap.add_argument("--skip", nargs="*", default=[], choices=("speed", "memory", "startup", "profile", "parts"))
    ap.add_argument("--compare-tree", type=Path, metavar="DIR",
                    help="also time the replay of another commit's code (git archive COMMIT | tar -x -C DIR) against this one")
    ap.add_argument("--compare-rev", default="the other tree", help="the commit in --compare-tree, for the table's title")
    ap.add_argument("--no-write", action="store_true", help="print only; do not write replay/results/ingest.md")
    args = ap.parse_args()
    logs = args.logs or sorted(SHARED_LOGS.glob("*.bin")) + sorted(SHARED_LOGS.glob("*.tlog"))
    load = os.getloadavg()
    head = (f"Measured {time.strftime('%Y-%m-%d')}, load average {load[0]:.1f} on {os.cpu_count()} cores (other jobs "
            "running); CPU time, so the load matters less than in wall time, but it still slows both sides.\n\n")
    path = results_file("ingest")
    title = "Ingest and replay throughput"
    cmd = (f"    .venv/bin/python -m replay.live.throughput --repeat {args.repeat}"
           + ("" if "memory" in args.skip else f" --hours {args.hours:g}")
           + (f" --skip {' '.join(args.skip)}" if args.skip else "") + "\n\n")
    if "speed" not in args.skip:
        publish("## Speed against pymavlink's raw parse\n\n" + cmd + head +
                f"Both sides in one process, interleaved, {args.repeat} times; CPU s are medians, the ratio "
                "(pymavlink's CPU time / ours for the same file) the median of the pairs. Targets: ratio >= 0.5 and "
                ">= 300x real time with the navigator and the record.\n\n" + speed_table(logs, args.repeat),
                path, "speed", title, write=not args.no_write)
    if "memory" not in args.skip:
        publish("## Memory against flight length\n\n" + cmd + head + "`companion replay` (navigator and record) in "
                "a child process; its peak RSS. Target: the long replay <= 1.2x the 5 min one.\n\n" +
                memory_table(args.hours), path, "memory", title, write=not args.no_write)
    if "startup" not in args.skip:
        publish("## Start-up\n\n" + cmd + head + "Target: import + start-up to READY <= 1 s.\n\n" + startup_table(),
                path, "startup", title, write=not args.no_write)
    if args.compare_tree is not None:
        rev, tree = args.compare_rev, args.compare_tree
        publish(f"## Against commit {rev}\n\n    mkdir -p {tree} && git archive {rev} | tar -x -C {tree}\n"
                f"    .venv/bin/python -m replay.live.throughput --skip speed memory startup profile --compare-tree {tree} "
                f"--compare-rev {rev} --repeat {args.repeat}\n\n" + head + "The replay with navigator and record, each commit's code in a child "
                "process (imports excluded), in turn; CPU s medians, the speed-up the median of the pairs.\n\n" +
                compare_table(logs, args.compare_tree, args.repeat), path, "compare", title, write=not args.no_write)
    if "parts" not in args.skip:
        publish("## Where the time goes, by part\n\n" + cmd + head + parts_table(logs), path, "parts", title,
                write=not args.no_write)
    if "profile" not in args.skip:
        publish("## Where the time goes (log171, replay with navigator and record)\n\n" + cmd + head +
                profile_table(LOG171), path, "profile", title, write=not args.no_write)


if __name__ == "__main__":
    main()
