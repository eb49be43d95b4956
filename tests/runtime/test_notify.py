"""sd_notify protocol against a local datagram socket standing in for systemd."""

from __future__ import annotations

import os
import socket
import tempfile
from pathlib import Path

import pytest

from companion.notify import Notifier
from tests.conftest import REPO, free_port


def _server(tmp_path):
    # a unix socket path is at most 107 bytes: a nested or parallel pytest's tmp_path can be longer (then: a short
    # directory of its own under /tmp)
    path = str(tmp_path / "notify.sock")
    if len(path.encode()) > 100:
        path = str(Path(tempfile.mkdtemp(prefix="cn-", dir="/tmp")) / "notify.sock")
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


def test_service_process_sends_ready_watchdog_stopping(tmp_path):
    """`companion run` under a fake systemd: READY once running, WATCHDOG pings, STOPPING on SIGTERM."""
    import signal
    import subprocess
    import sys
    import threading
    import time

    from companion.sim.playback import playback_from_flight
    from companion.sim.vehicle import VehicleSim

    srv, path = _server(tmp_path)
    port = free_port()
    sim = VehicleSim(playback_from_flight(), f"tcpin:127.0.0.1:{port}", start_s=20.0)
    th = threading.Thread(target=sim.run, daemon=True)
    th.start()
    env = dict(os.environ, NOTIFY_SOCKET=path, WATCHDOG_USEC="1000000")
    proc = subprocess.Popen(
        [sys.executable, "-m", "companion.cli", "run", "--connect", f"tcp:127.0.0.1:{port}", "--out", str(tmp_path / "s.mcap")],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    got: list[bytes] = []
    t_end = time.monotonic() + 180  # a loaded machine can take many seconds to import and start: wait for the pings
    while time.monotonic() < t_end and sum(m == b"WATCHDOG=1" for m in got) < 4 and proc.poll() is None:
        try:
            got.append(srv.recv(4096))
        except TimeoutError:
            continue
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    srv.settimeout(0.5)
    try:
        while True:
            got.append(srv.recv(4096))
    except TimeoutError:
        pass
    sim.stop()
    th.join(5)
    assert proc.returncode == 0, err
    assert got[0].startswith(b"READY=1\nSTATUS=")
    assert sum(m == b"WATCHDOG=1" for m in got) >= 4  # pinged every WATCHDOG_USEC / 2
    assert any(m.startswith(b"STATUS=link autopilot") for m in got)
    assert b"STOPPING=1" in got
    srv.close()


def test_unit_file_verifies_and_is_hardened(tmp_path):
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    repo = REPO
    unit = (repo / "systemd" / "companion.service").read_text()
    for directive in ("Type=notify", "WatchdogSec=", "Restart=on-failure", "User=companion", "SupplementaryGroups=dialout",
                      "NoNewPrivileges=yes", "ProtectSystem=strict", "ReadWritePaths=/var/lib/companion", "PrivateTmp=yes",
                      "After=network-online.target", "Wants=network-online.target", "SystemCallFilter=@system-service",
                      "DeviceAllow=char-ttyTHS rw"):
        assert directive in unit, directive
    exe = Path(sys.executable).parent / "companion"
    if shutil.which("systemd-analyze") is None:
        import pytest

        pytest.skip("systemd-analyze not installed (CI installs Debian's systemd package)")
    # verify the unit as installed, with ExecStart pointing at this checkout's console script
    local = tmp_path / "companion.service"
    local.write_text(unit.replace("/opt/companion/.venv/bin/companion", str(exe)))
    res = subprocess.run(["systemd-analyze", "verify", str(local)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "companion.service" not in res.stderr, res.stderr  # no warnings about our unit


@pytest.mark.parametrize("fault", ["dies", "hangs"])
def test_watchdog_stops_when_the_link_reader_dies_or_hangs(tmp_path, fault):
    """The process may be up but deaf: a link reader that died (an error it cannot handle) or hangs must stop the
    WATCHDOG pings, so systemd restarts the service; a reader that dies says why."""
    import asyncio
    import threading
    import time

    from companion.config import load_config
    from companion.runtime.runner import Runtime

    srv, path = _server(tmp_path)
    srv.setblocking(False)
    notifier = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "400000"})  # a ping every 0.2 s
    cfg = load_config(None, {"link.connect": f"udpin:127.0.0.1:{free_port()}"})
    logs: list[str] = []
    rt = Runtime(cfg, None, notifier=notifier, log=logs.append)
    release = threading.Event()

    def pings() -> int:
        n = 0
        while True:
            try:
                n += srv.recv(4096) == b"WATCHDOG=1"
            except BlockingIOError:
                return n

    async def until(cond, limit_s=120.0):
        end = time.monotonic() + limit_s
        while not cond():
            assert time.monotonic() < end, "timed out"
            await asyncio.sleep(0.02)

    def broken_recv(timeout_s):
        if fault == "dies":
            raise RuntimeError("reader broken by the test")
        release.wait(60)  # hangs (until the test ends)
        return b""

    async def main():
        task = asyncio.ensure_future(rt.run())
        seen = [0]
        await until(lambda: rt.link._transport is not None)
        await until(lambda: seen.__setitem__(0, seen[0] + pings()) or seen[0] >= 2)  # pinging while all is well
        rt.link._transport.recv = broken_recv
        if fault == "dies":
            await until(lambda: not rt.link.thread_alive)
        else:
            await until(lambda: time.monotonic() - rt.link.alive_at > 2 * notifier.watchdog_period_s)
        await asyncio.sleep(notifier.watchdog_period_s)  # a ping already decided may still be on its way
        pings()
        quiet_from = time.monotonic()
        await asyncio.sleep(5 * notifier.watchdog_period_s)
        late = pings()
        quiet_s = time.monotonic() - quiet_from
        release.set()
        rt._stop_requested = True
        task.cancel()
        try:
            await task
        except asyncio.CancelledError:
            pass
        return late, quiet_s

    late, quiet_s = asyncio.run(main())
    srv.close()
    assert late == 0, f"{late} WATCHDOG pings in the {quiet_s:.1f} s after the link reader {fault}"
    if fault == "dies":
        assert any("link failed" in line and "reader broken by the test" in line for line in logs), logs
