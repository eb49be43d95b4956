"""Eotvos effect on a moving gravimeter (Gao et al. 2022 eqs. 5-6)."""

from __future__ import annotations

import numpy as np

MPS_PER_KNOT = 1852.0 / 3600.0


def eotvos_mgal(speed_mps, heading_rad, lat_deg) -> np.ndarray:
    """E = 7.5 V sin(psi) cos(phi) + 0.004 V^2 with V in knots (nautical mile/h), result in mGal (eq. 5).

    psi is the heading from north (so V sin psi is the east speed), phi the latitude.
    """
    v_kn = np.asarray(speed_mps, float) / MPS_PER_KNOT
    return 7.5 * v_kn * np.sin(heading_rad) * np.cos(np.radians(lat_deg)) + 0.004 * v_kn**2


def eotvos_from_ne_mgal(vel_ne_mps, lat_deg) -> np.ndarray:
    """Eq. 5 from NE velocity components: V sin(psi) = v_east."""
    v = np.asarray(vel_ne_mps, float)
    speed = np.hypot(v[..., 0], v[..., 1])
    heading = np.arctan2(v[..., 1], v[..., 0])
    return eotvos_mgal(speed, heading, lat_deg)


def correct_eotvos_mgal(measured_mgal, vel_ne_mps, lat_deg) -> np.ndarray:
    """G = G_measured - E (eq. 6), E evaluated with the (INS) velocity and latitude."""
    return np.asarray(measured_mgal, float) - eotvos_from_ne_mgal(vel_ne_mps, lat_deg)
