"""The link reader under load: IMU frames thinned at the byte level, arrival times from the kernel, one UDP read for
every datagram waiting, and at most one wake-up of the event loop pending however fast the reader posts."""

from __future__ import annotations

import asyncio
import select
import socket
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.mavlink.shed import ImuShedder
from companion.mavlink.transport import TCP_READ_BYTES, ArrivalTracker, TcpTransport, UdpTransport, _queued_bytes
from tests.conftest import free_port


def _frames(n_imu=2000, imu_hz=4000.0, garbage=False):
    """RAW_IMU at imu_hz from (1, 1), an ATTITUDE every 100 of them, garbage (with magic bytes) after every 500th."""
    tx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out, atts = [], 0
    for k in range(n_imu):
        out.append(bytes(mavlink2.MAVLink_raw_imu_message(int(1e6 + k * 1e6 / imu_hz), k % 100, 2, 3, 4, 5, 6, 7, 8, 9,
                                                          0, 20).pack(tx)))
        tx.seq = (tx.seq + 1) % 256
        if k % 100 == 0:
            out.append(bytes(mavlink2.MAVLink_attitude_message(1000 + k, 0.1, 0.2, 0.3, 0, 0, 0).pack(tx)))
            tx.seq = (tx.seq + 1) % 256
            atts += 1
        if garbage and k % 500 == 499:
            out.append(b"\xfd\x05garbage\xfe")
    return b"".join(out), atts


def _shed_and_parse(data, min_interval_s=0.01, read=4096):
    shed = ImuShedder(min_interval_s)
    kept = b"".join(shed.filter(data[i:i + read]) for i in range(0, len(data), read))
    rx = mavlink2.MAVLink(None)
    rx.robust_parsing = True
    return shed, [m.get_type() for m in rx.parse_buffer(kept) or []], rx


def test_shedder_thins_imu_to_its_interval_and_passes_everything_else():
    data, atts = _frames()
    shed, types, _ = _shed_and_parse(data)  # one RAW_IMU per 10 ms of its own time: 2000 at 4 kHz (0.5 s) -> 50
    assert types.count("ATTITUDE") == atts and "BAD_DATA" not in types  # nothing else touched, no frame broken
    n_imu = types.count("RAW_IMU")
    cut = len(data) // 4096 + 1  # a frame cut by a read's end goes to the parser whole
    assert 50 <= n_imu <= 50 + cut and shed.kept == 50 and shed.shed >= 2000 - 50 - cut


def test_shedder_loses_nothing_to_garbage_the_parser_would_keep():
    data, atts = _frames(garbage=True)
    rx = mavlink2.MAVLink(None)
    rx.robust_parsing = True
    alone = [m.get_type() for m in rx.parse_buffer(data)]
    lost_alone = (atts - alone.count("ATTITUDE")) + (2000 - alone.count("RAW_IMU"))  # what the resync eats: 3
    shed, types, _ = _shed_and_parse(data)
    assert shed.shed > 1800
    # the frame after each garbage block is eaten by the parser's resync, whichever frame that is
    assert types.count("ATTITUDE") >= atts - lost_alone


def test_shedder_keeps_a_time_going_back_and_other_senders():
    tx1 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    tx2 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=2)

    def imu(tx, t_us):
        return bytes(mavlink2.MAVLink_raw_imu_message(t_us, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(tx))

    data = imu(tx1, 5_000_000) + imu(tx2, 5_000_100) + imu(tx1, 5_000_200) + imu(tx1, 1_000) + imu(tx1, 1_100)
    shed = ImuShedder(0.01)
    rx = mavlink2.MAVLink(None)
    kept = [(m.get_srcComponent(), m.time_usec) for m in rx.parse_buffer(shed.filter(data))]
    # the second sender has its own interval; a reboot's time going back is kept (the clock judges it)
    assert kept == [(1, 5_000_000), (2, 5_000_100), (1, 1_000)]


def test_arrival_tracker_dates_bytes_by_the_first_read_that_saw_them_queued():
    now = [0.0]
    tr = ArrivalTracker(clock=lambda: now[0])
    assert tr.observe(100, 0) == 0.0  # nothing left behind: they just arrived
    now[0] = 1.0
    assert tr.observe(100, 900) == 0.0  # 1000 bytes seen by t = 1.0
    now[0] = 3.0
    assert tr.observe(500, 0) == 2.0  # already queued at t = 1.0
    now[0] = 3.5
    assert tr.observe(400, 0) == 2.5  # up to byte 1100, queued at t = 1.0 too
    now[0] = 4.0
    assert tr.observe(100, 0) == 0.0  # beyond: only this read saw them


def _until_kernel_stamps(send, transport) -> None:
    """Wait until the kernel stamps arrivals. Linux turns its receive stamps on with deferred work after the first
    socket asks (net_enable_timestamp); until it has run, a read gets its own time as the stamp (age ~0). A probe
    that waited 0.05 s in the queue and reads as that old shows the stamps are on (up to 60 s, for a loaded machine)."""
    end = time.monotonic() + 60
    while time.monotonic() < end:
        send(b"p")
        time.sleep(0.05)
        if transport.recv(5.0) == b"p" and transport.last_age_s >= 0.04:
            return
    raise AssertionError("the kernel never stamped a received datagram or segment")


def test_udp_read_takes_every_datagram_waiting_with_its_kernel_age():
    port = free_port()
    rx = UdpTransport("127.0.0.1", port, listen=True)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        _until_kernel_stamps(lambda b: tx.sendto(b, ("127.0.0.1", port)), rx)
        t_first = time.monotonic()  # before the first datagram: an upper bound of their age whatever the load
        for k in range(5):
            tx.sendto(bytes([k]) * 100, ("127.0.0.1", port))
        # the first datagram is in the kernel's queue (stamped) once the socket is readable: under heavy load the
        # loopback delivery itself can lag the send, so the wait starts from there, not from the send
        assert select.select([rx.sock], [], [], 30.0)[0]
        time.sleep(0.3)  # the datagrams wait in the kernel this long (at least)
        data = rx.recv(5.0)
        waited = time.monotonic() - t_first
        assert data == b"".join(bytes([k]) * 100 for k in range(5))
        assert 0.3 <= rx.last_age_s <= waited + 0.01  # (+ the wall and monotonic clocks' read-out skew)
        assert rx.recv(0.0) == b"" and rx.last_age_s == 0.0
    finally:
        tx.close()
        rx.close()


def _accepted_tcp_pair():
    """A listening TcpTransport and a client connected to it, once the transport has accepted (waits up to 60 s)."""
    port = free_port()
    srv = TcpTransport("127.0.0.1", port, listen=True)
    cli = socket.create_connection(("127.0.0.1", port))
    end = time.monotonic() + 60
    while srv.sock is None and time.monotonic() < end:
        srv.recv(0.1)
    return srv, cli


def test_tcp_read_reports_the_kernel_age_of_its_bytes():
    srv, cli = _accepted_tcp_pair()
    try:
        _until_kernel_stamps(cli.sendall, srv)
        t_first = time.monotonic()
        cli.sendall(b"x" * 1000)
        time.sleep(0.3)
        data = srv.recv(5.0)
        waited = time.monotonic() - t_first
        assert data == b"x" * 1000 and srv.last_pending == 0
        assert 0.3 <= srv.last_age_s <= waited + 0.01
    finally:
        cli.close()
        srv.close()


def test_tcp_read_waits_out_its_timeout_and_a_full_read_reports_what_is_left():
    """The read waits up to its time-out (SO_RCVTIMEO, no select), 0 does not wait; a read that fills the buffer says how
    many bytes the kernel still holds (the reader's "behind" signal), one that empties the queue says 0."""
    srv, cli = _accepted_tcp_pair()
    try:
        t0 = time.monotonic()
        assert srv.recv(0.2) == b""
        assert time.monotonic() - t0 >= 0.19
        assert srv.recv(0.0) == b""
        extra = 5000
        cli.sendall(b"y" * (TCP_READ_BYTES + extra))
        while _queued_bytes(srv.sock) < TCP_READ_BYTES + extra and time.monotonic() < end:
            time.sleep(0.01)
        assert srv.recv(5.0) == b"y" * TCP_READ_BYTES and srv.last_pending == extra
        assert srv.recv(5.0) == b"y" * extra and srv.last_pending == 0
    finally:
        cli.close()
        srv.close()


def test_reader_posts_wake_the_loop_once_however_many_items():
    """100,000 items from the reader thread: in order, and never more than one loop wake-up pending (one
    call_soon_threadsafe per item fills asyncio's self-pipe, which then eats a signal's wake-up byte)."""
    from companion.config import LinkConfig, StreamConfig
    from companion.mavlink.link import MavlinkLink

    link = MavlinkLink(LinkConfig(connect=f"udpin:127.0.0.1:{free_port()}"), StreamConfig())
    n = 100_000
    link._run = lambda: [link._put(k) for k in range(n)]
    got: list[int] = []
    pending = [0, 0]  # now, most ever

    async def main():
        loop = asyncio.get_running_loop()
        orig = loop.call_soon_threadsafe

        def counted(cb, *args):
            pending[0] += 1
            pending[1] = max(pending[1], pending[0])

            def run():
                pending[0] -= 1
                cb(*args)

            return orig(run)

        loop.call_soon_threadsafe = counted
        link.start(loop, got.append)
        end = time.monotonic() + 120
        while len(got) < n and time.monotonic() < end:
            await asyncio.sleep(0.01)
        link._thread.join(10)

    asyncio.run(main())
    assert got == list(range(n))
    assert pending[1] == 1


def test_fuzz_peer_burst_frames_are_what_pymavlink_packs():
    """The peer's fast burst frames (tabled CRC) are byte for byte pymavlink's, sequence numbers wrapping."""
    from replay.fuzz.frames import FastFrames

    tmpl = mavlink2.MAVLink_raw_imu_message(5, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0, 20)
    fast_tx, ref_tx = mavlink2.MAVLink(None, 1, 1), mavlink2.MAVLink(None, 1, 1)
    fast_tx.seq = ref_tx.seq = 250
    times = [1_000_000 + 25 * k for k in range(20)] + [2**40 + 7]
    ref = []
    for t in times:
        tmpl.time_usec = t
        ref.append(bytes(tmpl.pack(ref_tx)))
        ref_tx.seq = (ref_tx.seq + 1) % 256
    assert FastFrames(tmpl, fast_tx).frames(times) == b"".join(ref)
    assert fast_tx.seq == ref_tx.seq
