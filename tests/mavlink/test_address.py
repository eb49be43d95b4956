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
