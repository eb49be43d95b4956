"""Fleet replay throughput: the shared logs repeated to a fleet (links in a temporary folder), replayed by
``companion replay FOLDER`` on 1 and 2 local workers and on a Dask LocalCluster of 2 workers.

    nice -n 5 .venv-test/bin/python -m replay.live.fleet [--copies 20] [--no-write]

Per set-up: wall time, the CPU time of every process involved (the command, its workers, the cluster's; from
``getrusage`` of the children and of this process), flight hours per wall hour and per CPU hour, the largest process's
peak RSS, and every log's exit code as in a replay of its own. Memory against fleet size: the same on 2 local workers
with a fleet of one copy of each log, then ``--copies``. Results in replay/results/ingest.md, section "fleet".
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from companion.shared_data import shared_logs_dir
from replay.harness.results import md_table, publish, results_file

SHARED_LOGS = shared_logs_dir()


def make_fleet(folder: Path, logs: list[Path], copies: int) -> int:
    """``copies`` links to each log in ``folder`` (never copies of the data); returns the number of logs."""
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(copies):
        for log in logs:
            (folder / f"{k:03d}_{log.name}").symlink_to(log.resolve())
    return copies * len(logs)


#: run in a child process of its own, so that its getrusage covers exactly one set-up: the command (and, with
#: "dask", a LocalCluster of N workers started here first); prints CPU s of everything and the largest peak RSS (KiB)
_WRAPPER = """
import resource, subprocess, sys
mode, n, cmd = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
if mode == "dask":
    from dask.distributed import LocalCluster
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        res = subprocess.run(cmd + ["--scheduler", cluster.scheduler_address], capture_output=True, text=True)
else:
    res = subprocess.run(cmd, capture_output=True, text=True)
s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(res.returncode, s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime, max(s.ru_maxrss, c.ru_maxrss))
sys.stderr.write(res.stderr[-500:])
"""


def run_setup(fleet: Path, out: Path, mode: str, workers: int) -> dict:
    """``companion replay FLEET --out OUT -q`` on ``workers`` local workers (mode "local") or on a Dask LocalCluster
    of ``workers`` single-threaded worker processes (mode "dask", its start-up included): wall s, CPU s of every
    process, the largest peak RSS, the summary rows."""
    cmd = [sys.executable, "-m", "companion.cli", "replay", str(fleet), "--out", str(out), "-q"]
    if mode == "local":
        cmd += ["--workers", str(workers)]
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-c", _WRAPPER, mode, str(workers), *cmd], capture_output=True, text=True)
    wall = time.monotonic() - t0
    code, cpu, rss = res.stdout.split()[-3:]
    with open(out / "fleet_summary.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return {"wall_s": wall, "cpu_s": float(cpu), "rss_mib": int(rss) / 1024, "rows": rows, "exit": int(code),
            "stderr": res.stderr}


def _row(label: str, r: dict, expected: dict[str, str]) -> list:
    flight_s = sum(float(x["duration_s"] or 0) for x in r["rows"])
    codes = {Path(x["log"]).name.split("_", 1)[1]: x["exit_code"] for x in r["rows"]}
    same = all(codes.get(k) == v for k, v in expected.items()) and len(r["rows"]) == r["n"]
    return [label, len(r["rows"]), f"{flight_s / 3600:.1f}", f"{r['wall_s']:.0f}", f"{r['cpu_s']:.0f}",
            f"{flight_s / r['wall_s']:.0f}", f"{flight_s / r['cpu_s']:.0f}", f"{r['rss_mib']:.0f}",
            "yes" if same else "NO"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--copies", type=int, default=20, help="links per shared log (default 20: a fleet of 100)")
    ap.add_argument("--skip", nargs="*", default=[], choices=("1", "2", "dask", "memory"))
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    logs = sorted(SHARED_LOGS.glob("*.bin")) + sorted(SHARED_LOGS.glob("*.tlog"))
    load0 = os.getloadavg()[0]
    table, mem = [], []
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        one = d / "one"
        make_fleet(one, logs, 1)
        ref = run_setup(one, d / "ref", "local", 1)  # each log's exit code as replayed alone
        expected = {Path(x["log"]).name.split("_", 1)[1]: x["exit_code"] for x in ref["rows"]}
        fleet = d / "fleet"
        n = make_fleet(fleet, logs, args.copies)
        setups = [("1 local worker", "1", lambda o: run_setup(fleet, o, "local", 1)),
                  ("2 local workers", "2", lambda o: run_setup(fleet, o, "local", 2)),
                  ("Dask LocalCluster, 2 workers", "dask", lambda o: run_setup(fleet, o, "dask", 2))]
        for i, (label, key, run) in enumerate(setups):
            if key in args.skip:
                continue
            r = run(d / f"out{i}")
            r["n"] = n
            table.append(_row(label, r, expected))
            if r["exit"] not in (0, 3):
                print(f"{label}: exit {r['exit']}: {r['stderr']}", file=sys.stderr)
            for p in (d / f"out{i}").glob("*.mcap"):
                p.unlink()  # the records of 100 logs are 2.5 GB: not kept
        if "memory" not in args.skip:
            for label, folder, count in (("1 copy", one, len(logs)), (f"{args.copies} copies", fleet, n)):
                r = run_setup(folder, d / f"mem{count}", "local", 2)
                r["n"] = count
                mem.append([f"{label} ({count} logs)", f"{r['wall_s']:.0f}", f"{r['cpu_s']:.0f}", f"{r['rss_mib']:.0f}"])
                for p in (d / f"mem{count}").glob("*.mcap"):
                    p.unlink()
    load1 = os.getloadavg()[0]
    cmd = f"    nice -n 5 .venv-test/bin/python -m replay.live.fleet --copies {args.copies}\n\n"
    head = (f"Measured {time.strftime('%Y-%m-%d')} on {os.cpu_count()} cores, 1-min load average {load0:.1f} at the "
            f"start and {load1:.1f} at the end (other jobs running: wall times include waiting for them; CPU times "
            "do not).\n\n")
    text = ("## Fleet replay (`companion replay FOLDER`)\n\n" + cmd + head +
            f"The {len(logs)} shared logs, {args.copies} links to each in a temporary folder; `companion replay FOLDER "
            "-q` with the navigator and one MCAP per log. CPU s: every process involved (the command, its workers, "
            "the cluster's scheduler and workers, their start-up). x real time: flight time / wall time, and / CPU "
            "time. Peak RSS: the largest single process. Same exit codes: every log's as when the 5 logs are "
            "replayed once.\n\n" +
            md_table(["set-up", "logs", "flight h", "wall s", "CPU s", "x real time (wall)", "x real time (CPU)",
                      "peak RSS MiB", "same exit codes"], table))
    if mem:
        text += ("\n\nMemory against fleet size (2 local workers): the largest process's peak RSS.\n\n" +
                 md_table(["fleet", "wall s", "CPU s", "peak RSS MiB"], mem))
    publish(text, results_file("ingest"), "fleet", "Ingest and replay throughput", write=not args.no_write)


if __name__ == "__main__":
    main()
