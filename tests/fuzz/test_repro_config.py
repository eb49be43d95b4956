"""Reproducers: settings that `companion run` accepts but cannot live with. Every number must have a sane range
checked at start (exit 2 with one line naming the setting, before any link is opened); a config file must be
read or refused in one line.
"""

from __future__ import annotations

import time

import pytest

from replay.fuzz.link import Companion, Peer
from tests.fuzz.conftest import run_cli

XFAIL = dict(strict=True, raises=AssertionError)


def _one_line(rc, err) -> bool:
    return rc == 2 and err.startswith("companion: error:") and len(err.strip().splitlines()) == 1


def _with_peer(tmp_path, *args, seconds=8.0, inject="inject"):
    """`companion run ARGS --duration SECONDS` against the fuzzing peer playing the plain stream."""
    peer = Peer("tcp")
    comp = Companion(peer.url, tmp_path / "out" / "live.mcap", "--duration", str(seconds), *args, inject=inject,
                     workdir=tmp_path)
    peer.companion = comp
    try:
        try:
            peer.connect(60)
        except TimeoutError:
            pass  # it refused to start: what the tests want
        else:
            t0 = time.monotonic()
            peer.play(lambda now: comp.proc.poll() is not None or time.monotonic() - t0 > seconds + 30)
        rc = comp.wait(30)
    finally:
        comp.close()
        peer.close()
    return rc, comp.stderr, peer


def test_flush_interval_1e300_refused_at_start(tmp_path):
    res = run_cli("run", "--connect", "tcp:127.0.0.1:9", "--out", tmp_path / "x.mcap", "--duration", "3",
                  "--set", "record.flush_interval_s=1e300")
    assert "Traceback" not in res.stderr, res.stderr[-500:]
    assert _one_line(res.returncode, res.stderr), res.stderr


def test_non_utf8_config_file_one_line(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_bytes(b'[link]\nconnect = "tcp:127.0.0.1:9"\n# \xff\xfe latin-1 comment: caf\xe9\n')
    res = run_cli("run", "--config", cfg, "--out", tmp_path / "x.mcap", "--duration", "3")
    assert "Traceback" not in res.stderr, res.stderr[-500:]
    assert _one_line(res.returncode, res.stderr), res.stderr


def test_stream_rate_1e_40_refused_at_start(tmp_path):
    rc, err, peer = _with_peer(tmp_path, "--set", "streams.GPS_RAW_INT=1e-40")
    assert "Traceback" not in err, err[-700:]
    assert _one_line(rc, err), (rc, err[-500:])


def test_segment_1e_9_refused_at_start(tmp_path):
    rc, err, _ = _with_peer(tmp_path, "--set", "record.segment_s=1e-9", seconds=6.0, inject="shadow")
    files = sorted((tmp_path / "out").glob("*.mcap"))
    assert len(files) <= 2, f"{len(files)} segment files in 6 s"
    assert _one_line(rc, err), (rc, err[-500:])


def test_gnss_delay_1e300_refused_at_start(tmp_path):
    rc, err, peer = _with_peer(tmp_path, "--set", "navigator.gnss_delay_s=1e300")
    worst = max((g.err_h_m / g.h_acc_m for g in peer.gps_inputs if g.fix_type >= 3 and g.err_h_m is not None), default=0)
    assert worst <= 4.0, f"a fix-3 GPS_INPUT {worst:.0f} x its stated accuracy off ({len(peer.gps_inputs)} sent)"
    assert _one_line(rc, err), (rc, err[-500:])
