"""What every ``companion replay`` of a damaged log must satisfy (the fault-tolerance requirements), and the table.

Per run, against the clean input it was made from (measured the same way, on the same machine, same run):

* ``hang``: killed at the hard time-out (the run did not end by itself);
* ``traceback``: a Python traceback on stderr (also "Exception in thread");
* ``bad_exit``: an exit code other than 0 (done), 2 (unusable input) or 3 (damaged: everything readable
  replayed); killed by a signal counts here too; so does exit 0 for an input known to be cut mid-record;
* ``stderr``: exit 2 with more than one line on stderr (the one-line error promise);
* ``time``: more than 3 x the clean input's time + 5 s; judged on CPU time (the work done: wall time on a
  shared machine also measures the other jobs), the wall time is kept beside it;
* ``memory``: peak RSS above 2 x the clean input's (or killed at the memory cap); for a forked child, its own
  growth beyond the pages it shares with its parent, + 16 MiB of slack;
* ``mcap``: exit 0 or 3 without a readable MCAP (the mcap reader opens it, the summary is present, every
  chunk's CRC checks and every message reads back);
* ``input``: the input file changed (hash before and after).
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field
from pathlib import Path

from replay.fuzz.runner import RunResult

VIOLATIONS = ("hang", "traceback", "bad_exit", "stderr", "time", "memory", "mcap", "input")
OK_EXITS = (0, 2, 3)
TRACEBACK_MARKS = ("Traceback (most recent call last)", "Exception in thread")


@dataclass(frozen=True)
class Baseline:
    """A clean input's run: the yardstick of its mutants."""

    wall_s: float
    cpu_s: float
    maxrss_kb: int  # own peak RSS (RunResult.own_rss_kb): a forked child's shared pages left out
    returncode: int = 0
    forked: bool = False

    @property
    def time_limit_s(self) -> float:
        return 3.0 * self.wall_s + 5.0

    @property
    def mem_limit_kb(self) -> int:
        """2 x clean; a forked child's own memory is only its growth, so 16 MiB of slack on top."""
        return 2 * self.maxrss_kb + (16 * 1024 if self.forked else 0)

    @staticmethod
    def of(results: list[RunResult]) -> Baseline:
        """Median of repeated clean runs."""
        return Baseline(
            statistics.median(r.wall_s for r in results),
            statistics.median(r.cpu_s for r in results),
            int(statistics.median(r.own_rss_kb for r in results)),
            results[0].returncode,
            results[0].shared_kb > 0,
        )

    @staticmethod
    def combined(parts: list[Baseline]) -> Baseline:
        """Of two inputs end to end (concatenation): their times add up, memory is the larger."""
        return Baseline(sum(p.wall_s for p in parts), sum(p.cpu_s for p in parts), max(p.maxrss_kb for p in parts),
                        0, parts[0].forked)


def check_mcap(path: Path) -> str:
    """"" when ``path`` is a readable, finalised MCAP; else why not."""
    from mcap.reader import make_reader

    if not path.exists():
        return "no MCAP written"
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return "no summary section"
            n = sum(1 for _ in reader.iter_messages(log_time_order=False))
            if n != summary.statistics.message_count:
                return f"{n} messages read back, the summary says {summary.statistics.message_count}"
    except Exception as exc:  # noqa: BLE001 - any failure to read is the finding
        return f"unreadable: {type(exc).__name__}: {exc}"
    return ""


@dataclass
class Verdict:
    violations: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.violations

    def add(self, what: str, note: str) -> None:
        if what not in self.violations:
            self.violations.append(what)
        self.notes.append(f"{what}: {note}")


def judge(res: RunResult, base: Baseline, *, out: Path, hash_before: str, hash_after: str,
          damaged: bool = False) -> Verdict:
    v = Verdict()
    err = res.stderr
    if res.killed == "timeout":
        v.add("hang", f"killed after {res.wall_s:.1f} s (clean {base.wall_s:.2f} s)")
    if res.killed == "memory":
        v.add("memory", f"killed at the memory cap ({res.own_rss_kb / 1024:.0f} MiB peak, clean {base.maxrss_kb / 1024:.0f})")
    for mark in TRACEBACK_MARKS:
        if mark in err:
            last = [line for line in err.strip().splitlines() if line.strip()][-1:]
            v.add("traceback", last[0][:200] if last else mark)
            break
    if not res.killed:
        if res.returncode not in OK_EXITS:
            v.add("bad_exit", f"exit {res.returncode}")
        elif damaged and res.returncode == 0:
            v.add("bad_exit", "exit 0 for an input cut mid-record (must be 3)")
        if res.returncode == 2 and len(err.strip().splitlines()) > 1:
            v.add("stderr", f"{len(err.strip().splitlines())} lines on stderr with exit 2")
        if res.cpu_s > 3.0 * base.cpu_s + 5.0:
            v.add("time", f"CPU {res.cpu_s:.1f} s > 3 x {base.cpu_s:.2f} + 5 s (wall {res.wall_s:.1f} s)")
        if res.own_rss_kb > base.mem_limit_kb:
            v.add("memory", f"peak {res.own_rss_kb / 1024:.0f} MiB > 2 x {base.maxrss_kb / 1024:.0f} MiB")
        if res.returncode in (0, 3):
            why = check_mcap(out)
            if why:
                v.add("mcap", why)
    if hash_after != hash_before:
        v.add("input", "the input file was modified or removed")
    return v


# ----------------------------------------------------------------------------------------------- table
COLUMNS = ("mutants", "ok", "hangs", "tracebacks", "bad exit", "stderr > 1 line", "time", "memory",
           "unreadable MCAP", "input changed")
_COL_OF = dict(zip(VIOLATIONS, COLUMNS[2:]))


def outcome_rows(outcomes: list[dict], key: str = "kind") -> list[list]:
    """One row per ``key`` value (kind, or input) and a total: counts of each violation."""
    groups: dict[str, list[dict]] = {}
    for o in outcomes:
        groups.setdefault(o[key], []).append(o)
    rows = []
    for name in list(groups) + ["**all**"]:
        os_ = outcomes if name == "**all**" else groups[name]
        row = [name, len(os_), sum(1 for o in os_ if not o["violations"])]
        row += [sum(1 for o in os_ if w in o["violations"]) for w in VIOLATIONS]
        rows.append(row)
    return rows
