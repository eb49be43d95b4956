"""Where the shared (read-only, not in the repo) gravity data lives."""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "COMPANION_SHARED"


def shared_dir() -> Path:
    """<repo>/../shared, or $COMPANION_SHARED if set."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).resolve()
    return (Path(__file__).resolve().parents[2] / ".." / "shared").resolve()


def shared_gravity_dir() -> Path:
    """Directory holding the Sandwell & Smith grids and tracks/ (see its MANIFEST.md)."""
    return shared_dir() / "data" / "gravity"


AK_GULF = "AK_gulf_grav.nc"
TASMAN = "tasman_grav_west_145E-160E.nc"
LOCAL_1KM = "grav.V18.par.surf.1km.sq.nc"
