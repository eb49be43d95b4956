"""The core install's footprint: its size on disk and the CPU time of `companion --version` and of `companion run`'s
imports, measured on a wheel installed into fresh venvs (targets: <= 350 MB, <= 0.3 s CPU).

    .venv-test/bin/python -m replay.live.install_footprint [--wheel DIST.whl] [--repeat 10]

Two installs of the same wheel, core only (no extras): ``pip install`` as a user runs it (bytecode compiled for every
installed module, pymavlink's 40 dialects included), and ``./dev.sh setup``'s (dev.sh ``compile_bytecode``: bytecode
for everything but pymavlink's dialects, then for the dialects the companion imports). Sizes are the installed
packages (site-packages less the venv's own pip and setuptools, which are the installer, not the install) and the
whole venv, in MB of 10^6 bytes of allocated blocks (``du``). CPU times are user + system of a child process, the
median of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from replay.harness.results import md_table, publish, results_file

ROOT = Path(__file__).resolve().parents[2]
#: the venv's installer, not the install
INSTALLER = ("pip", "setuptools", "pkg_resources", "_distutils_hack", "distutils-precedence.pth")
#: what `companion run` imports before it opens the link (the command line, settings, record, runtime, pipeline)
RUN_IMPORTS = ("companion.cli", "companion.config", "companion.record", "companion.record.clock", "companion.runtime",
               "companion.runtime.runner", "companion.runtime_status", "companion.pipeline.core", "companion.nav",
               "companion.inject.gps_input", "pymavlink.mavutil")


def _blocks(path: Path) -> int:
    if path.is_symlink() or not path.is_dir():
        return path.lstat().st_blocks * 512
    total = 0
    for root, _dirs, files in os.walk(path):
        for f in files:
            total += os.lstat(os.path.join(root, f)).st_blocks * 512
    return total


def sizes_mb(venv: Path) -> tuple[float, float, list[tuple[str, float]]]:
    """(installed packages MB, whole venv MB, the largest top-level entries of site-packages)."""
    (site,) = venv.glob("lib/python3*/site-packages")
    entries = {p.name: _blocks(p) for p in site.iterdir()}
    packages = sum(v for k, v in entries.items() if not k.startswith(INSTALLER))
    largest = sorted(((k, v / 1e6) for k, v in entries.items() if not k.startswith(INSTALLER)), key=lambda kv: -kv[1])
    return packages / 1e6, _blocks(venv) / 1e6, largest[:8]


def child_cpu_s(argv: list[str], repeat: int, cwd: Path) -> float:
    """Median user + system CPU s of running ``argv`` (a fresh process each time)."""
    out = []
    for _ in range(repeat):
        t0 = os.times()
        subprocess.run(argv, check=True, capture_output=True, cwd=cwd)
        t1 = os.times()
        out.append((t1.children_user - t0.children_user) + (t1.children_system - t0.children_system))
    return statistics.median(out)


def build_wheel(dist: Path) -> Path:
    subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(dist), str(ROOT)], check=True,
                   capture_output=True)
    (wheel,) = dist.glob("*.whl")
    return wheel


def install(venv: Path, wheel: Path, slim: bool) -> None:
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = str(venv / "bin" / "python")
    subprocess.run([py, "-m", "pip", "install", "-q", *(["--no-compile"] if slim else []), str(wheel)], check=True)
    if slim:  # what dev.sh's compile_bytecode does
        subprocess.run([str(ROOT / "dev.sh"), "compile-bytecode", str(venv)], check=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m replay.live.install_footprint", description=__doc__.split("\n\n")[0])
    ap.add_argument("--wheel", type=Path, help="the wheel to install (default: build one from this tree)")
    ap.add_argument("--repeat", type=int, default=10, help="runs per CPU time (median)")
    ap.add_argument("--no-write", action="store_true", help="print only, do not update replay/results/install.md")
    args = ap.parse_args(argv)
    rows, largest = [], None
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        wheel = args.wheel or build_wheel(tmp / "dist")
        for label, slim in (("pip install (every module compiled)", False), ("./dev.sh setup (dialects in use)", True)):
            venv = tmp / ("slim" if slim else "pip")
            install(venv, wheel, slim)
            packages, whole, top = sizes_mb(venv)
            largest = largest or top
            bindir = venv / "bin"
            version = child_cpu_s([str(bindir / "companion"), "--version"], args.repeat, tmp)
            imports = child_cpu_s([str(bindir / "python"), "-c", "import " + ", ".join(RUN_IMPORTS)], args.repeat, tmp)
            rows.append([label, f"{packages:.0f}", f"{whole:.0f}", f"{version:.3f}", f"{imports:.3f}"])
    load = os.getloadavg()[0]
    text = (f"## Core install\n\n    .venv-test/bin/python -m replay.live.install_footprint --repeat {args.repeat}\n\n"
            f"Wheel {wheel.name}, core only (no extras), Python {sys.version.split()[0]}; load average {load:.1f} on "
            f"{os.cpu_count()} cores when measured (CPU time: medians of {args.repeat} runs). Targets: <= 350 MB, "
            "`companion --version` <= 0.3 s CPU.\n\n"
            + md_table(["install", "packages MB", "venv MB (with pip, setuptools)", "`companion --version` CPU s",
                        "`companion run` imports CPU s"], rows)
            + "\n\nLargest installed packages (pip install): "
            + ", ".join(f"{name} {mb:.0f} MB" for name, mb in largest) + ".\n")
    publish(text, results_file("install"), "core", "Install", write=not args.no_write)


if __name__ == "__main__":
    main()
