"""Settings and files an adversarial user gives `companion run` / `replay`: an output that is an input (key, config,
log, map), a NUL byte, a device or FIFO as an input, durations with no floor, argument errors. Each ends at once with
one line and exit 2, and nothing is overwritten; `companion run` never replaces a record unless told (--force)."""

from __future__ import annotations

import hashlib
import os
import socket

import pytest

from tests.conftest import free_port
from tests.fuzz.conftest import one_line_error, run_cli


def _sha(p) -> str:
    return hashlib.sha256(open(p, "rb").read()).hexdigest()


@pytest.fixture
def files(tmp_path):
    key = tmp_path / "key.bin"
    key.write_bytes(bytes(range(32)))
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[link]\nconnect = "udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}"\n')
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    log = tmp_path / "log.bin"
    log.write_bytes(b"\xa3\x95\x80" + bytes(86))
    return {"key": key, "cfg": cfg, "fifo": fifo, "log": log, "dir": tmp_path}


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


@pytest.mark.parametrize("case", list(CASES))
def test_bad_setting_or_file_is_one_line_exit_2_and_overwrites_nothing(files, case):
    before = {k: _sha(files[k]) for k in ("key", "cfg", "log")}
    res = run_cli(*CASES[case](files), timeout=60)
    assert one_line_error(res), (res.returncode, res.stderr[-800:])
    assert {k: _sha(files[k]) for k in ("key", "cfg", "log")} == before


def test_run_never_replaces_a_record_unless_forced(files):
    out = files["dir"] / "live.mcap"
    first = run_cli("run", "--config", files["cfg"], "--out", out, "--duration", "0.5", "-q", timeout=120)
    assert first.returncode == 0 and out.exists(), first.stderr[-600:]
    sha = _sha(out)
    again = run_cli("run", "--config", files["cfg"], "--out", out, "--duration", "0.5", "-q", timeout=120)
    assert again.returncode == 0 and _sha(out) == sha, again.stderr[-600:]
    assert (files["dir"] / "live_2.mcap").exists() and "recording to" in again.stderr
    forced = run_cli("run", "--config", files["cfg"], "--out", out, "--duration", "0.5", "-q", "--force", timeout=120)
    assert forced.returncode == 0 and _sha(out) != sha and not (files["dir"] / "live_3.mcap").exists()
