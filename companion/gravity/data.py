"""The gravity grids of the shared data (see companion.shared_data for where it lives)."""

from __future__ import annotations

from companion.shared_data import shared_gravity_dir

AK_GULF = "AK_gulf_grav.nc"
TASMAN = "tasman_grav_west_145E-160E.nc"
LOCAL_1KM = "grav.V18.par.surf.1km.sq.nc"

__all__ = ["AK_GULF", "TASMAN", "LOCAL_1KM", "shared_gravity_dir"]
