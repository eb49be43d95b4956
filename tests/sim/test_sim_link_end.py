"""The simulator's TCP link at the end of its flight: a client behind the stream still gets every message sent.

A socket closed with unread input sends a reset, and the kernel then drops what it had not yet transmitted: a
companion behind a fast playback lost its last seconds (a gravity HIL test saw 411 of 694 readings under load).
"""

from __future__ import annotations

import socket
import time

from companion.mavlink.dialect import mavlink as mavlink2
from tests.runtime.test_hil import Sim


def test_a_slow_client_receives_every_message_sent(tmp_path):
    sim = Sim(tmp_path, "--speed", 20, "--streams", "all")
    got = 0
    try:
        deadline = time.monotonic() + 120  # "sim:" is printed before it listens: connect once it does
        while True:
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # a small window: the backlog sits in the sender
            try:
                sock.connect(("127.0.0.1", sim.port))
                break
            except ConnectionRefusedError:
                sock.close()
                assert time.monotonic() < deadline and sim.proc.poll() is None, "the simulator never listened"
                time.sleep(0.05)
        sock.settimeout(0.05)
        me = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        heartbeat = bytes(me.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(me))
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        deadline = time.monotonic() + 600  # generous: the flight is ~9 s at x20, longer as this client holds it back
        reset = False
        while time.monotonic() < deadline:
            try:
                sock.sendall(heartbeat)  # input the simulator has to read: unread at its close, it made the reset
            except OSError:
                pass
            try:
                data = sock.recv(1024)  # about 20 kB/s: slower than the x20 stream
            except TimeoutError:
                continue
            except ConnectionResetError:
                reset = True
                break
            if not data:
                break  # the simulator half-closed after its last message
            got += sum(1 for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA")
            time.sleep(0.04)
        sock.close()
    finally:
        if sim.proc.poll() is None and not got:
            sim.proc.kill()  # failed before any message came: leave no simulator listening
    recs = sim.finish(timeout=120)
    end = next(r for r in recs if r["event"] == "end")
    sent = sum(end["sent"].values())
    assert sent > 10000, end  # the whole sample flight was played
    assert not reset
    assert got == sent, (got, sent)
