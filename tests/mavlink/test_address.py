"""Connection strings: a serial device not there yet is a link not up yet; a malformed one is refused at once."""

from __future__ import annotations

import os

import pytest

from companion.mavlink.address import SERIAL_BAUDS, parse_url
from companion.sources.base import SourceError


def test_a_missing_serial_device_parses_for_a_later_open():
    spec = parse_url("/dev/ttyCOMPANIONNOTTHERE,921600")
    assert (spec.kind, spec.url, spec.baud) == ("serial", "/dev/ttyCOMPANIONNOTTHERE", 921600)
    assert parse_url("/dev/ttyCOMPANIONNOTTHERE").baud == 115200 and 921600 in SERIAL_BAUDS


def test_a_pty_is_a_serial_device():
    master, slave = os.openpty()
    try:
        name = os.ttyname(slave)
        if not name.startswith("/dev/"):
            pytest.skip(f"pty outside /dev: {name}")
        assert parse_url(name, 57600).kind == "serial"
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("url,why", [("/dev/ttyCOMPANIONNOTTHERE,12345", "baud rate 12345 is not supported"),
                                     ("/dev/ttyUSB0,fast", "is not a number"),
                                     ("/dev/shm", "not a character device"),
                                     ("tcp:1.2.3.4:70000", "out of range"),
                                     ("ttyUSB0", "not a connection string")])
def test_malformed_links_are_refused(url, why):
    with pytest.raises(SourceError, match=why):
        parse_url(url)


@pytest.mark.parametrize("url,kind,normal", [
    ("127.0.0.1:14550", "udpin", "udpin:127.0.0.1:14550"),  # mavutil: a bare HOST:PORT listens (input=True)
    ("localhost:14550", "udpin", "udpin:localhost:14550"),
    ("udp:0.0.0.0:14550", "udpin", "udpin:0.0.0.0:14550"),  # mavutil's legacy udp: with its default input=True
    ("udpbcast:192.168.1.255:14550", "udpbcast", "udpbcast:192.168.1.255:14550"),
    ("udpout:10.0.0.2:14550", "udpout", "udpout:10.0.0.2:14550"),
    ("tcpin:0.0.0.0:5760", "tcpin", "tcpin:0.0.0.0:5760"),
])
def test_mavutil_connection_strings(url, kind, normal):
    spec = parse_url(url)
    assert (spec.kind, spec.url) == (kind, normal)


@pytest.mark.parametrize("url,why", [("mcast:", "multicast is not supported"), ("uds:/run/mav.sock", "Unix domain"),
                                     ("unix:/run/mav.sock", "Unix domain"), ("ws:host:80", "WebSocket"),
                                     ("wsserver:0.0.0.0:80", "WebSocket"), ("flight.tlog", "replay it"),
                                     ("csv:x.csv", "not a link"), ("127.0.0.1:99999", "out of range")])
def test_unsupported_mavutil_strings_say_why(url, why):
    with pytest.raises(SourceError, match=why):
        parse_url(url)


def test_udpbcast_sends_to_the_broadcast_address_then_to_whoever_answered():
    import socket

    from companion.mavlink.transport import open_transport

    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    vehicle.bind(("127.0.0.1", 0))
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    vehicle.settimeout(10.0)
    other.settimeout(10.0)
    link = open_transport(parse_url(f"udpbcast:127.0.0.1:{vehicle.getsockname()[1]}"))
    try:
        assert link.write(b"hello")  # no answer yet: to the (broadcast) address given
        data, ours = vehicle.recvfrom(100)
        assert data == b"hello"
        other.sendto(b"answer", ours)  # the first answer names the peer ...
        assert link.recv(10.0) == b"answer"
        assert link.write(b"again")  # ... and from then on only it gets our datagrams
        assert other.recvfrom(100)[0] == b"again"
    finally:
        link.close()
        vehicle.close()
        other.close()
