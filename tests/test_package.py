"""The package as it is published and installed: one version, its metadata, a core install without the extras, and
the one-line error naming an extra a feature needs. (The wheel installed in a clean venv: .ci/package.)"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib

import companion
from companion.extras import DISTRIBUTION, EXTRAS
from tests.conftest import REPO, SAMPLE_LOG, free_port

PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
PROJECT = PYPROJECT["project"]
#: import names of what the extras bring (and pandas, which xarray brings): the core must work without any of them
EXTRA_MODULES = ("xarray", "netCDF4", "pandas", "matplotlib", "foxglove", "serial", "dask", "distributed")


def _run_without(modules, *argv: str, cwd=None) -> subprocess.CompletedProcess:
    """``companion ARGV`` in a process where importing any of ``modules`` fails, as without their extras."""
    code = ("import sys; sys.modules.update(dict.fromkeys(%r)); from companion.cli import main; sys.exit(main(%r))"
            % (tuple(modules), list(argv)))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=cwd)


def test_version_comes_from_one_place():
    assert PROJECT["dynamic"] == ["version"] and "version" not in PROJECT
    assert PYPROJECT["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "companion.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", companion.__version__)
    # the changelog's newest release is this version
    releases = re.findall(r"^## (\d+\.\d+\.\d+)", (REPO / "CHANGELOG.md").read_text(), re.M)
    assert releases and releases[0] == companion.__version__


def test_metadata_for_pypi():
    assert PROJECT["name"] == DISTRIBUTION != "companion"  # `companion` is taken on PyPI
    assert PROJECT["scripts"] == {"companion": "companion.cli:main"}
    assert len(PROJECT["keywords"]) >= 5 and PROJECT["urls"]
    classifiers = PROJECT["classifiers"]
    assert f"Programming Language :: Python :: {PROJECT['requires-python'].lstrip('>=')}" in classifiers
    assert not any(c.startswith("License ::") for c in classifiers)  # the SPDX `license` says it (PEP 639)


def test_extras_are_named_for_what_they_add():
    extras = PROJECT["optional-dependencies"]
    assert set(EXTRAS) | {"all", "test"} == set(extras)
    core = " ".join(PROJECT["dependencies"]).lower()
    for name in ("xarray", "netcdf4", "matplotlib", "pandas", "foxglove", "pyserial", "dask", "filterpy"):
        assert name not in core, f"{name} is in the core install"
    assert f"{DISTRIBUTION}[all]" in extras["test"]  # the suite runs every feature


def test_version_imports_nothing_heavy():
    code = ("import sys\nfrom companion.cli import main\ntry:\n    main(['--version'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('numpy', 'scipy', 'pymavlink', 'mcap', 'asyncio') if m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.stdout.splitlines() == [f"companion {companion.__version__}", "[]"], res.stdout + res.stderr


def test_replay_needs_no_extra(tmp_path):
    res = _run_without(EXTRA_MODULES, "replay", str(SAMPLE_LOG), "--out", str(tmp_path / "s.mcap"))
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert (tmp_path / "s.mcap").stat().st_size > 0


def test_a_missing_extra_is_one_line_naming_it(tmp_path):
    grid = REPO / "tests" / "data" / "missing.nc"  # never opened: the extra is checked first
    res = _run_without(("xarray",), "replay", str(SAMPLE_LOG), "--out", str(tmp_path / "g.mcap"),
                       "--gravity-map", str(grid), "--deny-gnss-after", "30")
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert f"pip install '{DISTRIBUTION}[gravity]'" in res.stderr and "xarray is not installed" in res.stderr
    assert not (tmp_path / "g.mcap").exists()  # no empty record left behind
    res = _run_without(("foxglove",), "run", "--connect", f"udpin:127.0.0.1:{free_port()}", "--foxglove", "0",
                       "--out", str(tmp_path / "r.mcap"))
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "[foxglove]" in res.stderr and "live Foxglove view" in res.stderr
