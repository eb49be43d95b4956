"""Link management with the autopilot: heartbeat, targeting, stream requests, loss, reconnect, reboot, signing.

One reader thread owns the transport. What it does on each link event (each also becomes a
:class:`LinkStatus` record on ``/link/status``):

* **opened**: the transport is open; we send HEARTBEAT (MAV_TYPE_ONBOARD_CONTROLLER, our system and
  component ids) every ``1 / heartbeat_hz`` s from now on -- an autopilot (or a ``udpout`` peer) starts
  talking once it hears one.
* **autopilot**: the first HEARTBEAT of an autopilot (or of the configured target) in this session:
  it becomes the target; every stream in ``streams.rates_hz`` is requested with COMMAND_LONG
  MAV_CMD_SET_MESSAGE_INTERVAL (511; param1 message id, param2 interval in us). COMMAND_ACKs are
  recorded (``ack`` when refused).
* **rate_low**: every ``check_period_s`` the arrival rate of each requested message is measured; one
  below ``min_fraction`` of the request is requested again.
* **reboot**: the autopilot's boot time went back (the decoder emits a Reboot event): rate statistics
  are reset and every stream is requested again (ArduPilot forgets intervals when it reboots).
* **lost**: nothing from the target for ``link_timeout_s`` (or the peer closed the connection): the
  transport is closed and **reconnecting** after a back-off that doubles from ``reconnect_min_s`` to
  ``reconnect_max_s`` (reset once an autopilot is heard again).
* **bad frames**: CRC errors, garbage and (with signing) unsigned or wrongly signed frames are dropped by
  the parser; the decoder counts them ("bad frame") with messages from other systems and malformed fields.
* **shedding** / **caught_up**: the reader is behind the link (more than :data:`SHED_PENDING_BYTES` still queued
  in the kernel, or what it read arrived more than :data:`SHED_AGE_S` ago): IMU frames are thinned before parsing
  (:class:`~companion.mavlink.shed.ImuShedder`, to twice the requested IMU rate) until it has kept up for
  :data:`SHED_HOLD_S`; ``counts["imu_frames_shed"]`` says how many went.
* **failed**: the reader thread hit an error it cannot handle: it ends (and the runtime's watchdog pings stop).

Everything the thread produces reaches the event loop through one queue with at most one pending wake-up
(``call_soon_threadsafe``), whatever the message rate, so asyncio's self-pipe never fills (a full one would eat
the byte that wakes the loop for a signal). A batch the loop's ``may_wait`` judges able to wait (nothing in it can
make an output leave) is queued without a wake-up: the loop takes it with the next one, in order, or
:data:`HOLD_MAX_S` later. Woken per output instead of per message, the loop finds its caches warmer.

Signing (MAVLink 2): with a key, every frame we send is signed and only correctly signed frames are
accepted (unless ``allow_unsigned``).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar


from companion.config import LinkConfig, StreamConfig, load_signing_key
from companion.events import Event, Reboot
from companion.mavlink.transport import LinkClosed, Transport, open_transport
from companion.mavlink.address import parse_url
from companion.mavlink.dialect import mavlink as mavlink2
from companion.mavlink.decode import MavlinkDecoder
from companion.mavlink.shed import ImuShedder

MAV_TYPE_ONBOARD_CONTROLLER = mavlink2.MAV_TYPE_ONBOARD_CONTROLLER
MAV_AUTOPILOT_INVALID = mavlink2.MAV_AUTOPILOT_INVALID
MAV_STATE_ACTIVE = mavlink2.MAV_STATE_ACTIVE
MAV_CMD_SET_MESSAGE_INTERVAL = mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
MAV_RESULT_ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
#: seconds since 2015-01-01, the MAVLink signing epoch
_SIGNING_EPOCH_UNIX_S = 1420070400
#: the reader is behind when more than this is still queued after a read (about 400 frames, 15 ms of parsing) ...
SHED_PENDING_BYTES = 16 * 1024
#: ... or when the bytes it read arrived this long ago
SHED_AGE_S = 0.05
#: shedding ends once the reader has not been behind for this long
SHED_HOLD_S = 1.0
#: a batch the loop's ``may_wait`` let wait is delivered at the latest this long (perf_counter s) after it was read
#: (docs/decisions/0014-live-wake-ups-and-compiled-core.md)
HOLD_MAX_S = 0.2


@dataclass(frozen=True, slots=True)
class LinkStatus(Event):
    """A link event: opened, autopilot, streams, rate_low, ack, reboot, lost, reconnecting, open_failed."""

    state: str
    detail: str
    topic: ClassVar[str] = "/link/status"


def message_id(name: str) -> int:
    return getattr(mavlink2, f"MAVLINK_MSG_ID_{name}")


@dataclass
class Batch:
    """Events decoded from one read, with the time (perf_counter) the bytes arrived."""

    recv_perf_s: float
    events: list[Event]
    trigger: str  # type of the last message in the read that produced events
    held: bool = False  # posted without waking the loop (nothing in it could make an output leave)


class MavlinkLink:
    """The autopilot link. ``start(loop, put)`` runs the reader thread; ``put`` gets Batch and LinkStatus."""

    def __init__(self, link: LinkConfig, streams: StreamConfig, *, clock: Callable[[], float] = time.monotonic,
                 gravity=None, speed_log=None) -> None:
        self.config = link
        self.streams = streams
        self.spec = parse_url(link.connect, link.baud)
        self.key = load_signing_key(link.signing_key_file) if link.signing_key_file else None
        self.clock = clock
        # a configured target system without a component means its autopilot (MAV_COMP_ID_AUTOPILOT1)
        ts = link.target_system or None
        # gravity: a NamedValueGravityDecoder for gravimeter readings (companion.mavlink.gravimeter), or None;
        # speed_log: a NamedValueSpeedLogDecoder for a boat's water speed (companion.mavlink.speed_log), or None
        self.decoder = MavlinkDecoder(ts, (link.target_component or mavlink2.MAV_COMP_ID_AUTOPILOT1) if ts else None,
                                      gravity=gravity, speed_log=speed_log)
        self.mav = self._new_mav()
        self.counts: Counter[str] = Counter()  # link event counts: opened, lost, reboot, stream_requests, ...
        self.messages_in = 0
        self.bytes_in = 0
        self.connected = False
        self.target: tuple[int, int] | None = None
        self.last_t_s = 0.0  # vehicle time of the newest event: stamps LinkStatus records
        self.alive_at = clock()  # reader loop's last iteration (for the watchdog)
        self._transport: Transport | None = None
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._put: Callable[..., None] | None = None
        self._wake_if_held: Callable[[float], None] | None = None
        #: the loop's judge of what may wait (the reader thread calls it with each read's events): True, the batch is
        #: queued without waking the loop, which takes it with the next batch that wakes it (or HOLD_MAX_S later)
        self.may_wait: Callable[[list[Event]], bool] | None = None
        imu_hz = streams.rates_hz.get("RAW_IMU", 50.0)
        self.shedder = ImuShedder(0.5 / imu_hz if imu_hz > 0 else 0.01)
        self._shed_until: float | None = None  # shedding while set: until this clock time unless behind again
        self._shed_start = 0

    # -- public -------------------------------------------------------------------------------
    def start(self, loop: asyncio.AbstractEventLoop, put: Callable[[Any], None]) -> None:
        outbox: deque = deque()
        lock = threading.Lock()
        pending = [False]  # a wake-up is scheduled and has not run yet
        held = [None]  # perf_counter time the oldest item posted without a wake-up was posted (None: none waits)

        def deliver() -> None:  # in the loop: everything posted since the last wake-up, in order
            with lock:
                items = list(outbox)
                outbox.clear()
                pending[0] = False
            for item in items:
                put(item)

        def wake() -> None:  # (called with the lock held)
            pending[0] = True
            held[0] = None
            try:
                loop.call_soon_threadsafe(deliver)
            except RuntimeError:
                pass  # the loop is closed: nobody is listening any more

        def post(item, quiet: bool = False) -> None:  # in the reader thread
            with lock:
                outbox.append(item)
                if pending[0]:
                    return
                if quiet:
                    if held[0] is None:
                        held[0] = time.perf_counter()
                    return
                wake()

        def wake_if_held(now_perf: float) -> None:  # in the reader thread: what waited HOLD_MAX_S goes now
            if held[0] is not None and now_perf - held[0] >= HOLD_MAX_S:
                with lock:
                    if held[0] is not None and not pending[0]:
                        wake()

        self._put = post
        self._wake_if_held = wake_if_held
        self._thread = threading.Thread(target=self._run, name="mavlink-link", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None
        self._close()

    @property
    def thread_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def send(self, msg) -> bool:
        """Pack (and sign) a message and write it; False when the link is down or has no peer yet."""
        with self._send_lock:
            tr = self._transport
            if tr is None or not self.connected:
                return False
            return tr.write(bytes(msg.pack(self.mav)))

    # -- internals ----------------------------------------------------------------------------
    def _new_mav(self):
        mav = mavlink2.MAVLink(None, srcSystem=self.config.system_id, srcComponent=self.config.component_id)
        mav.robust_parsing = True  # bad CRC / garbage become BAD_DATA messages, never exceptions
        if self.key is not None:
            mav.signing.secret_key = self.key
            mav.signing.sign_outgoing = True
            mav.signing.link_id = 0
            mav.signing.timestamp = int(max(time.time() - _SIGNING_EPOCH_UNIX_S, 0) * 1e5)
            if self.config.allow_unsigned:
                mav.signing.allow_unsigned_callback = lambda _mav, _msgid: True
        return mav

    def _status(self, state: str, detail: str = "") -> None:
        self.counts[state] += 1
        if self._put is not None:
            self._put(LinkStatus(self.last_t_s, state, detail))

    def _close(self) -> None:
        with self._send_lock:
            self.connected = False
            if self._transport is not None:
                self._transport.close()
                self._transport = None

    def _run(self) -> None:
        try:
            self._serve()
        except Exception as err:  # noqa: BLE001 - say why the reader ends; the watchdog stops pinging
            self._status("failed", f"link reader stopped: {type(err).__name__}: {err}")
            self._close()

    def _serve(self) -> None:
        c = self.config
        backoff = c.reconnect_min_s
        while not self._stop.is_set():
            self.alive_at = self.clock()
            try:
                tr = open_transport(self.spec)
            except (OSError, Exception) as err:  # noqa: BLE001 - any failure to open: retry later
                self._status("open_failed", f"{self.spec.url}: {getattr(err, 'strerror', None) or err}; retry in {backoff:g} s")
                self._wait(backoff)
                backoff = min(backoff * 2, c.reconnect_max_s)
                continue
            with self._send_lock:
                self._transport = tr
                self.connected = True
                self.mav = self._new_mav_keep_signing()
            self._status("opened", self.spec.url)
            heard = self._session(tr)
            self._close()
            if self._stop.is_set():
                break
            if heard:
                backoff = c.reconnect_min_s
            self._status("reconnecting", f"in {backoff:g} s")
            self._wait(backoff)
            backoff = min(backoff * 2, c.reconnect_max_s)

    def _new_mav_keep_signing(self):
        """A fresh parser per connection (no half frame carried over); signing timestamps keep increasing."""
        old = self.mav
        mav = self._new_mav()
        if self.key is not None:
            mav.signing.timestamp = max(mav.signing.timestamp, old.signing.timestamp + 1)
        return mav

    def _wait(self, seconds: float) -> None:
        end = self.clock() + seconds
        while not self._stop.is_set() and self.clock() < end:
            self.alive_at = self.clock()
            self._stop.wait(min(0.2, max(0.0, end - self.clock())))

    def _send_heartbeat(self) -> None:
        self.send(mavlink2.MAVLink_heartbeat_message(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE, 3))

    def _request_streams(self, why: str, names=None) -> None:
        if self.target is None:
            return
        sysid, compid = self.target
        names = list(self.streams.rates_hz) if names is None else names
        for name in names:
            interval_us = 1e6 / self.streams.rates_hz[name]
            self.send(
                mavlink2.MAVLink_command_long_message(
                    sysid, compid, MAV_CMD_SET_MESSAGE_INTERVAL, 0, message_id(name), interval_us, 0, 0, 0, 0, 0
                )
            )
            self.counts["stream_requests"] += 1
        self._status("streams", f"{why}: " + ", ".join(f"{n} {self.streams.rates_hz[n]:g} Hz" for n in names))

    def _shed(self, data: bytes, tr: Transport, now: float) -> bytes:
        """Behind the link: the IMU frames thinned before the parser sees them (see the module's doc)."""
        queued = tr.last_pending
        behind = queued > SHED_PENDING_BYTES or tr.last_age_s > SHED_AGE_S
        if behind:
            if self._shed_until is None:
                self._shed_start = self.shedder.shed
                self.shedder.reset()
                self._status("shedding", f"behind the link ({queued} bytes queued, input {tr.last_age_s:.3f} s "
                                          f"old): IMU frames thinned to {1 / self.shedder.min_interval_s:g} Hz")
            self._shed_until = now + SHED_HOLD_S
        elif self._shed_until is not None and now >= self._shed_until:
            self._shed_until = None
            self._status("caught_up", f"{self.shedder.shed - self._shed_start} IMU frames shed")
        if self._shed_until is None:
            return data
        before = self.shedder.shed
        data = self.shedder.filter(data)
        self.counts["imu_frames_shed"] += self.shedder.shed - before
        return data

    def _session(self, tr: Transport) -> bool:
        """Read until the link is lost or stop; True if an autopilot was heard in this session."""
        c, s = self.config, self.streams
        hb_period = 1.0 / c.heartbeat_hz
        next_hb = 0.0
        last_rx = self.clock()
        self.target = None
        rate_counts: Counter[str] = Counter()
        window_start = None
        heard = False
        while not self._stop.is_set():
            now = self.clock()
            self.alive_at = now
            if now >= next_hb:
                self._send_heartbeat()
                next_hb = now + hb_period
            try:
                data = tr.recv(0.05)
            except LinkClosed as err:
                self._status("lost", str(err))
                return heard
            now = self.clock()
            if data:
                recv_perf = time.perf_counter() - tr.last_age_s
                self.bytes_in += len(data)
                data = self._shed(data, tr, now)
                with self._send_lock:  # the parser's signing state is shared with send()
                    msgs = self.mav.parse_buffer(data) or []
                events: list[Event] = []
                trigger = ""
                for msg in msgs:
                    self.messages_in += 1
                    evs = self.decoder.decode(msg, now)
                    mtype = msg.get_type()
                    if mtype == "BAD_DATA":
                        continue
                    src = (msg.get_srcSystem(), msg.get_srcComponent())
                    # the autopilot itself keeps the link alive, sets the target and answers stream requests; what
                    # the decoder takes from other components (its source policy) only brings events
                    if self.decoder.target_system is not None and src == (self.decoder.target_system,
                                                                            self.decoder.target_component):
                        last_rx = now
                        rate_counts[mtype] += 1
                        if self.target is None and mtype == "HEARTBEAT":
                            self.target = src
                            heard = True
                            self._status("autopilot", f"system {src[0]} component {src[1]}")
                            self._request_streams("autopilot found")
                            window_start = now
                            rate_counts.clear()
                        if (mtype == "COMMAND_ACK" and msg.command == MAV_CMD_SET_MESSAGE_INTERVAL
                                and msg.result != MAV_RESULT_ACCEPTED):
                            self._status("ack", f"SET_MESSAGE_INTERVAL refused (result {msg.result})")
                    if evs:
                        events += evs
                        trigger = mtype
                        if any(isinstance(e, Reboot) for e in evs):
                            r = next(e for e in evs if isinstance(e, Reboot))
                            self.last_t_s = r.t_s
                            self._status("reboot", f"boot time {r.previous_boot_s:.3f} s -> {r.new_boot_s:.3f} s")
                            self._request_streams("autopilot rebooted")
                            window_start = now
                            rate_counts.clear()
                if events:
                    self.last_t_s = max(self.last_t_s, events[-1].t_s)
                    if self._put is not None:
                        quiet = self.may_wait is not None and self.may_wait(events)
                        self._put(Batch(recv_perf, events, trigger, quiet), quiet)
            if self._wake_if_held is not None:
                self._wake_if_held(time.perf_counter())
            if self.target is not None and now - last_rx > c.link_timeout_s:
                self._status("lost", f"nothing from the autopilot for {c.link_timeout_s:g} s")
                return heard
            if window_start is not None and now - window_start >= s.check_period_s:
                span = now - window_start
                low = [n for n, hz in s.rates_hz.items() if rate_counts[n] / span < s.min_fraction * hz]
                if low:
                    got = ", ".join(f"{n} {rate_counts[n] / span:.1f} Hz" for n in low)
                    self._status("rate_low", got)
                    self._request_streams("rate below request", low)
                window_start = now
                rate_counts.clear()
        return heard
