#!/usr/bin/env bash
# One entry point for a fresh machine (Debian, Python >= 3.11): sets up .venv once, then runs the job.
#   ./dev.sh replay [ARGS]   replay a log (default: the bundled sample) into out/*.mcap and summarise it
#   ./dev.sh test [ARGS]     run the whole test suite (what .ci/run calls)
#   ./dev.sh setup           only create/refresh the environment
# Idempotent: the venv is reused; dependencies are reinstalled only when pyproject.toml changes.
set -euo pipefail
cd "$(dirname "$0")"

PY=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.installed-$(sha256sum pyproject.toml | cut -c1-16)

setup() {
  if [ ! -x "$VENV/bin/python" ]; then
    if ! "$PY" -m venv "$VENV" 2>/dev/null; then
      echo "python venv module missing; installing python3-venv (needs root)" >&2
      apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
      rm -rf "$VENV"; "$PY" -m venv "$VENV"
    fi
  fi
  if [ ! -f "$STAMP" ]; then
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q -e '.[test]'
    rm -f "$VENV"/.installed-*; touch "$STAMP"
  fi
}

cmd=${1:-replay}; shift || true
case "$cmd" in
  setup) setup ;;
  replay) setup; exec "$VENV/bin/companion" replay "$@" ;;
  test) setup; exec "$VENV/bin/python" -m pytest "$@" ;;
  *) echo "usage: $0 {replay|test|setup} [args]" >&2; exit 2 ;;
esac
