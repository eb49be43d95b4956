"""Fixtures of the fuzz tests: clean inputs cut from the shared logs, and running `companion` on bytes.

Select these tests with ``-k fuzz`` (every test here carries the ``fuzz`` marker and lives in tests/fuzz/).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import SHARED_LOGS

CLI = [sys.executable, "-m", "companion.cli"]


def pytest_configure(config):
    config.addinivalue_line("markers", "fuzz: fuzz suite and fault-tolerance reproducers (select with -k fuzz)")


def pytest_collection_modifyitems(config, items):
    here = Path(__file__).parent
    for item in items:
        if here in Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.fuzz)


@pytest.fixture(scope="session")
def clean():
    """Clean inputs by name ("ac33dev-log171@45%", ...): 150 kB prefixes and mid-flight windows of the shared logs."""
    from replay.fuzz.logs import clean_inputs

    if not SHARED_LOGS.is_dir():
        pytest.skip(f"shared logs not found: {SHARED_LOGS} (set COMPANION_SHARED)")
    return {c.name: c for c in clean_inputs(150_000, SHARED_LOGS)}


def run_cli(*args, timeout=120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout, **kw)


def replay_bytes(tmp_path: Path, data: bytes, suffix: str = ".bin", name: str = "log", timeout=120):
    """Write ``data`` as a log and replay it: (CompletedProcess, log path, MCAP path)."""
    log = tmp_path / f"{name}{suffix}"
    log.write_bytes(data)
    out = tmp_path / f"{name}.mcap"
    return run_cli("replay", log, "--out", out, timeout=timeout), log, out  # (the summary: read by some tests)


def one_line_error(res) -> bool:
    return res.returncode == 2 and res.stderr.startswith("companion: error:") and len(res.stderr.strip().splitlines()) == 1
