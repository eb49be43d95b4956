"""What an event costs the navigator live, against back to back in a replay: the same events, the same work.

    .venv/bin/python -m replay.live.wake_cost [--events 1500] [--repeat 3] [--no-write]

The live process at 50 Hz IMU spends 3.5-4.6 % of a core from run to run (replay/results/live.md), several times
what the navigator's replay speed suggests: this isolates why. The simulated vehicle's
circuit flight (``companion sim --profile circuit``: 50 Hz IMU, 10 Hz GNSS and ATTITUDE, what the live link
requests) goes through a fresh :class:`~companion.nav.Navigator` in one process under five pacings, and the
navigator's own thread CPU time (``time.thread_time`` around each ``process`` call, nothing else) is divided by
the events:

* back to back -- as ``companion replay`` does;
* back to back, 8 MB touched between events -- one byte a page written in a buffer larger than the caches, no pause
  (what evicting the data caches alone costs);
* real time, sleeping -- each event at its vehicle time, the thread asleep in between (as the live loop waits on
  its link);
* real time, spinning -- the same spacing, the core kept busy by a spin loop instead of sleeping (no idle state);
* real time, 10 Hz batches -- asleep, woken every 100 ms of vehicle time for the events due (the fewest wake-ups a
  10 Hz output allows).

The link's reader thread is timed the same way (back to back, asleep, spinning): pymavlink's parser and the
decoder on the flight's frames, one frame a read, as ``companion.mavlink.link`` does.

Every pacing gives the navigator the same events in the same order: its outputs are checked equal, so only when
the work runs differs. The first ``--warmup`` events run back to back before the timing (filter initialised, KNN
database started).
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

from companion.events import ImuSample
from companion.nav import Navigator
from replay.harness.results import md_table, publish, results_file

PACINGS = ("back to back", "back to back, 8 MB touched between events", "real time, sleeping", "real time, spinning",
           "real time, 10 Hz batches")
TOUCH_BYTES = 8 << 20  # more than the last-level cache of this machine and of a Raspberry Pi
BATCH_PERIOD_S = 0.1
#: the pacings of the link's reader work (it reads each frame as it comes: no batches)
LINK_PACINGS = ("back to back", "real time, sleeping", "real time, spinning")


@functools.lru_cache(maxsize=1)
def circuit_stream() -> tuple[tuple[str, int, bytes], ...]:
    """The live benchmark's flight (replay.live.latency: circuit profile, 10 Hz GNSS, 50 Hz IMU, 10 Hz ATTITUDE,
    drone sensors, the sample seed) as the simulated vehicle sends it: (message type, receive time us, MAVLink frame)."""
    from companion.sim.flight import SAMPLE_SEED, SENSOR_SETS, SimConfig, simulate_flight
    from companion.sim.mavlink_out import pack_stream, telemetry_messages
    from companion.sim.vehicle_cli import circuit_profile

    flight = simulate_flight(circuit_profile(), SAMPLE_SEED,
                             SimConfig(gnss_rate_hz=10.0, imu_rate_hz=50.0, attitude_rate_hz=10.0,
                                       **SENSOR_SETS["drone"]))
    msgs = telemetry_messages(flight)
    return tuple((o.msg.get_type(), t_us, frame)
                 for o, (t_us, frame) in zip(msgs, pack_stream(msgs, flight.config.boot_epoch_us), strict=True))


def circuit_events() -> list:
    """:func:`circuit_stream` as the link would deliver it: events, the first IMU only (the one requested)."""
    from companion.sim.tlog import tlog_bytes
    from companion.sources.files import read_events

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "circuit.tlog"
        path.write_bytes(tlog_bytes((t_us, frame) for _, t_us, frame in circuit_stream()))
        events = read_events(path)
    return [e for e in events if not (isinstance(e, ImuSample) and e.imu_index != 0)]


def circuit_frames() -> list[tuple[float, bytes]]:
    """:func:`circuit_stream` as the link would receive it: (receive time s, MAVLink frame), without the second IMU's
    SCALED_IMU2 (not requested live)."""
    return [(t_us * 1e-6, frame) for mtype, t_us, frame in circuit_stream() if mtype != "SCALED_IMU2"]


def _wait_until(deadline: float, spin: bool) -> None:
    if spin:
        while time.perf_counter() < deadline:
            pass
    else:
        left = deadline - time.perf_counter()
        if left > 0:
            time.sleep(left)


def run_paced(events: list, warmup: int, n: int, pacing: str) -> tuple[float, list]:
    """(navigator thread CPU s per event, the outputs) for ``events[warmup:warmup + n]`` under ``pacing``."""
    if pacing not in PACINGS:
        raise ValueError(f"unknown pacing {pacing!r} (one of {PACINGS})")
    nav = Navigator(None)
    outs: list = []
    for ev in events[:warmup]:
        outs += nav.process(ev)
    timed = events[warmup:warmup + n]
    if not timed:
        raise ValueError(f"no events to time: {len(events)} events, {warmup} of them warm-up")
    cpu_s = 0.0
    t0_ev, t0 = timed[0].t_s, time.perf_counter()
    if pacing == "real time, 10 Hz batches":
        i = 0
        while i < len(timed):
            due = t0_ev + (math.floor((timed[i].t_s - t0_ev) / BATCH_PERIOD_S) + 1) * BATCH_PERIOD_S  # batch's end
            k = i + 1  # at least the event that opened the batch, whatever the rounding
            while k < len(timed) and timed[k].t_s < due:
                k += 1
            _wait_until(t0 + due - t0_ev, spin=False)
            c0 = time.thread_time()
            for ev in timed[i:k]:
                outs += nav.process(ev)
            cpu_s += time.thread_time() - c0
            i = k
    else:
        paced, spin = pacing.startswith("real time"), pacing == "real time, spinning"
        junk = bytearray(TOUCH_BYTES) if pacing == "back to back, 8 MB touched between events" else None
        for ev in timed:
            if paced:
                _wait_until(t0 + ev.t_s - t0_ev, spin)
            elif junk is not None:
                for page in range(0, TOUCH_BYTES, 4096):
                    junk[page] ^= 1  # a write to every page
            c0 = time.thread_time()
            outs += nav.process(ev)
            cpu_s += time.thread_time() - c0
    return cpu_s / len(timed), outs


def run_link_paced(frames: list[tuple[float, bytes]], warmup: int, n: int, pacing: str) -> tuple[float, list]:
    """(thread CPU s per frame, the events) of the link's reader work -- pymavlink's parser and the decoder, as
    companion.mavlink.link does for each read -- for ``frames[warmup:warmup + n]``, one frame a read."""
    from companion.mavlink.decode import MavlinkDecoder
    from companion.mavlink.dialect import mavlink as mavlink2

    if pacing not in LINK_PACINGS:
        raise ValueError(f"unknown pacing {pacing!r} (one of {LINK_PACINGS})")
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER)
    mav.robust_parsing = True
    decoder = MavlinkDecoder()
    events: list = []
    for t_s, frame in frames[:warmup]:
        for msg in mav.parse_buffer(frame) or []:
            events += decoder.decode(msg, t_s)
    timed = frames[warmup:warmup + n]
    if not timed:
        raise ValueError(f"no frames to time: {len(frames)} frames, {warmup} of them warm-up")
    cpu_s = 0.0
    t0_rx, t0 = timed[0][0], time.perf_counter()
    paced, spin = pacing.startswith("real time"), pacing == "real time, spinning"
    for t_s, frame in timed:
        if paced:
            _wait_until(t0 + t_s - t0_rx, spin)
        c0 = time.thread_time()
        for msg in mav.parse_buffer(frame) or []:
            events += decoder.decode(msg, t_s)
        cpu_s += time.thread_time() - c0
    return cpu_s / len(timed), events


def pacing_table(run, inputs: list, warmup: int, n: int, repeat: int, pacings: tuple[str, ...],
                 unit: str) -> tuple[str, dict[str, float]]:
    """Median CPU per input of ``run(inputs, warmup, n, pacing)`` -> (CPU s per input, outputs) under each pacing,
    ``repeat`` rounds with the pacings in turn; every run's outputs must equal the first's (same work)."""
    per: dict[str, list[float]] = {p: [] for p in pacings}
    reference = None
    for _ in range(repeat):
        for p in pacings:
            cpu_s_per_input, outs = run(inputs, warmup, n, p)
            if reference is None:
                reference = outs
            elif outs != reference:
                raise AssertionError(f"pacing {p!r} changed the outputs")
            per[p].append(cpu_s_per_input)
    med = {p: statistics.median(v) for p, v in per.items()}
    rows = [[p, n, f"{1e6 * med[p]:.0f}", ", ".join(f"{1e6 * x:.0f}" for x in per[p]),
             f"{med[p] / med['back to back']:.1f}"] for p in pacings]
    return md_table(["pacing", f"{unit}s", f"us per {unit} (median)", "each round", "x back to back"], rows), med


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--events", type=int, default=1500, help="events timed per pacing (default 1500, ~20 s of flight)")
    ap.add_argument("--warmup", type=int, default=2000, help="events run back to back first (default 2000)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-write", action="store_true", help="print only; do not write replay/results/live.md")
    args = ap.parse_args(argv)
    if args.events < 1 or args.repeat < 1 or args.warmup < 0:
        ap.error("--events and --repeat must be >= 1, --warmup >= 0")
    events = circuit_events()
    load0 = os.getloadavg()[0]
    table, med = pacing_table(run_paced, events, args.warmup, args.events, args.repeat, PACINGS, "event")
    frames = circuit_frames()
    link_table, link_med = pacing_table(run_link_paced, frames, args.warmup, args.events, args.repeat, LINK_PACINGS,
                                        "frame")
    timed_frames = frames[args.warmup:args.warmup + args.events]
    frame_span_s = timed_frames[-1][0] - timed_frames[0][0]
    frame_rate = len(timed_frames) / frame_span_s if frame_span_s > 0 else float("nan")
    load1 = os.getloadavg()[0]
    timed = events[args.warmup:args.warmup + args.events]  # (run_paced refused an empty slice)
    flight_s = timed[-1].t_s - timed[0].t_s
    rate = len(timed) / flight_s if flight_s > 0 else float("nan")
    text = (
        "## What an event costs the navigator live (`replay.live.wake_cost`)\n\n"
        f"    .venv/bin/python -m replay.live.wake_cost --events {args.events} --repeat {args.repeat}\n\n"
        f"Measured {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, 1-min load average {load0:.1f} at start, "
        f"{load1:.1f} at end. The circuit flight of the live benchmark ({rate:.0f} events per second of flight), "
        "a fresh navigator per pacing, its thread CPU time per event; the outputs of every pacing are equal.\n\n"
        + table + "\n\n"
        f"At the live rate the navigator alone would take {100 * med['real time, sleeping'] * rate:.1f} % of a core "
        f"paced and asleep between events, {100 * med['back to back'] * rate:.1f} % if each event cost what it costs "
        "back to back.\n\n"
        "The link's reader thread (`companion.mavlink.link`): pymavlink's parser and the decoder on the same flight's "
        "frames as they come, one frame a read, the outputs checked equal:\n\n" + link_table + "\n\n"
        f"At the live rate ({frame_rate:.0f} frames a second) that is "
        f"{100 * link_med['real time, sleeping'] * frame_rate:.1f} % of a core paced, "
        f"{100 * link_med['back to back'] * frame_rate:.1f} % at the back-to-back cost."
    )
    publish(text, results_file("live"), "wake-cost", "Live companion: GPS_INPUT latency, CPU, memory",
            write=not args.no_write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
