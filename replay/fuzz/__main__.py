"""Fuzz benchmark: N mutated real logs through ``companion replay`` (and the live-link scenarios), outcome table.

    nice -n 10 .venv/bin/python -m replay.fuzz --mutants 2000 --seed 0 --jobs 2
    .venv/bin/python -m replay.fuzz --live-only                 # the live-link scenarios alone
    .venv/bin/python -m replay.fuzz --seed 0 --only 123 --keep out/fuzz   # rebuild and rerun one mutant

Prints the table per mutation kind (count, ok, hangs, tracebacks, bad exit, stderr, time, memory, unreadable
MCAP, input changed) and writes ``replay/results/fuzz.md`` (the section of this run is replaced; the live
section is kept unless ``--live`` runs it again). Every outcome goes to ``--jsonl`` as one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections import defaultdict
from pathlib import Path

from replay.fuzz.campaign import measure_baselines, mutants, run_campaign
from replay.fuzz.logs import clean_inputs, shared_logs_dir
from replay.fuzz.mutate import KINDS
from replay.fuzz.properties import COLUMNS, outcome_rows

TITLE = "# Fault tolerance: mutated logs through `companion replay`, a hostile live link against `companion run`\n\n"


def _results_file() -> Path:
    from replay.harness.results import results_file

    return results_file("fuzz")


def _write(key: str, text: str, path: Path) -> None:
    from replay.harness.results import write_section

    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(TITLE)
    write_section(path, key, text, TITLE.strip("# \n"))


def _table(header, rows) -> str:
    from replay.harness.results import md_table

    return md_table(list(header), rows)


class Load:
    """1-minute load average samples while the benchmark runs."""

    def __init__(self) -> None:
        self.samples = [os.getloadavg()[0]]

    def sample(self) -> None:
        self.samples.append(os.getloadavg()[0])

    def text(self) -> str:
        s = self.samples
        return f"1-min load average {s[0]:.1f} at start, {s[-1]:.1f} at end, mean {sum(s) / len(s):.1f}, max {max(s):.1f}"


def _examples(outcomes: list[dict], per: int = 2) -> str:
    """A few failing mutants per (kind, violation) with what went wrong, to rebuild with --only."""
    seen: dict[tuple[str, str], int] = defaultdict(int)
    lines = []
    for o in outcomes:
        for w in o["violations"]:
            key = (o["kind"], w)
            if seen[key] >= per:
                continue
            seen[key] += 1
            note = next((n for n in o["notes"] if n.startswith(w)), w)
            lines.append(f"- `{o['kind']}` #{o['index']} on {o['input']}: {o['desc']} -> {note}")
    return "\n".join(lines) if lines else "(none)"


def run_replay_fuzz(a, load: Load) -> tuple[list[dict], str]:
    inputs = clean_inputs(a.size)
    kinds = a.kinds.split(",") if a.kinds else list(KINDS)
    workdir = Path(a.workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    if a.mode == "fork":
        from replay.fuzz.runner import preload

        preload()
    t0 = time.monotonic()
    print(f"clean inputs: {len(inputs)} ({a.size} bytes at most each); measuring baselines ...", file=sys.stderr)
    base = measure_baselines(inputs, mode=a.mode, repeat=3, workdir=workdir)
    indices = a.only if a.only else range(a.mutants)
    jsonl = open(a.jsonl, "w") if a.jsonl else None  # noqa: SIM115
    n = [0]

    def on_outcome(o: dict) -> None:
        n[0] += 1
        load.sample()
        if jsonl:
            jsonl.write(json.dumps(o) + "\n")
            jsonl.flush()
        if o["violations"] or a.only:
            print(f"[{n[0]}] #{o['index']} {o['kind']} {o['input']}: {o['desc'][:100]} -> exit {o['exit']} "
                  f"{o['wall_s']:.1f} s {o['maxrss_mb']:.0f} MiB {'; '.join(o['notes'])[:300]}", file=sys.stderr, flush=True)
        elif n[0] % 50 == 0:
            print(f"[{n[0]}] ...", file=sys.stderr, flush=True)

    keep = Path(a.keep) if a.keep else None
    outcomes = run_campaign(mutants(indices, a.seed, inputs, kinds), base, mode=a.mode, jobs=a.jobs, workdir=workdir,
                            keep=keep, on_outcome=on_outcome)
    if jsonl:
        jsonl.close()
    wall = time.monotonic() - t0
    header = ["kind", *COLUMNS]
    by_kind = _table(header, outcome_rows(outcomes, "kind"))
    by_input = _table(["input", *COLUMNS], outcome_rows(outcomes, "input"))
    base_rows = [[c.name, c.kind, len(c.data), base[c.name].returncode, round(base[c.name].wall_s, 2),
                  round(base[c.name].cpu_s, 2), round(base[c.name].maxrss_kb / 1024, 1)] for c in inputs]
    cmd = " ".join(["nice -n 10 .venv/bin/python -m replay.fuzz", f"--mutants {a.mutants}", f"--seed {a.seed}",
                    *([f"--jobs {a.jobs}"] if a.mode == "subprocess" else [f"--mode {a.mode}"]),
                    *([f"--size {a.size}"] if a.size != 200_000 else []), *([f"--kinds {a.kinds}"] if a.kinds else [])])
    text = "\n".join([
        "## Mutated logs through `companion replay`",
        "",
        "Command (repository root):",
        "",
        f"    {cmd}",
        "",
        f"{len(outcomes)} mutants ({len(kinds)} kinds, dealt round-robin) of {len(inputs)} clean inputs cut from the "
        f"shared real logs ({shared_logs_dir()}), each replayed as `companion replay MUTANT --out OUT.mcap --quiet` "
        f"({'a subprocess' if a.mode == 'subprocess' else 'a forked child of the benchmark'}), "
        f"{a.jobs if a.mode == 'subprocess' else 1} at a time; "
        f"{wall / 60:.1f} min wall. {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
        f"{load.text()} (other jobs share the machine).",
        "",
        "Properties (replay/fuzz/properties.py): exit 0/2/3 (exit 0 for an input cut mid-record is a bad exit); no "
        "traceback; at most one stderr line with exit 2; CPU time <= 3 x the clean input's + 5 s; peak RSS <= 2 x "
        "the clean input's; a readable, finalised MCAP (summary, chunk CRCs, every message) with exit 0 or 3; the "
        "input file unchanged. A run is killed 5 s after its time limit (hang) or at 3 x the clean peak RSS. A mutant "
        "can break several properties; `ok` counts the mutants that broke none.",
        "",
        "### Outcome per mutation kind",
        "",
        by_kind,
        "",
        "### Outcome per clean input",
        "",
        by_input,
        "",
        "### Clean inputs (baselines: median of 3 runs)",
        "",
        _table(["input", "format", "bytes", "exit", "wall s", "CPU s", "peak RSS MiB"], base_rows),
        "",
        "### Examples (rebuild one with `--seed S --only INDEX --keep DIR`)",
        "",
        _examples(outcomes),
    ])
    return outcomes, text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mutants", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2, help="replays at a time (subprocess mode)")
    ap.add_argument("--mode", choices=("subprocess", "fork"), default="subprocess")
    ap.add_argument("--size", type=int, default=200_000, help="bytes of each clean input (prefix or window)")
    ap.add_argument("--kinds", default="", help=f"comma-separated subset of: {', '.join(KINDS)}")
    ap.add_argument("--only", type=int, nargs="*", help="run only these mutant indices")
    ap.add_argument("--keep", default="", help="write the mutants that broke a property to this directory")
    ap.add_argument("--workdir", default="out/fuzz/work")
    ap.add_argument("--jsonl", default="out/fuzz/outcomes.jsonl", help="every outcome as a JSON line ('' for none)")
    ap.add_argument("--out", type=Path, default=None, help="results file (default replay/results/fuzz.md)")
    ap.add_argument("--no-write", action="store_true", help="print only, leave the results file alone")
    ap.add_argument("--live", action="store_true", help="also run the live-link scenarios")
    ap.add_argument("--live-only", action="store_true", help="only the live-link scenarios")
    ap.add_argument("--settings", action="store_true",
                    help="also the settings-and-files cases (replay/fuzz/settings.py; with --live-only: those too)")
    a = ap.parse_args(argv)
    if a.jsonl:
        Path(a.jsonl).parent.mkdir(parents=True, exist_ok=True)
    out = a.out or _results_file()
    load = Load()
    if not a.live_only:
        outcomes, text = run_replay_fuzz(a, load)
        print(text)
        if not a.no_write and not a.only:
            _write("replay", text, out)
    if a.live or a.live_only:
        from replay.fuzz.link import run_live_fuzz

        cmd = "nice -n 10 .venv/bin/python -m replay.fuzz " + " ".join(argv if argv is not None else sys.argv[1:])
        text = run_live_fuzz(load=Load(), workdir=Path(a.workdir), seed=a.seed, command=cmd.strip())
        print(text)
        if not a.no_write:
            _write("live", text, out)
    if a.settings:
        from replay.fuzz.settings import run_settings_fuzz

        cmd = "nice -n 10 .venv/bin/python -m replay.fuzz " + " ".join(argv if argv is not None else sys.argv[1:])
        text = run_settings_fuzz(Path(a.workdir), command=cmd.strip())
        print(text)
        if not a.no_write:
            _write("settings", text, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
