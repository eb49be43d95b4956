"""sd_notify protocol against a local datagram socket standing in for systemd."""

from __future__ import annotations

import os
import socket

from companion.notify import Notifier


def _server(tmp_path):
    path = str(tmp_path / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(path)
    srv.settimeout(2.0)
    return srv, path


def test_ready_status_watchdog_datagrams(tmp_path):
    srv, path = _server(tmp_path)
    n = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "4000000", "WATCHDOG_PID": str(os.getpid())})
    assert n.enabled and n.watchdog_period_s == 2.0
    assert n.ready("connected to 1/1")
    assert srv.recv(4096) == b"READY=1\nSTATUS=connected to 1/1"
    assert n.watchdog()
    assert srv.recv(4096) == b"WATCHDOG=1"
    assert n.stopping()
    assert srv.recv(4096) == b"STOPPING=1"
    assert n.sent == 3 and n.errors == 0
    n.close()
    srv.close()


def test_abstract_namespace_socket():
    name = f"companion-test-{os.getpid()}"
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind("\0" + name)
    srv.settimeout(2.0)
    n = Notifier({"NOTIFY_SOCKET": "@" + name})
    assert n.ready()
    assert srv.recv(100) == b"READY=1"
    srv.close()


def test_without_systemd_does_nothing():
    n = Notifier({})
    assert not n.enabled and n.watchdog_period_s is None
    assert not n.ready() and not n.watchdog()


def test_watchdog_for_another_pid_is_ignored(tmp_path):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "x"), "WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"})
    assert n.watchdog_period_s is None or os.getpid() == 1


def test_socket_gone_is_counted_not_raised(tmp_path):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "missing.sock")})
    assert not n.ready() and n.errors == 1
