"""Many logs at once: ``companion replay DIR`` (or several logs) replays each log into its own MCAP, on a local process
pool by default or on a Dask cluster (``--scheduler tcp://HOST:8786``), and writes a fleet summary (CSV and markdown).

Each log is one job (companion.replay_job.replay_job) in a worker: a bad log is a row with its exit code and reason,
never the end of the run. At most two jobs per worker are in flight, and a finished job's row is all that comes back,
so the coordinator's memory does not grow with the fleet (the rows are ~300 bytes each). Rows come back as jobs
finish; the summary lists them in the order the logs were given. On a Dask cluster the logs and the output directory
must be at the same paths on every worker (a shared file system), and the workers need this package installed.
"""

from __future__ import annotations

import csv
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from companion.replay_job import EXIT_DAMAGED, EXIT_ERROR, EXIT_OK, replay_job

#: what a folder of logs holds: dataflash and telemetry logs by their usual names (recognised by content when read)
LOG_SUFFIXES = (".bin", ".tlog")
SUMMARY_NAME = "fleet_summary"
COLUMNS = ("log", "exit_code", "duration_s", "vehicle", "firmware", "gnss_hz", "imu_hz", "gnss_fixes", "gnss_gaps",
           "gnss_gap_s", "stream_gaps", "events", "warnings", "cpu_s", "record", "error")


def find_logs(paths: Iterable[str | os.PathLike]) -> list[Path]:
    """The logs named, a folder's logs (``*.bin``, ``*.tlog``, any case, its sub-folders too) in name order; a path
    given twice is replayed once (links to one file are different logs: a fleet may be made of links). Raises
    FileNotFoundError for a path that does not exist."""
    out: list[Path] = []
    seen: set[Path] = set()  # absolute, links not followed
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(q for q in p.rglob("*") if q.suffix.lower() in LOG_SUFFIXES and q.is_file())
        elif p.exists():
            found = [p]
        else:
            raise FileNotFoundError(f"{p}: no such file or folder")
        for q in found:
            key = Path(os.path.abspath(q))
            if key not in seen:
                seen.add(key)
                out.append(q)
    return out


def record_paths(logs: list[Path], out_dir: Path) -> list[Path]:
    """``OUT/<log name>.mcap`` per log; logs of the same name (from different folders) get ``-2``, ``-3``, ..."""
    used: dict[str, int] = {}
    out = []
    for log in logs:
        n = used[log.stem] = used.get(log.stem, 0) + 1
        out.append(out_dir / (f"{log.stem}.mcap" if n == 1 else f"{log.stem}-{n}.mcap"))
    return out


def _local_rows(jobs: list[tuple], workers: int) -> Iterator[tuple[int, dict]]:
    """(job index, row) as jobs finish on a pool of ``workers`` processes (1: in this process)."""
    if workers <= 1:
        for i, args in enumerate(jobs):
            yield i, replay_job(*args)
        return
    import concurrent.futures as cf

    # the platform's start method (fork on Linux: the workers are this process's children, their CPU time in its
    # rusage; the coordinator holds nothing large to copy)
    with cf.ProcessPoolExecutor(workers) as pool:
        yield from _bounded(lambda args: pool.submit(replay_job, *args), jobs, 2 * workers,
                            lambda fs: cf.wait(fs, return_when=cf.FIRST_COMPLETED)[0], lambda f: f.result())


def _dask_rows(jobs: list[tuple], address: str) -> Iterator[tuple[int, dict]]:
    """(job index, row) as jobs finish on the Dask cluster whose scheduler is at ``address``."""
    from companion.extras import require

    distributed = require("dask.distributed", "dask", "replay on a Dask cluster (--scheduler)")
    with distributed.Client(address) as client:
        slots = 2 * max(1, len(client.scheduler_info().get("workers", {})))

        yield from _bounded(lambda args: client.submit(replay_job, *args, pure=False), jobs, slots,
                            lambda fs: distributed.wait(list(fs), return_when="FIRST_COMPLETED").done,
                            lambda f: f.result())


def _bounded(submit: Callable, jobs: list[tuple], slots: int, wait: Callable, result: Callable) -> Iterator[tuple[int, dict]]:
    """Keep at most ``slots`` jobs in flight; yield (index, row) as they finish. A job that fails in the machinery
    (a worker killed, out of memory) is a row with exit code 2 and the reason."""
    pending: dict[Any, int] = {}
    it = iter(enumerate(jobs))
    try:
        while True:
            while len(pending) < slots:
                nxt = next(it, None)
                if nxt is None:
                    break
                pending[submit(nxt[1])] = nxt[0]
            if not pending:
                return
            for f in wait(pending.keys()):
                i = pending.pop(f)
                try:
                    row = result(f)
                except Exception as err:  # noqa: BLE001 - the worker died: the log's row says so, the rest go on
                    log, out = jobs[i][0], jobs[i][1]
                    row = {"log": str(log), "record": str(out), "exit_code": EXIT_ERROR,
                           "error": f"worker failed: {type(err).__name__}: {err}"}
                yield i, row
    finally:
        for f in pending:
            f.cancel()


def replay_fleet(logs: list[Path], out_dir: Path, *, navigator: bool = True, workers: int = 1,
                 scheduler: str | None = None, on_row: Callable[[dict], None] | None = None) -> list[dict]:
    """Replay every log into ``out_dir``; the rows in the order of ``logs`` (a log whose job never ran, the run being
    interrupted, has no row). ``on_row(row)`` is called as each finishes (a progress bar)."""
    outs = record_paths(logs, out_dir)
    jobs = [(str(log), str(out), navigator) for log, out in zip(logs, outs)]
    rows: dict[int, dict] = {}
    source = _dask_rows(jobs, scheduler) if scheduler else _local_rows(jobs, workers)
    try:
        for i, row in source:
            rows[i] = row
            if on_row is not None:
                on_row(row)
    finally:
        source.close()
    return [rows[i] for i in sorted(rows)]


def fleet_exit_code(rows: list[dict], n_logs: int) -> int:
    """0: every log replayed cleanly; 2: none was replayed; 3: some failed or were damaged (their rows say which)."""
    codes = [r.get("exit_code", EXIT_ERROR) for r in rows]
    if n_logs and codes.count(EXIT_ERROR) == n_logs:
        return EXIT_ERROR
    return EXIT_OK if len(codes) == n_logs and all(c == EXIT_OK for c in codes) else EXIT_DAMAGED


def _cell(v: Any) -> str:
    if v is None:
        return ""
    return f"{v:g}" if isinstance(v, float) else str(v)


def write_summary(rows: list[dict], out_dir: Path, name: str = SUMMARY_NAME) -> tuple[Path, Path]:
    """``OUT/fleet_summary.csv`` and ``.md``: one row per log (COLUMNS), the markdown with a totals line."""
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, md_path = out_dir / f"{name}.csv", out_dir / f"{name}.md"
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in COLUMNS])
    md_cols = [c for c in COLUMNS if c != "record"]
    lines = ["| " + " | ".join(md_cols) + " |", "|" + "---|" * len(md_cols)]
    for r in rows:
        cells = [_cell(r.get(c)).replace("|", "\\|").replace("\n", " ") for c in md_cols]
        cells[0] = Path(cells[0]).name
        lines.append("| " + " | ".join(cells) + " |")
    ok = sum(r.get("exit_code") == EXIT_OK for r in rows)
    dmg = sum(r.get("exit_code") == EXIT_DAMAGED for r in rows)
    hours = sum(r.get("duration_s") or 0.0 for r in rows) / 3600
    cpu = sum(r.get("cpu_s") or 0.0 for r in rows)
    lines += ["", f"{len(rows)} logs: {ok} replayed, {dmg} damaged but replayed, {len(rows) - ok - dmg} not replayed; "
                  f"{hours:.2f} h of flight in {cpu:.1f} s of the workers' CPU time."]
    md_path.write_text("\n".join(lines) + "\n")
    return csv_path, md_path


def run_fleet_command(paths: list[str], out_dir: Path, *, navigator: bool, workers: int | None, scheduler: str | None,
                      quiet: bool) -> int:
    """``companion replay`` of several logs or folders: a progress bar over the fleet, a line per log with a problem,
    the summary files; returns the exit code (fleet_exit_code; 130 when interrupted). ValueError: unusable arguments."""
    if not paths:
        raise ValueError("a fleet replay needs logs or folders of logs")
    try:
        logs = find_logs(paths)
    except FileNotFoundError as err:
        raise ValueError(str(err)) from None
    if not logs:
        raise ValueError(f"no logs (*.bin, *.tlog) in {', '.join(map(str, paths))}")
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"--out {out_dir}: a fleet replay writes into a folder, and this is a file")
    workers = workers if workers is not None else (os.cpu_count() or 1)
    where = f"the Dask cluster at {scheduler}" if scheduler else f"{workers} local worker(s)"
    from tqdm import tqdm

    # disable=None: shown on a terminal, silent when stderr is a file or a pipe
    bar = tqdm(total=len(logs), desc="fleet", unit="log", file=sys.stderr, disable=True if quiet else None, leave=False)

    done: list[dict] = []

    def on_row(row: dict) -> None:
        done.append(row)
        bar.update(1)
        if row.get("exit_code") != EXIT_OK and not quiet:
            bar.write(f"{Path(row['log']).name}: exit {row.get('exit_code')} {row.get('error') or '(damaged log)'}",
                      file=sys.stderr)

    interrupted = False
    rows: list[dict] = []
    try:
        rows = replay_fleet(logs, out_dir, navigator=navigator, workers=workers, scheduler=scheduler, on_row=on_row)
    except KeyboardInterrupt:  # the summary of the logs done so far
        interrupted = True
        order = {str(log): i for i, log in enumerate(logs)}
        rows = sorted(done, key=lambda r: order.get(r["log"], len(order)))
    finally:
        bar.close()
    csv_path, md_path = write_summary(rows, out_dir)
    if not quiet:
        ok = sum(r.get("exit_code") == EXIT_OK for r in rows)
        print(f"fleet        {len(logs)} logs on {where}: {ok} replayed cleanly, {len(rows) - ok} with problems"
              + (", interrupted" if interrupted else ""))
        print(f"records      {out_dir}/")
        print(f"summary      {csv_path}, {md_path}")
    return 130 if interrupted else fleet_exit_code(rows, len(logs))
