"""Byte transports for a MAVLink link: UDP (in/out), TCP (client/server) and serial, no dependency.

Each transport is blocking-with-timeout and used from one reader thread; ``write`` may be called from
another thread (the reader never writes while holding the transport's state). A closed peer raises
:class:`LinkClosed`; the link manager reconnects.
"""

from __future__ import annotations

import os
import select
import socket
import termios
import tty

from companion.sources.base import SourceError
from companion.mavlink.address import SERIAL_BAUDS as _BAUDS, LinkSpec


class LinkClosed(Exception):
    """The peer closed the connection or the device went away."""


class Transport:
    def recv(self, timeout_s: float) -> bytes:
        """Bytes that arrived within ``timeout_s`` (b"" when none)."""
        raise NotImplementedError

    def write(self, data: bytes) -> bool:
        """True when the bytes were handed to the OS; False when there is no peer to send to."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class UdpTransport(Transport):
    """``udpin``: bind and answer whoever sent last. ``udpout``: send to a fixed address."""

    def __init__(self, host: str, port: int, listen: bool) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        if listen:
            self.sock.bind((host, port))
            self.peer = None
        else:
            self.peer = (host, port)
        self.listen = listen

    def recv(self, timeout_s: float) -> bytes:
        r, _, _ = select.select([self.sock], [], [], timeout_s)
        if not r:
            return b""
        try:
            data, addr = self.sock.recvfrom(65536)
        except ConnectionRefusedError:
            return b""  # udpout with nobody listening yet (ICMP port unreachable)
        if self.listen:
            self.peer = addr
        return data

    def write(self, data: bytes) -> bool:
        if self.peer is None:
            return False
        try:
            self.sock.sendto(data, self.peer)
        except OSError:
            return False
        return True

    def close(self) -> None:
        self.sock.close()


class TcpTransport(Transport):
    """``tcp``: connect to a server (ArduPilot SITL listens on 5760). ``tcpin``: accept one client."""

    def __init__(self, host: str, port: int, listen: bool, connect_timeout_s: float = 2.0) -> None:
        self.listen_sock = None
        self.sock = None
        if listen:
            self.listen_sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.listen_sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.listen_sock.bind((host, port))
            self.listen_sock.listen(1)
        else:
            s = socket.create_connection((host, port), timeout=connect_timeout_s)
            self._setup(s)

    def _setup(self, s: socket.socket) -> None:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        s.settimeout(None)
        s.setblocking(True)
        self.sock = s

    def recv(self, timeout_s: float) -> bytes:
        if self.sock is None:
            r, _, _ = select.select([self.listen_sock], [], [], timeout_s)
            if r:
                s, _ = self.listen_sock.accept()
                self._setup(s)
            return b""
        r, _, _ = select.select([self.sock], [], [], timeout_s)
        if not r:
            return b""
        try:
            data = self.sock.recv(65536)
        except OSError as err:
            raise LinkClosed(f"connection error ({err.strerror or err})") from None
        if not data:
            raise LinkClosed("connection closed by the peer")
        return data

    def write(self, data: bytes) -> bool:
        s = self.sock
        if s is None:
            return False
        try:
            s.sendall(data)
        except OSError:
            return False  # the reader sees the closed connection and reconnects
        return True

    def close(self) -> None:
        for s in (self.sock, self.listen_sock):
            if s is not None:
                s.close()
        self.sock = self.listen_sock = None


class SerialTransport(Transport):
    """A tty in raw mode at ``baud`` (8N1, no flow control), through termios."""

    def __init__(self, device: str, baud: int) -> None:
        if baud not in _BAUDS:
            raise SourceError(f"{device}: baud rate {baud} is not supported (use one of {sorted(_BAUDS)[-8:]})")
        self.fd = os.open(device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            tty.setraw(self.fd)
            attr = termios.tcgetattr(self.fd)
            attr[4] = attr[5] = _BAUDS[baud]
            attr[2] = (attr[2] & ~(termios.CSTOPB | termios.PARENB | termios.CRTSCTS)) | termios.CLOCAL | termios.CREAD
            termios.tcsetattr(self.fd, termios.TCSANOW, attr)
        except termios.error as err:
            os.close(self.fd)
            raise SourceError(f"{device}: not a serial port ({err.args[-1]})") from None

    def recv(self, timeout_s: float) -> bytes:
        r, _, _ = select.select([self.fd], [], [], timeout_s)
        if not r:
            return b""
        try:
            data = os.read(self.fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as err:
            raise LinkClosed(f"serial device error ({err.strerror})") from None
        if not data:
            raise LinkClosed("serial device closed")
        return data

    def write(self, data: bytes) -> bool:
        try:
            view = memoryview(data)
            while view:
                n = os.write(self.fd, view)
                view = view[n:]
        except BlockingIOError:
            return False
        except OSError:
            return False
        return True

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def open_transport(spec: LinkSpec) -> Transport:
    """Open a link; OSError/SourceError when it cannot be opened now (the caller retries with back-off)."""
    if spec.kind == "serial":
        return SerialTransport(spec.url, spec.baud or 115200)
    scheme, host, port = spec.url.split(":")
    if scheme in ("udpin", "udpout"):
        return UdpTransport(host, int(port), listen=scheme == "udpin")
    return TcpTransport(host, int(port), listen=scheme == "tcpin")
