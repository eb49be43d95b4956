"""Flight legs through waypoints: straight lines joined by constant-radius turns (companion.sim.trajectory legs)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from companion.sim.motion import wrap_pi
from companion.sim.trajectory import BLEND_PEAK, Channel, Leg, Speed, Straight, Turn, Yaw, _rate_profile


def legs_through_waypoints(
    waypoints_ne_m: Sequence[Sequence[float]],
    start_ne_m: Sequence[float],
    start_heading_deg: float,
    speed_mps: float,
    turn_radius_m: float,
    *,
    max_accel_mps2: float = 2.0,
    turn_blend_s: float = 2.0,
    mode: str | None = None,
) -> list[Leg]:
    """Legs that fly from ``start_ne_m`` (at rest, nose at ``start_heading_deg``) through horizontal waypoints.

    The vehicle first yaws on the spot to face the first waypoint, accelerates to ``speed_mps``, flies
    by the intermediate waypoints with coordinated turns of ``turn_radius_m`` (the path cuts the corner
    like ArduPilot's waypoint navigation), and stops exactly at the last waypoint. Altitude is unchanged;
    combine with ``Climb(..., wait=False)`` for climbs along the way.
    """
    pts = [np.asarray(start_ne_m, dtype=float)] + [np.asarray(p, dtype=float) for p in waypoints_ne_m]
    if len(pts) < 2:
        raise ValueError("need at least one waypoint")
    dirs, lens = [], []
    for a, b in zip(pts[:-1], pts[1:]):
        d = b - a
        n = float(np.hypot(*d))
        if n < 1e-6:
            raise ValueError("consecutive waypoints coincide")
        dirs.append(math.atan2(d[1], d[0]))
        lens.append(n)
    legs: list[Leg] = []
    dyaw = math.degrees(float(wrap_pi(dirs[0] - math.radians(start_heading_deg))))
    if abs(dyaw) > 0.01:
        legs.append(Yaw(dyaw, mode=mode))
        mode = None
    accel_dist = speed_mps * BLEND_PEAK * speed_mps / max_accel_mps2 / 2.0  # mean speed V/2 over the blend
    turns = []  # (angle_deg, a = distance before corner, b = distance after corner)
    for k in range(1, len(dirs)):
        ang = float(wrap_pi(dirs[k] - dirs[k - 1]))
        if abs(ang) < 1e-6:
            turns.append((0.0, 0.0, 0.0))
            continue
        if abs(ang) > math.radians(170.0):
            raise ValueError(f"waypoint {k}: a {math.degrees(abs(ang)):.0f} deg reversal cannot be flown by; add a waypoint")
        a, b = _turn_offsets(ang, speed_mps, turn_radius_m, turn_blend_s)
        turns.append((math.degrees(ang), a, b))
    legs.append(Speed(speed_mps, max_accel_mps2, mode=mode))
    before = accel_dist  # distance of the current leg already used
    for k in range(len(dirs)):
        after = turns[k][1] if k < len(turns) else accel_dist  # needed at the end of leg k
        straight = lens[k] - before - after
        if straight < -1e-6:
            raise ValueError(
                f"leg {k} ({lens[k]:.1f} m) is too short for the turn radius / acceleration; "
                "reduce speed or radius or move the waypoints apart"
            )
        if straight > 1e-6:
            legs.append(Straight(straight))
        if k < len(turns):
            ang, _, b = turns[k]
            if ang != 0.0:
                legs.append(Turn(ang, turn_radius_m, turn_blend_s))
            before = b
    legs.append(Speed(0.0, max_accel_mps2))
    return legs


def _turn_offsets(angle_rad: float, speed_mps: float, radius_m: float, blend_s: float) -> tuple[float, float]:
    """Distances a (before the corner on the entry line) and b (after, on the exit line) of a blended turn."""
    rate, blend, hold = _rate_profile(angle_rad, speed_mps / radius_m, blend_s)
    ch = Channel(0.0)
    ch.blend(0.0, blend, rate)
    ch.blend(blend + hold, blend, 0.0)
    dur = 2 * blend + hold
    n = max(2000, int(dur * 2000))
    t = np.linspace(0.0, dur, n + 1)
    psi = ch.evaluate(t)[3]
    vx, vy = speed_mps * np.cos(psi), speed_mps * np.sin(psi)
    dt = t[1] - t[0]
    dx = float(np.sum(vx[:-1] + vx[1:]) * dt / 2)
    dy = float(np.sum(vy[:-1] + vy[1:]) * dt / 2)
    # a * (1, 0) + b * (cos ang, sin ang) = (dx, dy)
    ca, sa = math.cos(angle_rad), math.sin(angle_rad)
    b = dy / sa
    a = dx - b * ca
    return a, b
