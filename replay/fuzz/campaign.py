"""A fuzz campaign over mutated logs: clean baselines, then every mutant run and judged.

Used by the benchmark (``python -m replay.fuzz``, subprocesses, in parallel) and by the CI-sized test
(forked children, one at a time). Each outcome is a plain dict (kind, input, description, exit code, times,
peak RSS, violations with notes) so it prints, tabulates and serialises the same way everywhere.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from replay.fuzz.logs import CleanInput, sha256
from replay.fuzz.mutate import Mutant, NotApplicable, make_mutant
from replay.fuzz.properties import Baseline, judge
from replay.fuzz.runner import RunResult, replay_args, run

#: the memory cap that kills a run is above the property's 2 x clean, so the violation is certain when it fires
MEM_CAP_FACTOR = 3
#: a run is killed this long after it has passed the time property's limit (subprocess mode)
GRACE_S = 5.0


def replay_file(data: bytes, suffix: str, *, mode: str, timeout_s: float, mem_cap_kb: int | None,
                workdir: str | os.PathLike | None = None, keep: Path | None = None) -> tuple[RunResult, Path, str, str, Path]:
    """Write ``data`` to a file, replay it to an MCAP next to it; returns (result, mcap, hash before, after, dir)."""
    d = Path(tempfile.mkdtemp(prefix="fuzz-", dir=workdir))
    log = d / f"input{suffix}"
    log.write_bytes(data)
    h0 = sha256(data)
    out = d / "out.mcap"
    res = run(replay_args(log, out), mode=mode, timeout_s=timeout_s, mem_cap_kb=mem_cap_kb, workdir=d)
    h1 = sha256(log.read_bytes()) if log.exists() else "(missing)"
    return res, out, h0, h1, d


def _cleanup(d: Path) -> None:
    for p in sorted(d.rglob("*"), reverse=True):
        p.unlink() if p.is_file() or p.is_symlink() else p.rmdir()
    d.rmdir()


def measure_baselines(inputs: Sequence[CleanInput], *, mode: str, repeat: int = 3, workdir=None,
                      timeout_s: float = 120.0) -> dict[str, Baseline]:
    """Replay each clean input ``repeat`` times; the median is its baseline. A clean input must exit 0."""
    for c in inputs:
        c.parsed()  # parsed once, before any fork: the parent's memory stays flat from here on
    out: dict[str, Baseline] = {}
    for c in inputs:
        results = []
        for _ in range(repeat):
            res, _mcap, _h0, _h1, d = replay_file(c.data, c.suffix, mode=mode, timeout_s=timeout_s, mem_cap_kb=None,
                                                  workdir=workdir)
            _cleanup(d)
            if res.returncode != 0:
                raise RuntimeError(f"clean input {c.name} does not replay cleanly: exit {res.returncode}\n{res.stderr[-2000:]}")
            results.append(res)
        out[c.name] = Baseline.of(results)
    return out


def baseline_for(m: Mutant, baselines: dict[str, Baseline]) -> Baseline:
    parts = [baselines[n] for n in m.inputs]
    return parts[0] if len(parts) == 1 else Baseline.combined(parts)


def run_mutant(m: Mutant, baselines: dict[str, Baseline], *, mode: str, workdir=None, keep: Path | None = None,
               hard_timeout: Callable[[Baseline], float] | None = None) -> dict:
    base = baseline_for(m, baselines)
    timeout_s = hard_timeout(base) if hard_timeout else base.time_limit_s + GRACE_S
    res, out, h0, h1, d = replay_file(m.data, m.suffix, mode=mode, timeout_s=timeout_s,
                                      mem_cap_kb=MEM_CAP_FACTOR * base.maxrss_kb + (64 * 1024 if base.forked else 0),
                                      workdir=workdir)
    v = judge(res, base, out=out, hash_before=h0, hash_after=h1, damaged=m.damaged)
    outcome = {
        "index": m.index, "seed": m.seed, "kind": m.kind, "input": m.inputs[0], "inputs": list(m.inputs),
        "desc": m.desc, "exit": res.returncode, "killed": res.killed, "wall_s": round(res.wall_s, 3),
        "cpu_s": round(res.cpu_s, 3), "maxrss_mb": round(res.own_rss_kb / 1024, 1),
        "clean_wall_s": round(base.wall_s, 3), "clean_maxrss_mb": round(base.maxrss_kb / 1024, 1),
        "violations": v.violations, "notes": v.notes,
        "stderr_tail": res.stderr.strip().splitlines()[-3:],
    }
    if keep is not None and v.violations:
        keep.mkdir(parents=True, exist_ok=True)
        (keep / f"mutant-{m.seed}-{m.index:05d}-{m.kind}{m.suffix}").write_bytes(m.data)
    _cleanup(d)
    return outcome


def mutants(indices: Iterable[int], seed: int, inputs: Sequence[CleanInput], kinds=None) -> Iterable[Mutant]:
    for i in indices:
        try:
            yield make_mutant(i, seed, inputs, kinds)
        except NotApplicable:
            continue


def run_campaign(ms: Iterable[Mutant], baselines: dict[str, Baseline], *, mode: str, jobs: int = 1, workdir=None,
                 keep: Path | None = None, on_outcome: Callable[[dict], None] | None = None,
                 stop: Callable[[dict], bool] | None = None) -> list[dict]:
    """Run every mutant; ``stop(outcome)`` True ends the campaign early (what has run is returned)."""
    outcomes: list[dict] = []
    if mode == "fork" or jobs <= 1:
        for m in ms:
            o = run_mutant(m, baselines, mode=mode, workdir=workdir, keep=keep)
            outcomes.append(o)
            if on_outcome:
                on_outcome(o)
            if stop and stop(o):
                break
        return outcomes
    with ThreadPoolExecutor(jobs) as pool:
        for o in pool.map(lambda m: run_mutant(m, baselines, mode=mode, workdir=workdir, keep=keep), ms):
            outcomes.append(o)
            if on_outcome:
                on_outcome(o)
    return outcomes
