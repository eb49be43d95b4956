"""The pipeline's mechanisms: feedback events go back to the first stage; a filter stage decides what later
stages see; the GNSS denial is such a filter, with its truth passed on unrecorded."""

from __future__ import annotations

from companion.events import GnssFix, ImuSample, PositionFix
from companion.pipeline import Pipeline
from companion.pipeline.denial import GnssDenial, GnssDenialStage, WithheldFix
from companion.pipeline.stage import Stage
from tests.helpers import Collect


class _Stage(Stage):
    def __init__(self, name, emit_fix=False):
        self.name, self.emit_fix, self.seen = name, emit_fix, []

    def process(self, item):
        self.seen.append(item)
        if self.emit_fix and isinstance(item, ImuSample):
            return [PositionFix(item.t_s, 1.0, 2.0, 5.0, 5.0, "test")]
        return []

    def finish(self):
        return [PositionFix(99.0, 1.0, 2.0, 5.0, 5.0, "test")] if self.emit_fix else []


def test_feedback_reaches_stage0_once_in_order_and_is_recorded_once():
    s0, s1, s2 = _Stage("nav"), _Stage("grav", emit_fix=True), _Stage("inj")
    rec = Collect()
    p = Pipeline(stages=[s0, s1, s2], sink=rec)
    for k in range(3):
        p.process(ImuSample(float(k), (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0))
    p.finish()
    kinds = [type(x).__name__ for x in s0.seen]
    assert kinds == ["ImuSample", "PositionFix"] * 3  # each fix right after the event that produced it
    assert [type(x).__name__ for x in s2.seen] == kinds  # later stages see it once, via the feedback pass
    assert [x.t_s for x in s0.seen if isinstance(x, PositionFix)] == [0.0, 1.0, 2.0]
    assert sum(isinstance(x, PositionFix) for x in rec.items) == 4  # 3 + the one from finish(), each once
    assert sum(isinstance(x, ImuSample) for x in rec.items) == 3
    assert all(not isinstance(x, PositionFix) or x.t_s < 99 for x in s0.seen)  # finish(): recorded only




def _fix(t):
    return GnssFix(t, 3, -35.0, 149.0, 500.0, 0.0, 0.0, None, 0.0, 0.0, 10, 0.8, 1.2, 1.0, 2.0, 0.3, None, None, 0)


def test_a_filter_stage_decides_what_later_stages_see_and_the_denial_passes_the_truth_on_unrecorded():
    denial = GnssDenialStage(GnssDenial(2.0))
    after = _Stage("nav")
    rec = Collect()
    p = Pipeline(stages=[denial, after], sink=rec)
    for k in range(5):
        p.process(ImuSample(float(k), (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0))
        p.process(_fix(k + 0.5))
    p.finish()
    fixes = [x for x in after.seen if isinstance(x, GnssFix)]
    withheld = [x for x in after.seen if isinstance(x, WithheldFix)]
    assert [f.t_s for f in fixes] == [0.5, 1.5]  # the cut is 2 s after the first event
    assert [w.fix.t_s for w in withheld] == [2.5, 3.5, 4.5] and denial.gnss_withheld == 3
    assert sum(isinstance(x, ImuSample) for x in after.seen) == 5  # everything else passes
    assert not any(isinstance(x, WithheldFix) for x in rec.items)  # the truth is not recorded again ...
    assert sum(isinstance(x, GnssFix) for x in rec.items) == 5  # ... the fixes are, as input events
    assert denial.metadata() == {"gnss_withheld_after_s": "2", "gnss_withheld": "3"}


def test_progress_is_reported_by_time_also_when_paced():
    """A paced replay of a few events a second refreshes its progress a few times a second, not every N events."""
    import asyncio

    from companion.pipeline.core import run_source

    class _Source:
        def __init__(self, n, dt_s):
            self.events = [ImuSample(k * dt_s, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), 0) for k in range(n)]

        async def _gen(self):
            for ev in self.events:
                yield ev

        def __aiter__(self):
            return self._gen()

    calls: list[int] = []
    # 11 events 0.1 s apart at real time: at least 1 s of wall time, reported every 0.25 s of it
    asyncio.run(run_source(_Source(11, 0.1), Pipeline(sink=Collect()), realtime_factor=1.0,
                           on_progress=lambda src, n: calls.append(n), progress_interval_s=0.25))
    assert len(calls) >= 3 and calls == sorted(calls) and calls[-1] <= 11
