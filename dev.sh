#!/usr/bin/env bash
# One entry point for a fresh machine (Debian, Python >= 3.11): sets up .venv once, then runs the job.
#   ./dev.sh replay [ARGS]   replay a log (default: the bundled sample) into out/*.mcap and summarise it
#   ./dev.sh test [ARGS]     run the whole test suite (what .ci/run calls)
#   ./dev.sh setup           only create/refresh the production environment
#   ./dev.sh compile-bytecode VENV   (setup's last step, also for replay.live.install_footprint)
# Two venvs: .venv is the production install (`pip install .`: the core, no extras, no editable link, bytecode for
# the MAVLink dialects in use only: compile_bytecode);
# .venv-test is the developer's (`pip install -e .[test]`: pytest, jsonschema, websockets, dask).
# Idempotent: a venv is reused; dependencies are reinstalled only when pyproject.toml (or, for .venv,
# the source) changes.
set -euo pipefail
cd "$(dirname "$0")"

PY=${PYTHON:-python3}

make_venv() {  # make_venv DIR
  if [ ! -x "$1/bin/python" ]; then
    if ! "$PY" -m venv "$1" 2>/dev/null; then
      echo "python venv module missing; installing python3-venv (needs root)" >&2
      apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
      rm -rf "$1"; "$PY" -m venv "$1"
    fi
  fi
}

drop_old_name() {  # a venv made before the distribution was renamed still holds `companion` (the same import package)
  if "$1/bin/python" -m pip show -q companion >/dev/null 2>&1; then "$1/bin/python" -m pip uninstall -q -y companion; fi
}

compile_bytecode() {  # compile_bytecode VENV: a companion computer's install without 46 MB of unused bytecode
  # pip compiles every installed module, pymavlink's 40 MAVLink dialects too (two copies each, MAVLink 1 and 2); the
  # companion imports two of them. Everything else is compiled, then the dialects the companion's modules import (as
  # root at install time: the service's user cannot write there, and would compile them at every start)
  local site
  site=$("$1/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  "$1/bin/python" -m compileall -q -j 0 -x '/pymavlink/dialects/v[12]0/' "$site" >/dev/null
  "$1/bin/python" - <<'PY'
import py_compile, sys
import companion.cli, companion.record.convert, companion.runtime.runner, companion.sim.vehicle, pymavlink.mavutil  # noqa
for name, module in list(sys.modules.items()):  # (compiled explicitly: PYTHONDONTWRITEBYTECODE may be set)
    if name.startswith("pymavlink.dialects.") and getattr(module, "__file__", None):
        py_compile.compile(module.__file__, doraise=True)
PY
}

setup() {  # production: a non-editable install of the package, without test extras
  local venv=.venv
  local stamp=$venv/.installed-$( (cat pyproject.toml; find companion -type f \( -name '*.py' -o -name '*.tlog' \) | sort | xargs cat) | sha256sum | cut -c1-16)
  make_venv "$venv"
  if [ ! -f "$stamp" ]; then
    "$venv/bin/python" -m pip install -q --upgrade pip
    drop_old_name "$venv"
    "$venv/bin/python" -m pip install -q --no-compile .
    compile_bytecode "$venv"
    rm -f "$venv"/.installed-*; touch "$stamp"
  fi
}

setup_test() {  # development: editable, with the test extras
  local venv=.venv-test
  local stamp=$venv/.installed-$(sha256sum pyproject.toml | cut -c1-16)
  make_venv "$venv"
  if [ ! -f "$stamp" ]; then
    "$venv/bin/python" -m pip install -q --upgrade pip
    drop_old_name "$venv"
    "$venv/bin/python" -m pip install -q -e '.[test]'
    rm -f "$venv"/.installed-*; touch "$stamp"
  fi
}

cmd=${1:-replay}; shift || true
case "$cmd" in
  setup) setup ;;
  compile-bytecode) compile_bytecode "${1:?usage: $0 compile-bytecode VENV}" ;;
  replay) setup; exec .venv/bin/companion replay "$@" ;;
  # two workers (pytest-xdist), a test file per worker: most of the suite's wall time is live processes waiting on
  # simulated vehicles in real time; COMPANION_TEST_JOBS=0 runs it in one process
  test) setup_test; jobs=${COMPANION_TEST_JOBS:-2}
        if [ "$jobs" = 0 ]; then exec .venv-test/bin/python -m pytest "$@"; fi
        exec .venv-test/bin/python -m pytest -n "$jobs" --dist loadfile "$@" ;;
  *) echo "usage: $0 {replay|test|setup} [args]" >&2; exit 2 ;;
esac
