"""CI-sized fuzz of `companion replay`: a few mutants of every kind (replay/fuzz/mutate.py), each judged by the
fault-tolerance properties (replay/fuzz/properties.py): exit 0/2/3, no traceback, one stderr line with exit 2,
bounded time and memory, a readable MCAP, the input untouched.

The replays run as children forked from this process (replay/fuzz/runner.py: the same CLI entry point, without
interpreter start-up per run), one at a time, each killed at 3 x its clean input's time + 5 s or at its memory cap.
A kind stops at its first violation (that mutant is the test's failure message); kinds that break a property today
are marked xfail(strict) with the failure seen, so fixing them turns them into errors to unmark.
"""

from __future__ import annotations

import threading
import time

import pytest

from replay.fuzz.campaign import measure_baselines, mutants, run_campaign
from replay.fuzz.mutate import KINDS

SEED = 11
PER_KIND = 8  # x 29 kinds: 232 mutants when every kind passes

_FAILS_TODAY: dict[str, str] = {
    # kind: what breaks with this seed today (the reproducers in tests/fuzz/test_repro_*.py pin each class down).
    # Empty: the tlog cut mid-frame, concatenated logs, renamed FMT columns, one record or the rest of a log far
    # ahead in time and times >= 2^64 ns all pass the properties now.
}


@pytest.fixture(scope="module")
def campaign(clean, tmp_path_factory):
    from replay.fuzz.runner import preload

    # forking is only safe without other threads; otherwise each replay is a subprocess (slower, same properties)
    mode = "fork" if threading.active_count() == 1 else "subprocess"
    if mode == "fork":
        preload()
    work = tmp_path_factory.mktemp("fuzz")
    inputs = list(clean.values())
    base = measure_baselines(inputs, mode=mode, repeat=2, workdir=work)
    return inputs, base, mode, work


def _params():
    for k in KINDS:
        marks = [pytest.mark.xfail(strict=True, raises=AssertionError, reason=_FAILS_TODAY[k])] if k in _FAILS_TODAY else []
        yield pytest.param(k, marks=marks, id=k)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("kind", list(_params()))
def test_fuzz_replay(kind, campaign):
    inputs, base, mode, work = campaign
    kinds = list(KINDS)
    indices = [kinds.index(kind) + j * len(kinds) for j in range(PER_KIND)]
    t0 = time.monotonic()
    outcomes = run_campaign(mutants(indices, SEED, inputs), base, mode=mode, workdir=work,
                            stop=lambda o: bool(o["violations"]))
    bad = [o for o in outcomes if o["violations"]]
    assert outcomes, f"no mutant of {kind} could be built"
    assert not bad, (
        f"{kind} mutant #{bad[0]['index']} (seed {SEED}) of {bad[0]['input']}: {bad[0]['desc']}\n  "
        + "\n  ".join(bad[0]["notes"]) + f"\n  stderr: {bad[0]['stderr_tail']}\n"
        f"  rebuild: python -m replay.fuzz --seed {SEED} --size 150000 --only {bad[0]['index']} --keep out/fuzz"
        f" ({len(outcomes)} run in {time.monotonic() - t0:.1f} s)"
    )
