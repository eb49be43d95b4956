"""The live companion: one asyncio loop driving the link's events through the shared pipeline.

``Runtime`` wires :class:`~companion.mavlink.link.MavlinkLink` -> :func:`companion.pipeline.core.build_pipeline`
(the same stages ``companion replay`` uses, plus the GPS_INPUT :class:`~companion.inject.Injector`) ->
the MCAP recorder. Link events (:class:`~companion.mavlink.link.LinkStatus`) are recorded beside the
pipeline's output and reported to systemd as STATUS; READY is sent once the link manager runs, WATCHDOG
every half watchdog period while both the loop and the link thread are alive (a hung link thread stops
the pings and systemd restarts the service).

Latency: for every GPS_INPUT that leaves, the time from the arrival of the bytes whose decoding caused
it (``Batch.recv_perf_s``) to the return of the socket write is kept per triggering message type.

Batches between outputs: the link's reader queues what cannot make a GPS_INPUT leave (IMU samples, attitude and
receiver fixes before the navigator's next output is due, :mod:`companion.runtime.wait`) without waking the loop;
the loop runs them, in order, just before the batch that can. Same events, same order, same outputs; the loop
wakes per output, not per message.

Freshness under load: the injector is told when the input it is working on arrived (the kernel's receive time,
see :mod:`companion.mavlink.transport`) and never sends a state whose input arrived more than ``inject.max_lag_s``
(less :data:`DELIVERY_MARGIN_S`) ago. When the loop is behind the link (a batch waited
more than :data:`SHED_AFTER_S`), everything queued is taken at once and its IMU samples are coalesced (the
mean of each run between other events, held over the run's interval like one sample) so the loop catches
up instead of falling further behind; it says so once per episode and counts what it shed (metadata
``shed.*``, the summary). The link's reader thins IMU frames itself when it is behind the kernel's queue
(:mod:`companion.mavlink.shed`; ``link.imu_frames_shed``). SIGTERM/SIGINT end the loop within a batch, whatever is still queued: the loop
yields to the event loop every :data:`YIELD_S` so the signal handler runs.
"""

from __future__ import annotations

import asyncio
import importlib
import logging
import signal
import sys
import threading
import time
from array import array
from collections import defaultdict, deque
from dataclasses import replace
from typing import Any

from companion.config import Config
from companion.inject.gps_input import GpsInputRecord, Injector
from companion.notify import Notifier
from companion.pipeline.core import Pipeline, build_pipeline
from companion.events import Event, ImuSample
from companion.mavlink.link import Batch, LinkStatus, MavlinkLink
from companion.nav import Navigator
from companion.runtime.wait import OutputWait
from companion.sources.base import SourceInfo

_logger = logging.getLogger(__name__)

_STOP = object()
#: a batch that waited this long (perf_counter, since its bytes arrived) means the loop is behind: shed load
SHED_AFTER_S = 0.1
#: the injector's freshness check comes before the write, the autopilot's read after it: a state is held to
#: ``inject.max_lag_s`` minus this since its input arrived (what a loaded machine adds: up to 70 ms measured between
#: the check and the peer's read, 2 cores at load 8)
DELIVERY_MARGIN_S = 0.1
#: back on time this long: the episode is over (one pair of log lines per episode, not per late batch)
CAUGHT_UP_AFTER_S = 1.0
#: the loop hands control back to the event loop (signals, housekeeping) at least this often while busy
YIELD_S = 0.02
#: batches taken from the queue at once when behind
MAX_DRAIN = 100_000
LATENCY_KEEP = 1 << 20  # latency samples kept per trigger (8 MiB); beyond, thinned by half


def run_loop(main: Any) -> Any:
    """``asyncio.run(main)`` on uvloop's event loop when uvloop is installed (a dependency on Linux and macOS), else on
    asyncio's own. The live process wakes up for every message the link delivers; uvloop does the loop's share of each
    wake-up (self-pipe, ready queue, futures' call-backs) in C."""
    try:
        import uvloop
    except ImportError:
        return asyncio.run(main)
    with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
        return runner.run(main)


def percentile_ms(values, q: float) -> float:
    import numpy as np

    return float(np.percentile(np.asarray(values, dtype=float), q) * 1e3) if len(values) else float("nan")


class Runtime:
    def __init__(self, config: Config, sink: Any, *, notifier: Notifier | None = None, nav_config: Any = None, log=None,
                 stop_signals: Any = None) -> None:
        self.config = config
        #: a companion.signals.StopSignals caught from the command's start (a signal before the loop runs stops it)
        self.stop_signals = stop_signals
        self.sink = sink
        gravity, speed_log, stages = None, None, []
        self.gravity_stage = None
        if config.gravity.map:  # gravity-aided: readings from the link, fixes into the navigator
            from companion.gravity.stage import live_gravity_stage
            from companion.mavlink.gravimeter import NamedValueGravityDecoder

            self.gravity_stage = live_gravity_stage(config.gravity)
            stages.append(self.gravity_stage)
            gravity = NamedValueGravityDecoder(config.gravity.named_value, config.gravity.sigma_mgal,
                                               eotvos_corrected=config.gravity.eotvos_corrected)
            if config.gravity.air_speed_log:
                from companion.mavlink.speed_log import NamedValueSpeedLogDecoder

                speed_log = NamedValueSpeedLogDecoder(config.gravity.air_speed_log)
        nav_config = nav_config or config.nav_config()
        self.link = MavlinkLink(config.link, config.streams, gravity=gravity, speed_log=speed_log)
        sender = self.link.send if config.inject.mode == "inject" else None
        self.injector = Injector(config.inject, sender=sender, trust=config.trust)
        self.injector.on_sent = self._on_sent
        # freshness judged by when the input's bytes arrived, with a margin for the way out after the check
        self.injector.arrival_clock = lambda: time.perf_counter() + DELIVERY_MARGIN_S
        # the reader thread sees a reboot before the loop does: nothing built on the previous boot leaves after it
        self.injector.link_reboots = lambda: self.link.decoder.clock.reboots
        # what the pipeline records waits until the batch is done: the GPS_INPUT goes out before the disk work
        self.deferred = DeferredSink(sink) if sink is not None else None
        self.pipeline: Pipeline = build_pipeline(self.deferred, nav_config=nav_config,
                                                 extra_stages=[*stages, self.injector])
        #: the navigator's batches between outputs wait for the next output (companion.runtime.wait)
        self.navigator = next((st for st in self.pipeline.stages if isinstance(st, Navigator)), None)
        nc = self.navigator.config if self.navigator is not None else None
        self.output_wait = (OutputWait(nc.reorder_window_s, nc.future_outlier_s, nc.future_confirm_n)
                            if nc is not None else None)
        if self.output_wait is not None:
            self.link.may_wait = self.output_wait.may_wait
        self.notifier = notifier if notifier is not None else Notifier()
        self.info = SourceInfo(kind="live", location=self.link.spec.url)
        self.latency_s: dict[str, array] = defaultdict(lambda: array("d"))
        self.link_log: list[LinkStatus] = []
        self.batches = 0
        self.stopped_by: str | None = None
        self.shed: dict[str, int] = defaultdict(int)  # load shed when behind: imu_in, imu_out, batches, episodes
        self._behind = False
        self._behind_at = 0.0  # perf_counter time the loop was last found behind
        self.lag_max_s = 0.0  # longest an input event waited between its arrival and its processing (wall s)
        self.events_late = 0  # input events that waited longer than inject.max_lag_s
        self.events_in = 0
        self._queue: Inbox | None = None
        self._stop_requested = False
        self._rx: tuple[float, str] | None = None
        self._last_batch_wall = time.monotonic()
        self._log = log

    # -- callbacks ----------------------------------------------------------------------------
    def _on_sent(self, rec: GpsInputRecord) -> None:
        if self._rx is not None:
            recv, trigger = self._rx
            vals = self.latency_s[trigger]
            vals.append(time.perf_counter() - recv)
            if len(vals) >= LATENCY_KEEP:  # bounded memory on a service running for days: keep every other
                self.latency_s[trigger] = vals[::2]

    def _say(self, level: int, text: str) -> None:
        """One line to the caller's log hook when it gave one, else to the module logger."""
        if self._log is not None:
            self._log(text)
        else:
            _logger.log(level, "%s", text)

    def _on_status(self, st: LinkStatus) -> None:
        self.link_log.append(st)
        if self.deferred is not None:
            self.deferred.write(st)
            self.deferred.drain()
        if self._log is not None:
            self._log(f"link {st.state}: {st.detail}")
        else:
            level = (logging.ERROR if st.state == "failed" else
                     logging.WARNING if st.state in ("lost", "open_failed", "rate_low", "shedding") else logging.INFO)
            _logger.log(level, "link %s: %s", st.state, st.detail)
        if st.state in ("autopilot", "lost", "reboot", "opened", "failed"):
            self.notifier.status(f"link {st.state}: {st.detail}")

    # -- loop ---------------------------------------------------------------------------------
    async def run(self, duration_s: float | None = None) -> str | None:
        """Run until SIGTERM/SIGINT or ``duration_s``; returns what stopped it."""
        loop = asyncio.get_running_loop()
        queue = Inbox(loop)
        self._queue = queue
        reasons: list[str] = []
        # the link thread and the loop share the GIL: hand it over within 1 ms, not CPython's default 5 ms
        sys.setswitchinterval(0.001)

        def stop(reason: str) -> None:
            reasons.append(reason)
            self._stop_requested = True
            queue.put_nowait(_STOP)

        sigs = (signal.SIGINT, signal.SIGTERM)
        for sig in sigs:
            loop.add_signal_handler(sig, stop, sig.name)
        if self.stop_signals is not None and self.stop_signals.reason is not None:
            stop(self.stop_signals.reason)  # caught before the loop ran
        if duration_s:
            loop.call_later(duration_s, stop, f"--duration {duration_s:g} s")
        self.link.start(loop, queue.put_nowait)
        self.notifier.ready(f"link {self.link.spec.url} open, injector {self.config.inject.mode}")
        threading.Thread(target=warm_deferred_imports, name="warm-imports", daemon=True).start()
        housekeeping = asyncio.ensure_future(self._housekeeping())
        last_yield = time.perf_counter()
        try:
            while not self._stop_requested:
                item = await queue.get()
                if item is _STOP:
                    break
                if isinstance(item, Batch):
                    if not item.held and time.perf_counter() - item.recv_perf_s > SHED_AFTER_S:
                        work, later = self._catch_up(item, queue)
                        for st in later:
                            if st is _STOP:
                                self._stop_requested = True
                            else:
                                self._on_status(st)
                    else:
                        work = [(ev, item.recv_perf_s, item.trigger) for ev in item.events]
                        if self._behind and time.perf_counter() - self._behind_at > CAUGHT_UP_AFTER_S:
                            self._behind = False
                            self._say(logging.INFO, f"caught up with the link; shed so far: {self._shed_text()}")
                    max_lag = self.config.inject.max_lag_s
                    for ev, arrival_s, trigger in work:
                        # each event is judged by when its own bytes arrived, merged or not
                        waited = time.perf_counter() - arrival_s
                        if waited > self.lag_max_s:
                            self.lag_max_s = waited
                        if waited > max_lag:
                            self.events_late += 1  # older than a state may be when sent: the run fell behind
                        self.events_in += 1
                        self._rx = (arrival_s, trigger)
                        self.injector.arrival_s = arrival_s
                        self.pipeline.process(ev)
                        if time.perf_counter() - last_yield > YIELD_S:
                            self._drain()
                            await asyncio.sleep(0)  # let a signal handler run
                            last_yield = time.perf_counter()
                            if self._stop_requested:
                                break
                    self._rx = None  # (the injector keeps the arrival: what finish() flushes was built from it)
                    if self.output_wait is not None:
                        self.output_wait.next_output_s = self.navigator.next_output_s
                    self._drain()
                    self.batches += 1
                    self._last_batch_wall = time.monotonic()
                elif isinstance(item, LinkStatus):
                    self._on_status(item)
                if time.perf_counter() - last_yield > YIELD_S:
                    await asyncio.sleep(0)
                    last_yield = time.perf_counter()
        finally:
            for sig in sigs:
                loop.remove_signal_handler(sig)
            if self.stop_signals is not None:
                self.stop_signals.rearm()  # (the defaults are back: they would kill the finalising)
            housekeeping.cancel()
            self.notifier.stopping()
            await asyncio.to_thread(self.link.stop, 1.0)
            while not queue.empty():  # statuses posted while stopping (the backlog of data is left)
                item = queue.get_nowait()
                if isinstance(item, LinkStatus):
                    self._on_status(item)
                elif isinstance(item, Batch):
                    self.shed["batches_left_at_stop"] += 1
            self._drain()
            self.pipeline.finish()
            self._drain()
            self.notifier.close()
        self.stopped_by = reasons[0] if reasons else None
        return self.stopped_by

    def _catch_up(self, first: Batch, queue: Inbox) -> tuple[list[tuple[Event, float, str]], list]:
        """Behind the link: every queued batch at once, IMU samples coalesced; returns the events with their
        arrival times and triggers, and the link statuses (and a stop) that were queued between them."""
        self._behind_at = time.perf_counter()
        batches, other = [first], []
        while not queue.empty() and len(batches) < MAX_DRAIN:
            nxt = queue.get_nowait()
            (batches if isinstance(nxt, Batch) else other).append(nxt)
        work = coalesce_imu_timed([(ev, b.recv_perf_s, b.trigger) for b in batches for ev in b.events])
        n_imu_in = sum(isinstance(e, ImuSample) for b in batches for e in b.events)
        n_imu_out = sum(isinstance(w[0], ImuSample) for w in work)
        self.shed["batches_merged"] += len(batches) - 1
        self.shed["imu_samples_in"] += n_imu_in
        self.shed["imu_samples_coalesced"] += n_imu_in - n_imu_out
        if not self._behind:
            self._behind = True
            self.shed["episodes"] += 1
            lag = time.perf_counter() - first.recv_perf_s
            self._say(logging.WARNING, f"{lag:.2f} s behind the link: coalescing IMU samples to catch up")
        return work, other

    def _drain(self) -> None:
        if self.deferred is not None:
            self.deferred.drain()

    def _shed_text(self) -> str:
        s = self.shed
        return (f"{s['imu_samples_coalesced']} of {s['imu_samples_in']} IMU samples coalesced, "
                f"{s['batches_merged']} batches merged, {s['episodes']} episodes")

    async def _housekeeping(self) -> None:
        """Watchdog pings and closing the MCAP chunk when the link goes quiet."""
        period = self.notifier.watchdog_period_s
        tick = min(period, 1.0) if period else 1.0
        next_ping = 0.0
        while True:
            await asyncio.sleep(tick)
            now = time.monotonic()
            if period and now >= next_ping and self.link.thread_alive and now - self.link.alive_at < 2.0 * period:
                self.notifier.watchdog()
                next_ping = now + period
            if now - self._last_batch_wall > 1.0 and hasattr(self.sink, "flush"):
                self.sink.flush()  # nothing arriving: put what we have on disk
            if (self._behind and self._queue is not None and self._queue.empty()
                    and time.perf_counter() - self._behind_at > CAUGHT_UP_AFTER_S):
                self._behind = False  # the backlog is worked off and nothing new came (a quiet or lost link)
                self._say(logging.INFO, f"caught up with the link (nothing queued); shed so far: {self._shed_text()}")

    # -- reporting ----------------------------------------------------------------------------
    def finalize_info(self) -> None:
        """Decoder drop counts and link events into ``info.warnings``/``details`` (for metadata and summary)."""
        for why, n in sorted(self.link.decoder.dropped.items()):
            msg = f"dropped {n} messages: {why}"
            if msg not in self.info.warnings:
                self.info.warnings.append(msg)
        self.info.details["messages_in"] = str(self.link.messages_in)
        for k, v in sorted(self.link.counts.items()):
            self.info.details[f"link.{k}"] = str(v)

    def metadata(self) -> dict[str, str]:
        meta = {"batches": str(self.batches), "messages_in": str(self.link.messages_in)}
        every = [v for vals in self.latency_s.values() for v in vals]
        groups = sorted(self.latency_s.items()) + ([("all", every)] if every else [])
        for trig, vals in groups:
            meta[f"latency.{trig}.n"] = str(len(vals))
            meta[f"latency.{trig}.p50_ms"] = f"{percentile_ms(vals, 50):.3f}"
            meta[f"latency.{trig}.p99_ms"] = f"{percentile_ms(vals, 99):.3f}"
        for k, v in sorted(self.link.counts.items()):
            meta[f"link.{k}"] = str(v)
        for k, v in sorted(self.shed.items()):
            meta[f"shed.{k}"] = str(v)
        meta["lag.max_s"] = f"{self.lag_max_s:.3f}"
        meta["lag.events_over_max_lag"] = str(self.events_late)
        return meta

    def summary_lines(self) -> list[str]:
        lines = []
        if self.gravity_stage is not None:
            lines += self.gravity_stage.summary_lines()
        ls = ", ".join(f"{k} {v}" for k, v in sorted(self.link.counts.items()))
        lines.append(f"link         {self.link.messages_in} messages in; events: {ls or 'none'}")
        if self.shed.get("episodes"):
            lines.append(f"load shed    behind the link {self.shed['episodes']} times: {self._shed_text()}")
        lines.append(f"lag          input processed at most {self.lag_max_s:.3f} s after it arrived; "
                     f"{self.events_late} of {self.events_in} events beyond inject.max_lag_s "
                     f"{self.config.inject.max_lag_s:g} s")
        for trig, vals in sorted(self.latency_s.items()):
            lines.append(
                f"latency      {trig} -> GPS_INPUT: p50 {percentile_ms(vals, 50):.2f} ms, "
                f"p99 {percentile_ms(vals, 99):.2f} ms over {len(vals)}"
            )
        return lines


class Inbox:
    """What the link delivers, for the one task that takes it: asyncio.Queue's ``put_nowait``, ``get``, ``get_nowait`` and
    ``empty`` (unbounded, FIFO) without its per-call loop check and waiter bookkeeping (a wake-up a message)."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._items: deque = deque()
        self._waiter: asyncio.Future | None = None

    def put_nowait(self, item: Any) -> None:
        self._items.append(item)
        waiter = self._waiter
        if waiter is not None:
            self._waiter = None
            if not waiter.done():  # (a cancelled get)
                waiter.set_result(None)

    async def get(self) -> Any:
        while not self._items:
            self._waiter = self._loop.create_future()
            await self._waiter
        return self._items.popleft()

    def get_nowait(self) -> Any:
        if not self._items:
            raise asyncio.QueueEmpty
        return self._items.popleft()

    def empty(self) -> bool:
        return not self._items


class DeferredSink:
    """The pipeline's sink, written once the batch is processed (:meth:`drain`), in the order it was given."""

    def __init__(self, sink: Any) -> None:
        self.sink = sink
        self._pending: list[tuple[Any, tuple, dict]] = []

    def write(self, *args, **kw) -> None:
        self._pending.append((self.sink.write, args, kw))

    def write_location(self, *args, **kw) -> None:
        self._pending.append((self.sink.write_location, args, kw))

    def write_log(self, *args, **kw) -> None:
        self._pending.append((self.sink.write_log, args, kw))

    def drain(self) -> None:
        pending, self._pending = self._pending, []
        for fn, args, kw in pending:
            fn(*args, **kw)

    def __getattr__(self, name: str) -> Any:  # anything else (flush, paths, ...) is the sink's own, after a drain
        self.drain()
        return getattr(self.sink, name)


#: modules the pipeline imports at their first use, not at start-up (READY comes sooner without them); imported in a
#: thread once the loop runs, so the first use does not stall the loop behind the link (scipy.spatial, the KNN
#: predictor's tree: 0.56 s, which made the loop coalesce IMU samples for the first second of every run)
DEFERRED_IMPORTS = ("scipy.spatial",)


def warm_deferred_imports() -> None:
    for name in DEFERRED_IMPORTS:
        try:
            importlib.import_module(name)
        except Exception as err:  # noqa: BLE001 - the first use will raise it where it can be handled
            _logger.debug("deferred import of %s failed: %s", name, err)


def coalesce_imu(events: list[Event]) -> list[Event]:
    """Each run of IMU samples (per IMU) between other events -> one sample: the mean, at the run's last time.

    The navigator holds a sample over the interval since the previous one, so the mean held over the whole run
    integrates the same velocity and angle change to first order; other events keep their order and place."""
    return [w[0] for w in coalesce_imu_timed([(ev, 0.0, "") for ev in events])]


def coalesce_imu_timed(work: list[tuple[Event, float, str]]) -> list[tuple[Event, float, str]]:
    """:func:`coalesce_imu` on (event, arrival, trigger): a coalesced sample keeps its last member's arrival."""
    out: list[tuple[Event, float, str]] = []
    runs: dict[int, list[tuple[ImuSample, float, str]]] = {}

    def flush() -> None:
        for run in runs.values():
            if len(run) == 1:
                out.append(run[0])
                continue
            n = float(len(run))
            acc = tuple(sum(s.accel_frd_mps2[i] for s, _, _ in run) / n for i in range(3))
            gyr = tuple(sum(s.gyro_frd_radps[i] for s, _, _ in run) / n for i in range(3))
            last, arrival_s, trigger = run[-1]
            out.append((replace(last, accel_frd_mps2=acc, gyro_frd_radps=gyr), arrival_s, trigger))
        runs.clear()

    for w in work:
        ev = w[0]
        if isinstance(ev, ImuSample):
            runs.setdefault(ev.imu_index, []).append(w)
        else:
            flush()
            out.append(w)
    flush()
    return out
