"""The fuzzer's settings-and-files operators: what an adversarial user gives `companion run` / `replay` / `convert`
-- an output that is one of the run's inputs (signing key, config, log), a NUL byte in a path, a device
(/dev/zero, /dev/urandom) or a FIFO without a writer as an input, durations without a floor, NaN, argument errors.

Each case must end by itself (killed after :data:`TIMEOUT_S`: a hang) with exit 2 and one line on stderr, no
traceback, and every input file unchanged (hash before and after).
"""

from __future__ import annotations

import hashlib
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

CLI = [sys.executable, "-m", "companion.cli"]
TIMEOUT_S = 30.0


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def make_files(d: Path) -> dict[str, Path]:
    """A signing key, a config, a FIFO with no writer and a (header-only) dataflash log in ``d``."""
    d.mkdir(parents=True, exist_ok=True)
    f = {"key": d / "key.bin", "cfg": d / "c.toml", "fifo": d / "fifo", "log": d / "log.bin", "dir": d}
    f["key"].write_bytes(bytes(range(32)))
    f["cfg"].write_text(f'[link]\nconnect = "udpin:127.0.0.1:{_free_udp_port()}"\n')
    if not f["fifo"].exists():
        os.mkfifo(f["fifo"])
    f["log"].write_bytes(b"\xa3\x95\x80" + bytes(86))
    return f


#: case -> the command line, from the files of make_files
CASES = {
    "out is the key": lambda f: ["run", "--config", f["cfg"], "--signing-key-file", f["key"], "--out", f["key"]],
    "record.out is the key": lambda f: ["run", "--config", f["cfg"], "--signing-key-file", f["key"], "--set",
                                        f"record.out={f['key']}"],
    "out is the config": lambda f: ["run", "--config", f["cfg"], "--out", f["cfg"]],
    "out is the log": lambda f: ["replay", f["log"], "--out", f["log"]],
    "record.out with a NUL": lambda f: ["run", "--config", f["cfg"], "--set", 'record.out="a\\u0000b.mcap"'],
    "config /dev/zero": lambda f: ["run", "--config", "/dev/zero"],
    "config /dev/urandom": lambda f: ["run", "--config", "/dev/urandom"],
    "config a FIFO": lambda f: ["run", "--config", f["fifo"]],
    "key /dev/zero": lambda f: ["run", "--config", f["cfg"], "--signing-key-file", "/dev/zero"],
    "key /dev/urandom": lambda f: ["run", "--config", f["cfg"], "--signing-key-file", "/dev/urandom"],
    "key a FIFO": lambda f: ["run", "--config", f["cfg"], "--signing-key-file", f["fifo"]],
    "log a FIFO": lambda f: ["replay", f["fifo"], "--out", f["dir"] / "o.mcap"],
    "log /dev/zero": lambda f: ["replay", "/dev/zero", "--out", f["dir"] / "o.mcap"],
    "convert a FIFO": lambda f: ["convert", f["fifo"], "--out", f["dir"] / "o.mcap"],
    "reconnect 1e-9": lambda f: ["run", "--config", f["cfg"], "--set", "link.reconnect_min_s=1e-9", "--set",
                                 "link.reconnect_max_s=1e-9"],
    "status-every 1e-9": lambda f: ["run", "--config", f["cfg"], "--status-every", "1e-9"],
    "status-every 0": lambda f: ["run", "--config", f["cfg"], "--status-every", "0"],
    "status-every -1": lambda f: ["run", "--config", f["cfg"], "--status-every=-1"],
    "status-every nan": lambda f: ["run", "--config", f["cfg"], "--status-every", "nan"],
    "duration -1": lambda f: ["run", "--config", f["cfg"], "--duration=-1"],
    "duration_s nan": lambda f: ["run", "--config", f["cfg"], "--set", "duration_s=nan"],
    "realtime nan": lambda f: ["replay", f["log"], "--realtime", "nan"],
    "no subcommand": lambda f: [],
    "map not netCDF": lambda f: ["run", "--config", f["cfg"], "--gravity-map", f["log"]],
}


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def run_case(name: str, f: dict[str, Path]) -> dict:
    """One case: its exit, stderr lines, wall time and violations (hang, bad_exit, stderr, traceback, input)."""
    before = {k: _sha(f[k]) for k in ("key", "cfg", "log")}
    t0 = time.monotonic()
    try:
        res = subprocess.run([*CLI, *map(str, CASES[name](f))], capture_output=True, text=True, timeout=TIMEOUT_S,
                             stdin=subprocess.DEVNULL)
        rc, err = res.returncode, res.stderr
    except subprocess.TimeoutExpired as exc:
        rc, err = None, (exc.stderr or b"").decode(errors="replace") if isinstance(exc.stderr, bytes) else ""
    wall = time.monotonic() - t0
    lines = err.strip().splitlines()
    v = []
    if rc is None:
        v.append("hang")
    elif rc != 2:
        v.append("bad_exit")
    if "Traceback" in err:
        v.append("traceback")
    if rc is not None and (len(lines) != 1 or not lines[0].startswith("companion: error:")):
        v.append("stderr")
    if {k: _sha(f[k]) for k in ("key", "cfg", "log")} != before:
        v.append("input")
    return {"case": name, "exit": rc, "lines": len(lines), "wall_s": wall, "violations": v,
            "stderr": lines[-1][:160] if lines else ""}


def run_settings_fuzz(workdir: Path, command: str) -> str:
    """Every case; the results as a Markdown section."""
    from replay.harness.results import md_table

    f = make_files(Path(workdir) / "settings")
    rows = []
    for name in CASES:
        o = run_case(name, f)
        print(f"settings {name}: {o['violations'] or 'ok'} exit {o['exit']}", file=sys.stderr, flush=True)
        rows.append([name, o["exit"], o["lines"], round(o["wall_s"], 2), ", ".join(o["violations"]) or "-",
                     o["stderr"].replace("|", "/")])
    bad = sum(1 for r in rows if r[4] != "-")
    return "\n".join([
        "## Settings and files an adversarial user gives `companion`",
        "",
        "Command (repository root):",
        "",
        f"    {command}",
        "",
        f"replay/fuzz/settings.py: {len(rows)} cases (an output that is an input, NUL in a path, a device or a FIFO "
        f"with no writer as an input, durations without a floor, NaN, argument errors); each must exit 2 by itself "
        f"(killed after {TIMEOUT_S:g} s: a hang) with one line on stderr, no traceback, the key, config and log "
        f"unchanged. {len(rows) - bad} of {len(rows)} ok.",
        "",
        md_table(["case", "exit", "stderr lines", "wall s", "violations", "stderr"], rows),
    ])
