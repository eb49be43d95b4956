"""Live-path benchmark: GPS_INPUT latency, CPU and memory of `companion run` against the simulated vehicle.

    nice -n 10 .venv/bin/python replay/live/latency.py --duration-s 1800 --out replay/results/live.md

Starts ``companion sim`` (200 m circuits looped, 10 Hz GNSS, 50 Hz IMU, 10 Hz ATTITUDE, real time) on
loopback TCP and ``companion run --inject inject`` against it as separate processes. After ``--warmup-s``
it samples the companion's CPU time and RSS from /proc every 10 s; at the end it stops the companion with
SIGTERM and reads the latency the runtime measured itself (arrival of the bytes of the GPS_RAW_INT or
RAW_IMU whose processing produced a GPS_INPUT -> return of the socket write) from the MCAP metadata.
Targets: latency p99 <= 10 ms idle and <= 50 ms with both cores busy (``--stress-cpus 2`` runs
``stress-ng --cpu 2`` beside it for the whole run); CPU <= 2 % of one core idle, <= 15 % beside stress-ng; RSS
flat. ``--out`` writes the table as its own section (idle, or stress-ng with N CPU workers) of the results file.
"""

from __future__ import annotations

import argparse
import os
import platform
import signal
import subprocess
import sys
import time
from pathlib import Path

from replay.live import free_port

REPO = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "companion.cli"]


def proc_sample(pid: int) -> tuple[float, float]:
    """(CPU seconds user+system, RSS MiB) of a process."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    cpu = (int(fields[11]) + int(fields[12])) / tick
    rss = 0.0
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                rss = int(line.split()[1]) / 1024.0
    return cpu, rss


def main_thread_cpu_s(pid: int) -> float:
    """CPU seconds (user+system) of a process's main thread: the companion's event loop and pipeline (the other
    threads: the link's reader, mostly)."""
    with open(f"/proc/{pid}/task/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=1800.0, help="measured time after the warm-up (default 1800)")
    ap.add_argument("--warmup-s", type=float, default=60.0)
    ap.add_argument("--out", type=Path, default=None, help="write the markdown table here too")
    ap.add_argument("--workdir", type=Path, default=Path("out/latency"))
    ap.add_argument("--stress-cpus", type=int, default=0, metavar="N",
                    help="run `stress-ng --cpu N` (Debian's stress-ng) beside the companion for the whole run")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="passed on to `companion run --set` (e.g. record.segment_s=600)")
    args = ap.parse_args()
    from companion.record import summarize

    args.workdir.mkdir(parents=True, exist_ok=True)
    stress = None
    if args.stress_cpus:
        import shutil

        if shutil.which("stress-ng") is None:
            print("latency: --stress-cpus needs stress-ng (apt-get install stress-ng)", file=sys.stderr)
            return 2
        stress = subprocess.Popen(["stress-ng", "--cpu", str(args.stress_cpus), "--quiet"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    port = free_port()
    sim = subprocess.Popen(
        [*CLI, "sim", "--profile", "circuit", "--loops", "0", "--gnss-hz", "10", "--imu-hz", "50",
         "--listen", f"tcpin:127.0.0.1:{port}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    sim.stdout.readline()
    cmd, label = CLI, "companion run"
    mcap = args.workdir / "live.mcap"
    comp = subprocess.Popen(
        [*cmd, "run", "--connect", f"tcp:127.0.0.1:{port}", "--inject", "inject", "--out", str(mcap),
         *[a for kv in args.set for a in ("--set", kv)]],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    samples = []
    load0 = os.getloadavg()[0]
    try:
        time.sleep(args.warmup_s)
        t0 = time.monotonic()
        cpu0, rss0 = proc_sample(comp.pid)
        loop_cpu0 = main_thread_cpu_s(comp.pid)
        samples.append((0.0, cpu0, rss0))
        while time.monotonic() - t0 < args.duration_s:
            time.sleep(min(10.0, args.duration_s - (time.monotonic() - t0) + 0.01))
            cpu, rss = proc_sample(comp.pid)
            samples.append((time.monotonic() - t0, cpu, rss))
            loop_cpu = main_thread_cpu_s(comp.pid)
            print(f"\r{samples[-1][0]:7.0f} s  CPU {100 * (cpu - cpu0) / samples[-1][0]:5.1f} %  RSS {rss:6.1f} MiB",
                  end="", file=sys.stderr, flush=True)
        print(file=sys.stderr)
    finally:
        comp.send_signal(signal.SIGTERM)
        out, err = comp.communicate(timeout=60)
        sim.send_signal(signal.SIGTERM)
        sim.communicate(timeout=30)
        if stress is not None:
            os.killpg(stress.pid, signal.SIGTERM)
            stress.wait(30)
    if comp.returncode != 0:
        print(err, file=sys.stderr)
        return 1
    wall = samples[-1][0]
    cpu_pct = 100.0 * (samples[-1][1] - samples[0][1]) / wall
    loop_pct = 100.0 * (loop_cpu - loop_cpu0) / wall
    if not mcap.exists():  # record.segment_s: the run's metadata is in the last segment
        mcap = sorted(args.workdir.glob(f"{mcap.stem}-*.mcap"))[-1]
    summary = summarize(mcap)
    meta = summary.metadata_dict("runtime")
    sent = int(summary.metadata_dict("Injector")["sent"])
    total_s = wall + args.warmup_s
    rss_max = max(s[2] for s in samples)
    load_txt = f"`stress-ng --cpu {args.stress_cpus}` running beside it" if args.stress_cpus else "no load added"
    lines = [
        f"Measured {wall / 60:.1f} min after a {args.warmup_s:g} s warm-up ({label}, {load_txt}; simulated vehicle: 200 m "
        f"circuits, 10 Hz GNSS, 50 Hz IMU, 10 Hz ATTITUDE, loopback TCP); {platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}; 1-min load average {load0:.1f} at start, "
        f"{os.getloadavg()[0]:.1f} at end (other work shares the machine: latency tails include its scheduling).",
        "",
        "| quantity | value | target |",
        "|---|---|---|",
    ]
    for trig in ("RAW_IMU", "GPS_RAW_INT", "all"):
        if f"latency.{trig}.n" in meta:
            lines.append(
                f"| latency {trig} -> GPS_INPUT (n = {meta[f'latency.{trig}.n']}) | p50 {float(meta[f'latency.{trig}.p50_ms']):.2f} ms, "
                f"p99 {float(meta[f'latency.{trig}.p99_ms']):.2f} ms | p99 <= {50 if args.stress_cpus else 10} ms |"
            )
    lines += [
        f"| CPU of the companion process | {cpu_pct:.1f} % of one core | <= {15 if args.stress_cpus else 2} % |",
        f"| of which the event loop's thread / the others (the link's reader) | {loop_pct:.1f} % / "
        f"{cpu_pct - loop_pct:.1f} % | - |",
        f"| RSS at start / end / max | {samples[0][2]:.1f} / {samples[-1][2]:.1f} / {rss_max:.1f} MiB | flat |",
        f"| GPS_INPUT sent | {sent} in {total_s:.0f} s ({sent / total_s:.1f} Hz) | >= 5 Hz |",
    ]
    text = "\n".join(lines)
    print(text)
    if args.out:
        from replay.harness.results import write_section

        key = f"latency-stress{args.stress_cpus}" if args.stress_cpus else "latency-idle"
        title = f"With `stress-ng --cpu {args.stress_cpus}`" if args.stress_cpus else "No load added"
        write_section(args.out, key,
                      f"## {title}\n\n"
                      f"Command: `.venv/bin/python -m replay.live.latency --duration-s {args.duration_s:g} --warmup-s {args.warmup_s:g} "
                      f"--out {args.out}{' --stress-cpus %d' % args.stress_cpus if args.stress_cpus else ''}"
                      f"{''.join(' --set ' + kv for kv in args.set)}`\n\n"
                      + text + "\n\nRSS samples (s, MiB): "
                      + ", ".join(f"{s[0]:.0f}:{s[2]:.1f}" for s in samples[:: max(1, len(samples) // 20)]) + "\n",
                      "Live companion: GPS_INPUT latency, CPU, memory")
    return 0


if __name__ == "__main__":
    sys.exit(main())
