"""systemd's notify protocol (sd_notify(3)) without a dependency: READY, STATUS, WATCHDOG, STOPPING.

With ``Type=notify`` systemd passes ``NOTIFY_SOCKET`` (a path, or ``@name`` for the abstract namespace)
and, with ``WatchdogSec=``, ``WATCHDOG_USEC`` (and ``WATCHDOG_PID``). Each notification is one datagram of
``KEY=VALUE`` lines on that AF_UNIX socket. Outside systemd (no NOTIFY_SOCKET) every call does nothing.

Written here on purpose: systemd documents the protocol as its stable interface and gives a standalone
reimplementation in sd_notify(3) ("Standalone Implementations") rather than asking programs to link libsystemd.
The Python packages were measured against it: ``systemd-python`` and ``cysystemd`` ship no wheels (a C build
against libsystemd-dev on the vehicle), ``sdnotify`` (last release 2017) does not read ``WATCHDOG_USEC`` /
``WATCHDOG_PID``, which this module needs for the watchdog period.
"""

from __future__ import annotations

import os
import socket


class Notifier:
    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        addr = env.get("NOTIFY_SOCKET", "")
        self.address: str | None = None
        if addr:
            if addr.startswith("@"):
                addr = "\0" + addr[1:]  # abstract namespace
            if addr.startswith(("/", "\0")):
                self.address = addr
        self.watchdog_usec = 0
        wd = env.get("WATCHDOG_USEC", "")
        pid = env.get("WATCHDOG_PID", "")
        if wd.isdigit() and (not pid or pid == str(os.getpid())):
            self.watchdog_usec = int(wd)
        self._sock: socket.socket | None = None
        self.sent: int = 0
        self.errors: int = 0

    @property
    def enabled(self) -> bool:
        return self.address is not None

    @property
    def watchdog_period_s(self) -> float | None:
        """How often to ping: half the watchdog timeout, as sd_watchdog_enabled(3) recommends; None if off."""
        return self.watchdog_usec / 2e6 if self.watchdog_usec else None

    def notify(self, **fields: str | int) -> bool:
        """Send ``KEY=VALUE`` lines (keys upper-cased); True when the datagram went out."""
        if self.address is None:
            return False
        data = "\n".join(f"{k.upper()}={v}" for k, v in fields.items()).encode()
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(data, self.address)
        except OSError:
            self.errors += 1  # systemd gone or socket full: the service keeps running
            return False
        self.sent += 1
        return True

    def ready(self, status: str = "") -> bool:
        return self.notify(READY=1, STATUS=status) if status else self.notify(READY=1)

    def status(self, text: str) -> bool:
        return self.notify(STATUS=text)

    def watchdog(self) -> bool:
        return self.notify(WATCHDOG=1)

    def stopping(self) -> bool:
        return self.notify(STOPPING=1)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
