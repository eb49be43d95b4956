"""Proof that a speed change left the output alone: every MCAP message of ``companion replay`` of each shared log, by
this tree's code and by another checkout's, compared payload by payload (topic, log time, bytes).

    mkdir -p /tmp/base && git archive REV | tar -x -C /tmp/base
    .venv-test/bin/python -m replay.live.same_output --other-tree /tmp/base --other-rev REV [LOG ...]

Each side runs ``python -m companion.cli replay LOG --out X.mcap --quiet`` in a child process with its tree first on
``PYTHONPATH``. A payload that differs in bytes but is JSON equal in value (every number the same float) is counted
apart (float spelling); any other difference, or a different message count, is a failure (exit status 1). The
metadata records (CPU times, versions) are not compared.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from companion.record.inspect import iter_payloads
from companion.shared_data import shared_logs_dir
from replay.harness.results import md_table, publish, results_file

HERE = Path(__file__).resolve().parents[2]


def replay_payloads(tree: Path, log: Path, out: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log_time_ns, payload) of every message of the replay of ``log`` by the companion in ``tree``."""
    res = subprocess.run([sys.executable, "-m", "companion.cli", "replay", str(log), "--out", str(out), "--quiet"],
                         env=dict(os.environ, PYTHONPATH=str(tree)), cwd=tempfile.gettempdir(),
                         stdout=subprocess.DEVNULL)
    if res.returncode not in (0, 3):  # 3: a truncated log, replayed and recorded as far as it reads
        raise RuntimeError(f"replay of {log.name} by {tree} exited {res.returncode}")
    return list(iter_payloads(out))


def _equal_in_value(a: bytes, b: bytes) -> bool:
    try:
        return json.loads(a) == json.loads(b)  # floats parse to the same double only if equal in value
    except ValueError:
        return False


def compare(log: Path, other: Path) -> list:
    with tempfile.TemporaryDirectory() as d:
        pa = replay_payloads(other, log, Path(d) / "other.mcap")
        pb = replay_payloads(HERE, log, Path(d) / "this.mcap")
    same = spelling = differ = 0
    first = ""
    for x, y in zip(pa, pb):
        if x == y:
            same += 1
        elif x[:2] == y[:2] and _equal_in_value(x[2], y[2]):
            spelling += 1
        else:
            differ += 1
            first = first or f"{y[0]} at {y[1]} ns"
    differ += abs(len(pa) - len(pb))
    return [log.name[:40], len(pa), len(pb), same, spelling, differ, first or "-"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--other-tree", type=Path, required=True, metavar="DIR")
    ap.add_argument("--other-rev", default="the other tree")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    logs = args.logs or sorted(shared_logs_dir().glob("*.bin")) + sorted(shared_logs_dir().glob("*.tlog"))
    rows = [compare(log, args.other_tree) for log in logs]
    text = (f"## Same output as commit {args.other_rev}\n\n    mkdir -p {args.other_tree} && git archive {args.other_rev} "
            f"| tar -x -C {args.other_tree}\n    .venv-test/bin/python -m replay.live.same_output --other-tree "
            f"{args.other_tree} --other-rev {args.other_rev}\n\nMeasured {time.strftime('%Y-%m-%d')}. Every message "
            "of `companion replay LOG` by each commit's code: byte-identical, equal in value (JSON, float spelling "
            "only), or different.\n\n" +
            md_table(["log", "other msgs", "this msgs", "identical", "same value", "different", "first difference"], rows))
    publish(text, results_file("ingest"), "same-output", "Ingest and replay throughput", write=not args.no_write)
    sys.exit(1 if any(r[5] for r in rows) else 0)


if __name__ == "__main__":
    main()
