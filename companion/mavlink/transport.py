"""Byte transports for a MAVLink link: UDP (in/out), TCP (client/server) and serial, no dependency.

Each transport is blocking-with-timeout and used from one reader thread; ``write`` may be called from
another thread (the reader never writes while holding the transport's state). A closed peer raises
:class:`LinkClosed`; the link manager reconnects.

How far behind the reader is, after each ``recv``: ``last_pending`` (bytes the kernel still holds) and
``last_age_s``, how long ago the bytes just read reached the machine, from the kernel's receive time stamps
(``SO_TIMESTAMPNS``): UDP, the oldest datagram read (conservative); TCP, the newest bytes read (what the kernel
gives); until Linux has turned its stamps on (deferred work after the first socket asks, moments after start) a
read is stamped with its own time and reads as fresh. Serial (no time stamps): the first time the reader saw the
kernel's queue reach those bytes (:class:`ArrivalTracker`), exact to one read while the reader keeps reading. UDP
reads take every datagram waiting (up to :data:`UDP_DRAIN_BYTES`) at once.
"""

from __future__ import annotations

import fcntl
import os
import select
import socket
import struct
import termios
import time
import tty
from collections import deque

from companion.sources.base import SourceError
from companion.mavlink.address import SERIAL_BAUDS as _BAUDS, LinkSpec


class LinkClosed(Exception):
    """The peer closed the connection or the device went away."""


#: one UDP read takes the datagrams waiting up to this many bytes
UDP_DRAIN_BYTES = 1 << 18
#: one TCP read takes up to this many bytes
TCP_READ_BYTES = 1 << 16
_TIMEVAL = struct.Struct("@ll")  # SO_RCVTIMEO: struct timeval
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux: a struct timespec (CLOCK_REALTIME) per datagram
_TIMESPEC = struct.Struct("@qq")


def _enable_stamps(sock: socket.socket) -> None:
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        pass  # no kernel time stamps: ages read as 0 (unknown)


def _stamp_age_s(anc) -> float | None:
    """Age of the kernel's receive time stamp in recvmsg's ancillary data (None when there is none). The kernel
    stamps wall-clock time: clamped, so a clock step cannot make it negative or absurd."""
    for level, kind, raw in anc:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(raw) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(raw)
            return min(max(time.time() - (sec + nsec * 1e-9), 0.0), 60.0)
    return None


def _queued_bytes(fd) -> int:
    """Bytes waiting in the kernel's receive queue of a socket or tty (FIONREAD); 0 when it cannot tell."""
    try:
        return struct.unpack("@i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
    except (OSError, ValueError):
        return 0


class ArrivalTracker:
    """When the bytes of a byte stream arrived, from what the kernel's queue held at each read.

    After each read ``observe(n, queued)`` records (now, offset known to have arrived = bytes read + queued); the
    bytes just read arrived by the first such record that covers their end offset."""

    def __init__(self, clock=time.perf_counter) -> None:
        self.clock = clock
        self.read = 0
        self._seen: deque[tuple[float, int]] = deque()

    def observe(self, nbytes: int, queued: int) -> float:
        """Age (s) of the last byte of a read of ``nbytes``, ``queued`` bytes still waiting after it."""
        now = self.clock()
        self.read += nbytes
        self._seen.append((now, self.read + queued))
        while self._seen[0][1] < self.read:
            self._seen.popleft()
        return now - self._seen[0][0]


class Transport:
    #: after a recv: how long ago its newest bytes arrived (0 when unknown), and how many are still queued
    last_age_s: float = 0.0
    last_pending: int = 0

    def recv(self, timeout_s: float) -> bytes:
        """Bytes that arrived within ``timeout_s`` (b"" when none)."""
        raise NotImplementedError

    def write(self, data: bytes) -> bool:
        """True when the bytes were handed to the OS; False when there is no peer to send to."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class UdpTransport(Transport):
    """``udpin``: bind and answer whoever sent last. ``udpout``: send to a fixed address. ``udpbcast``: send to a
    broadcast address until the first datagram arrives, then only to its sender (pymavlink's mavudp broadcast)."""

    def __init__(self, host: str, port: int, listen: bool, broadcast: bool = False) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        _enable_stamps(self.sock)
        if listen:
            self.sock.bind((host, port))
            self.peer = None
        else:
            self.peer = (host, port)
            if broadcast:
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self.listen = listen
        self.broadcast = broadcast and not listen  # True until the first datagram names the peer

    def recv(self, timeout_s: float) -> bytes:
        r, _, _ = select.select([self.sock], [], [], timeout_s)
        self.last_age_s = 0.0
        if not r:
            return b""
        chunks: list[bytes] = []
        size = 0
        age_s = None
        while size < UDP_DRAIN_BYTES:
            try:
                data, anc, _flags, addr = self.sock.recvmsg(65536, 64, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:
                break  # udpout with nobody listening yet (ICMP port unreachable)
            if age_s is None:
                age_s = _stamp_age_s(anc)  # the oldest datagram of the read
            if self.listen:
                self.peer = addr
            elif self.broadcast:
                self.peer, self.broadcast = addr, False  # the vehicle answered: talk to it alone from now on
            chunks.append(data)
            size += len(data)
        self.last_age_s = age_s or 0.0
        self.last_pending = _queued_bytes(self.sock)  # the next datagram's size: nonzero when some were left
        return b"".join(chunks)

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
        self._arrivals = ArrivalTracker()
        self._rcvtimeo_s: float | None = None  # the socket's SO_RCVTIMEO
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
        _enable_stamps(s)
        s.settimeout(None)
        s.setblocking(True)
        self.sock = s
        self._rcvtimeo_s = None

    def recv(self, timeout_s: float) -> bytes:
        if self.sock is None:
            r, _, _ = select.select([self.listen_sock], [], [], timeout_s)
            if r:
                s, _ = self.listen_sock.accept()
                self._setup(s)
            return b""
        # one system call a read: the read itself waits (SO_RCVTIMEO; EAGAIN when nothing came), no select before it
        if timeout_s > 0 and timeout_s != self._rcvtimeo_s:
            sec = int(timeout_s)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, _TIMEVAL.pack(sec, min(999_999, max(1, round((timeout_s - sec) * 1e6)))))
            self._rcvtimeo_s = timeout_s
        try:
            data, anc, _flags, _addr = self.sock.recvmsg(TCP_READ_BYTES, 64, 0 if timeout_s > 0 else socket.MSG_DONTWAIT)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as err:
            raise LinkClosed(f"connection error ({err.strerror or err})") from None
        if not data:
            raise LinkClosed("connection closed by the peer")
        # a read that did not fill the buffer emptied the kernel's queue (Linux's tcp_recvmsg returns short only then):
        # what is queued now came in since and the next read takes it; FIONREAD only after a full read
        self.last_pending = _queued_bytes(self.sock) if len(data) == TCP_READ_BYTES else 0
        tracked = self._arrivals.observe(len(data), self.last_pending)
        stamped = _stamp_age_s(anc)
        self.last_age_s = tracked if stamped is None else stamped
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
        self._arrivals = ArrivalTracker()
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
        self.last_pending = _queued_bytes(self.fd)
        self.last_age_s = self._arrivals.observe(len(data), self.last_pending)
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
    if scheme in ("udpin", "udpout", "udpbcast"):
        return UdpTransport(host, int(port), listen=scheme == "udpin", broadcast=scheme == "udpbcast")
    return TcpTransport(host, int(port), listen=scheme == "tcpin")
