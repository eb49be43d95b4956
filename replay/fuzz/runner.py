"""Run ``companion`` on one input with a hard time-out and a memory cap; measure wall, CPU and peak RSS.

Two ways, same measurements:

* :func:`run_subprocess`: ``python -m companion.cli ARGS`` as a new process (what a user runs; the benchmark);
* :func:`run_forked`: a child forked from this process, which has imported the companion already, runs
  ``companion.cli.main(ARGS)`` with its stdout/stderr on files and exits with its return code; an uncaught
  exception is printed as Python would print it (a traceback, exit 1). No interpreter start-up and import per
  run, so a CI-sized fuzz fits in minutes. Fork only from a process without threads.

Both poll the child with ``os.wait4`` (its rusage: ``ru_maxrss`` is the peak RSS, utime + stime the CPU) and
read its RSS from /proc while it runs: past ``timeout_s`` or ``mem_cap_kb`` the child's process group is
killed (``killed`` = "timeout" / "memory"). In a forked child the peak RSS includes the pages it shares with
its parent: compare it with a clean run measured the same way.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

CLI = [sys.executable, "-m", "companion.cli"]
_PAGE_KB = os.sysconf("SC_PAGE_SIZE") // 1024


@dataclass
class RunResult:
    returncode: int | None  # None when killed; negative: ended by that signal
    wall_s: float
    cpu_s: float
    maxrss_kb: int
    stdout: str
    stderr: str
    killed: str = ""  # "", "timeout" or "memory"
    shared_kb: int = 0  # forked child: its RSS right after the fork (counted in maxrss_kb too); 0 for a subprocess

    @property
    def own_rss_kb(self) -> int:
        """Peak RSS beyond what a forked child shares with its parent (a subprocess: its peak RSS)."""
        return self.maxrss_kb - self.shared_kb


def replay_args(log: str | os.PathLike, out: str | os.PathLike) -> list[str]:
    return ["replay", str(log), "--out", str(out), "--quiet"]


def _rss_kb(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * _PAGE_KB
    except (OSError, ValueError, IndexError):
        return 0


def _watch(pid: int, t0: float, timeout_s: float, mem_cap_kb: int | None, poll_s: float = 0.01, rss_pid=None,
           rss_offset=None):
    """Wait for ``pid``; kill its group past the limits. Returns (wait status, rusage, killed).
    ``rss_pid()``: the pid whose RSS the memory cap applies to (default ``pid``); ``rss_offset()``: RSS not
    counted against the cap (a forked child's shared pages)."""
    killed = ""
    while True:
        wpid, status, ru = os.wait4(pid, os.WNOHANG)
        if wpid == pid:
            return status, ru, killed
        if not killed:
            watched = rss_pid() if rss_pid else pid
            if time.monotonic() - t0 > timeout_s:
                killed = "timeout"
            elif mem_cap_kb and watched and (off := rss_offset() if rss_offset else 0) is not None \
                    and _rss_kb(watched) - off > mem_cap_kb:
                killed = "memory"
            if killed:
                for target in (lambda: os.killpg(pid, signal.SIGKILL), lambda: os.kill(pid, signal.SIGKILL)):
                    try:
                        target()
                        break
                    except OSError:
                        pass
        time.sleep(poll_s)


def _result(status: int, ru, wall: float, out_path: Path, err_path: Path, killed: str, shared_kb: int = 0) -> RunResult:
    code = os.waitstatus_to_exitcode(status)
    return RunResult(
        returncode=None if killed else code,
        wall_s=wall,
        cpu_s=ru.ru_utime + ru.ru_stime,
        maxrss_kb=int(ru.ru_maxrss),
        stdout=out_path.read_text(errors="replace"),
        stderr=err_path.read_text(errors="replace"),
        killed=killed,
        shared_kb=shared_kb,
    )


#: A peak RSS measured by wait4 includes the RSS of the process that forked the child (the kernel keeps the
#: high-water mark across exec), so the command is started by this small interpreter (``python -I -S``, a few
#: MB): it forks and execs the command, writes the command's pid, then its wait4 status and rusage.
_SPAWNER = """
import os, sys
out = sys.argv[1]
pid = os.fork()
if pid == 0:
    try:
        os.execv(sys.argv[2], sys.argv[2:])
    finally:
        os._exit(127)
with open(out, "w") as f:
    f.write(f"{pid}\\n")
_, status, ru = os.wait4(pid, 0)
with open(out, "a") as f:
    f.write(f"{status} {ru.ru_utime + ru.ru_stime} {ru.ru_maxrss}\\n")
code = os.waitstatus_to_exitcode(status)
os._exit(code if code >= 0 else 128 - code)
"""


def run_subprocess(args: list[str], *, timeout_s: float, mem_cap_kb: int | None = None, cwd=None, env=None,
                   workdir: str | os.PathLike | None = None) -> RunResult:
    """``companion ARGS`` as a new process in its own session (started through :data:`_SPAWNER`)."""
    with tempfile.TemporaryDirectory(dir=workdir) as d:
        out_path, err_path, ru_path = Path(d) / "stdout", Path(d) / "stderr", Path(d) / "rusage"
        with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
            t0 = time.monotonic()
            proc = subprocess.Popen([sys.executable, "-I", "-S", "-c", _SPAWNER, str(ru_path), *CLI, *args],
                                    stdin=subprocess.DEVNULL, stdout=fo, stderr=fe, cwd=cwd, env=env,
                                    start_new_session=True)
            child = _Child(ru_path)
            status, ru, killed = _watch(proc.pid, t0, timeout_s, mem_cap_kb, rss_pid=child.pid)
            wall = time.monotonic() - t0
            proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
        res = _result(status, ru, wall, out_path, err_path, killed)
        got = child.final()
        if got is not None:  # the command's own status and rusage (not the spawner's)
            st, cpu, rss = got
            res.returncode = None if killed else os.waitstatus_to_exitcode(st)
            res.cpu_s, res.maxrss_kb = cpu, rss
        else:
            res.maxrss_kb = max(res.maxrss_kb if not killed else 0, child.peak_kb)
        return res


class _Child:
    """The spawned command as the spawner reports it: its pid (for RSS polling), then status and rusage."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._pid: int | None = None
        self.peak_kb = 0

    def pid(self) -> int | None:
        if self._pid is None:
            try:
                first = self.path.read_text().split("\n", 1)[0]
                self._pid = int(first) if first else None
            except (OSError, ValueError):
                return None
        if self._pid is not None:
            self.peak_kb = max(self.peak_kb, _rss_kb(self._pid))
        return self._pid

    def final(self) -> tuple[int, float, int] | None:
        try:
            lines = self.path.read_text().splitlines()
        except OSError:
            return None
        if len(lines) < 2:
            return None
        st, cpu, rss = lines[1].split()
        return int(st), float(cpu), int(rss)


def _child_main(args: list[str], out_fd: int, err_fd: int, rss0_path: Path) -> None:
    """In the forked child: companion.cli.main(args) with fresh stdio and default signal handling; never returns.
    Its RSS right after the fork goes to ``rss0_path`` first (what it shares with its parent)."""
    code = 1
    try:
        rss0_path.write_text(str(_rss_kb(os.getpid())))
        os.setpgid(0, 0)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for sig in (signal.SIGTERM, signal.SIGALRM, signal.SIGCHLD, signal.SIGPIPE):
            signal.signal(sig, signal.SIG_DFL)
        signal.setitimer(signal.ITIMER_REAL, 0)
        os.dup2(out_fd, 1)
        os.dup2(err_fd, 2)
        sys.stdout = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), write_through=True)
        sys.stderr = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), write_through=True)
        from companion.cli import main

        code = main(args)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001 - what the interpreter would print for an uncaught exception
        traceback.print_exc()
        code = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(int(code or 0) & 0xFF)


def run_forked(args: list[str], *, timeout_s: float, mem_cap_kb: int | None = None,
               workdir: str | os.PathLike | None = None) -> RunResult:
    """``companion.cli.main(ARGS)`` in a forked child (see the module docstring)."""
    with tempfile.TemporaryDirectory(dir=workdir) as d:
        out_path, err_path = Path(d) / "stdout", Path(d) / "stderr"
        out_fd = os.open(out_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        err_fd = os.open(err_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        sys.stdout.flush()
        sys.stderr.flush()
        rss0_path = Path(d) / "rss0"
        t0 = time.monotonic()
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the child never returns
            _child_main(args, out_fd, err_fd, rss0_path)
        os.close(out_fd)
        os.close(err_fd)
        try:
            os.setpgid(pid, pid)  # also done by the child; whichever runs first
        except OSError:
            pass
        shared = _Shared(rss0_path)
        status, ru, killed = _watch(pid, t0, timeout_s, mem_cap_kb, rss_pid=lambda: pid, rss_offset=shared.kb)
        wall = time.monotonic() - t0
        return _result(status, ru, wall, out_path, err_path, killed, shared.kb() or 0)


class _Shared:
    """A forked child's RSS right after the fork, once it has written it."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._kb: int | None = None

    def kb(self) -> int | None:
        """None until the child has written it."""
        if self._kb is None:
            try:
                self._kb = int(self.path.read_text())
            except (OSError, ValueError):
                return None
        return self._kb


def run(args: list[str], *, mode: str = "subprocess", **kw) -> RunResult:
    if mode == "fork":
        kw.pop("cwd", None)
        kw.pop("env", None)
        return run_forked(args, **kw)
    return run_subprocess(args, **kw)


def preload() -> None:
    """Import what a replay imports, once, before forking children (their start-up is then nothing)."""
    import companion.cli  # noqa: F401
    import companion.nav  # noqa: F401
    import companion.pipeline  # noqa: F401
    import companion.record  # noqa: F401
    import companion.sources  # noqa: F401
    from pymavlink import DFReader, mavutil  # noqa: F401
