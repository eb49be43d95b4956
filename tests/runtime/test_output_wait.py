"""The live loop's batches between outputs (companion.runtime.wait): what waits for the next output cannot make one,
the navigator's outputs are the same batched as one by one, and most of the stream waits."""

from __future__ import annotations

import asyncio
import time

import pytest

from companion.config import LinkConfig, StreamConfig
from companion.events import GnssFix
from companion.mavlink.link import HOLD_MAX_S, MavlinkLink
from companion.nav import Navigator
from companion.nav.outputs import FusedState
from companion.runtime.wait import OutputWait
from tests.conftest import free_port


@pytest.fixture(scope="module")
def circuit_events():
    """The live benchmark's flight as the link delivers it (50 Hz IMU, 10 Hz GNSS and attitude), its first 60 s."""
    from replay.live.wake_cost import circuit_events

    return [e for e in circuit_events() if e.t_s < 60.0]


def _late_fixes(events, lag: int):
    """The receiver's fixes each delivered ``lag`` events after their place (a receiver behind the IMU)."""
    out, late = [], []
    for ev in events:
        if isinstance(ev, GnssFix):
            late.append([lag, ev])
            continue
        out.append(ev)
        for item in late:
            item[0] -= 1
        while late and late[0][0] <= 0:
            out.append(late.pop(0)[1])
    return out + [ev for _, ev in late]


def _run(events, batched: bool):
    """The navigator fed as the live loop feeds it; (outputs as text, events that waited, FusedStates from them)."""
    nav = Navigator()
    wait = OutputWait(nav.config.reorder_window_s)
    out, held, waited, from_held, before_output = [], [], 0, 0, []
    for ev in events:
        if batched and wait.may_wait([ev]):
            held.append(ev)
            waited += 1
            continue
        for h in held:
            got = nav.process(h)
            from_held += sum(isinstance(o, FusedState) for o in got)
            out += got
        got = nav.process(ev)
        if any(isinstance(o, FusedState) for o in got):
            before_output.append(len(held))
        out += got
        held = []
        wait.next_output_s = nav.next_output_s
    for h in held:
        out += nav.process(h)
    out += nav.finish()
    return [repr(o) for o in out], waited, from_held, before_output


@pytest.mark.parametrize("lag", [0, 7])
def test_batched_outputs_equal_one_by_one_and_no_waiting_event_makes_one(circuit_events, lag):
    events = _late_fixes(circuit_events, lag) if lag else circuit_events
    one_by_one, _, _, _ = _run(events, batched=False)
    batched, waited, from_held, before_output = _run(events, batched=True)
    assert sum("FusedState(" in o for o in one_by_one) >= 500  # 10 Hz for most of the minute
    assert batched == one_by_one
    assert from_held == 0  # every output came from an event that woke the loop
    # ... which found little waiting before it (the loop was woken ahead to run the rest): its latency is not delayed
    assert sum(before_output) / len(before_output) <= 3 and max(before_output) <= 6
    assert waited >= 0.6 * len(events)  # about one event in four wakes the loop at 72 events and 10 outputs a second


def test_an_event_that_could_release_an_output_never_waits():
    from companion.events import ImuSample, SystemTime

    def imu(t):
        return ImuSample(t_s=t, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0)

    wait = OutputWait(0.25)
    assert not wait.may_wait([imu(1.0)])  # nothing published yet: never wait
    wait.next_output_s = float("inf")
    assert not wait.may_wait([imu(1.02)])  # no output scheduled yet: the fix that schedules one may be in the navigator
    wait.next_output_s = 1.1
    assert wait.may_wait([imu(1.12)])  # the first event after the tick
    assert wait.may_wait([imu(1.3)])
    assert not wait.may_wait([imu(1.33)])  # within LEAD_S of the output: the loop runs what waited, once
    assert wait.may_wait([imu(1.36)])  # 1.36 - 0.25 < 1.12: the navigator still holds it
    assert not wait.may_wait([imu(1.37)])  # 1.12 leaves the reorder buffer: the tick at 1.1 goes
    assert not wait.may_wait([SystemTime(t_s=1.0, unix_time_s=1.7e9)])  # not a stream the navigator orders
    wait.next_output_s = 1.2
    assert wait.may_wait([imu(1.38)])
    assert not wait.may_wait([imu(1.21), imu(1.5)])  # one of a read's events is enough to wake
    late = OutputWait(0.25)
    late.next_output_s = 1.0
    assert late.may_wait([imu(0.9)]) and late.may_wait([imu(1.3)])
    assert not late.may_wait([imu(1.02)])  # after the tick, older than the newest - window: released at once


def test_a_time_stamp_far_ahead_wakes_the_loop_without_stopping_what_follows_from_waiting():
    from companion.events import ImuSample

    def imu(t):
        return ImuSample(t_s=t, accel_frd_mps2=(0.0, 0.0, -9.8), gyro_frd_radps=(0.0, 0.0, 0.0), imu_index=0)

    wait = OutputWait(0.25, outlier_s=30.0, confirm_n=3)
    wait.next_output_s = 1.1
    assert wait.may_wait([imu(1.12)])
    assert not wait.may_wait([imu(500.0)])  # an outlier: the navigator holds it, the loop looks at it at once
    assert wait.may_wait([imu(1.14)])  # and it moved nothing: the stream goes on waiting
    assert not any(wait.may_wait([imu(t)]) for t in (800.0, 800.02, 800.04))  # three confirm a jump ...
    wait.next_output_s = 800.1  # (the navigator's ticks jumped with it)
    assert wait.may_wait([imu(800.12)])  # ... after which the stream waits again on its new clock
    assert len(wait._recent) <= 10


def test_the_link_delivers_what_waited_in_order_with_the_next_wake_up_or_after_hold_max():
    async def main():
        got: list = []
        link = MavlinkLink(LinkConfig(connect=f"udpin:127.0.0.1:{free_port()}"), StreamConfig())
        link.start(asyncio.get_running_loop(), got.append)
        try:
            await _until(lambda: got)  # the link's "opened" status: what follows is ours alone
            del got[:]
            link._put("a", True)
            link._put("b", True)
            link._put("c")
            await _until(lambda: len(got) >= 3)
            assert got == ["a", "b", "c"]
            t0 = time.perf_counter()
            link._put("d", True)  # nothing wakes the loop after it: the reader's check sends it HOLD_MAX_S later
            await _until(lambda: len(got) >= 4)
            assert got[3] == "d" and time.perf_counter() - t0 >= HOLD_MAX_S
        finally:
            await asyncio.to_thread(link.stop)

    asyncio.run(main())


async def _until(cond, timeout_s: float = 60.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, "timed out"
        await asyncio.sleep(0.01)
