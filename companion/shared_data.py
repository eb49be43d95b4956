"""Where the shared, read-only data (real flight logs, gravity grids) lives: ``<repo>/../shared``, or
``$COMPANION_SHARED``. The one place tests, benchmarks and the gravity helpers ask."""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "COMPANION_SHARED"
#: set (to 1) where the shared data must be there, e.g. CI: a test needing it then fails instead of skipping
REQUIRE_ENV_VAR = "COMPANION_REQUIRE_SHARED"


def shared_dir() -> Path:
    """<repo>/../shared, or $COMPANION_SHARED if set."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).resolve()
    return (Path(__file__).resolve().parents[1] / ".." / "shared").resolve()


def shared_logs_dir() -> Path:
    """The real ArduPilot logs (see its MANIFEST.md)."""
    return shared_dir() / "data" / "logs"


def shared_gravity_dir() -> Path:
    """The Sandwell & Smith grids and tracks/ (see its MANIFEST.md)."""
    return shared_dir() / "data" / "gravity"


def shared_required() -> bool:
    """Whether the environment says the shared data must be present."""
    return os.environ.get(REQUIRE_ENV_VAR, "") not in ("", "0")
