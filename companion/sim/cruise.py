"""Hours-long survey cruises for the vehicle simulator (to fly a long GNSS denial over a gravity map).

``cruise_profile`` builds a lawn-mower survey: a short ground hold, a climb to the survey height, acceleration
to cruise speed, parallel lines ``line_km`` long and ``spacing_km`` apart flown in alternating directions with
fly-by turns (90 deg at each end of a line, the cross leg in between), for as long as ``hours`` allows; then it
slows to a stop and descends (or, at sea level, holds). The trajectory model is the multirotor one of
:mod:`companion.sim.trajectory` (the attitude follows the specific force), which is all the companion's
position pipeline needs. Long cruises use a coarse pre-integration grid (``internal_rate_hz``).

Cruises fly over a rotating WGS84 ellipsoid by default (``earth="ellipsoid"``, see :mod:`companion.sim.trajectory`):
over hundreds of kilometres and hours the flat-Earth model's missing Earth rate (15 deg/h), Coriolis
(0.02 m/s^2 at 150 m/s), normal-gravity variation and tangent-plane longitude (~4 % over 3 deg of latitude) would
be errors of the simulated physics, not of the navigator under test.

Presets: ``AIRCRAFT`` (150 m/s at 300 m) and ``SHIP`` (8 m/s at 0 m); unpack them into ``cruise_profile``.
"""

from __future__ import annotations

import math

import numpy as np

from companion.constants import G0_MPS2
from companion.nav.frame import LocalFrame
from companion.sim.trajectory import BLEND_PEAK, Climb, FlightProfile, Hold, Land, Leg
from companion.sim.waypoints import legs_through_waypoints

#: typical survey settings: an aircraft (a 300 km x 100 km box in 3 h) and a survey ship
AIRCRAFT = {"speed_mps": 150.0, "altitude_m": 300.0, "line_km": 300.0, "spacing_km": 25.0}
SHIP = {"speed_mps": 8.0, "altitude_m": 0.0, "line_km": 20.0, "spacing_km": 2.0}

#: pre-integration grid of cruise profiles (Hz): position error of the 4th-order Hermite rule is far below 1 mm
CRUISE_INTERNAL_RATE_HZ = 25.0
_GROUND_HOLD_S = (6.0, 4.0)  # disarmed, then armed before the climb
_MAX_BANK_DEG = 20.0


def default_turn_radius_m(speed_mps: float, spacing_m: float) -> float:
    """A 20 deg bank turn, at least 60 s per half circle (ships), and small enough for the cross leg."""
    r = max(speed_mps**2 / (G0_MPS2 * math.tan(math.radians(_MAX_BANK_DEG))), 60.0 * speed_mps / math.pi)
    return min(r, 0.4 * spacing_m)


def default_accel_mps2(speed_mps: float) -> float:
    """Along-track acceleration: 2 m/s^2 for an aircraft, gentler for slow vehicles (0.2 m/s^2 for a ship at 8 m/s)."""
    return min(2.0, max(0.05, speed_mps / 40.0))


def survey_waypoints(
    distance_m: float, line_m: float, spacing_m: float, heading_deg: float, max_lines: int | None = None
) -> list[tuple[float, float]]:
    """Corners of a lawn-mower path from (0, 0) along ``heading_deg``, the next line ``spacing_m`` to the right,
    cut at path length ``distance_m`` (the last point may lie inside a segment). With ``max_lines`` the
    pattern turns back across the box after that many lines instead of growing."""
    if line_m <= 0 or spacing_m <= 0:
        raise ValueError("line and spacing must be positive")
    if max_lines is not None and max_lines < 2:
        raise ValueError("max_lines must be at least 2")
    h = math.radians(heading_deg)
    u = np.array([math.cos(h), math.sin(h)])  # along the lines (NE)
    c = np.array([-math.sin(h), math.cos(h)])  # to the right of the first line
    pts = [np.zeros(2)]
    left = float(distance_m)
    k = 0  # line number
    col, step = 0, 1  # cross index of the line being flown, direction of the next cross leg
    while left > 0:
        start_along = 0.0 if k % 2 == 0 else line_m
        end_along = line_m - start_along
        seg = [(end_along, col, line_m)]  # the line, then the cross leg to the next one
        if max_lines is not None and not 0 <= col + step < max_lines:
            step = -step
        seg.append((end_along, col + step, spacing_m))
        for along, cc, length in seg:
            p = along * u + cc * spacing_m * c
            if length >= left:
                pts.append(pts[-1] + (p - pts[-1]) * (left / length))
                left = 0.0
                break
            pts.append(p)
            left -= length
        col += step
        k += 1
    return [(float(p[0]), float(p[1])) for p in pts[1:]]


def cruise_profile(
    origin: LocalFrame,
    *,
    hours: float,
    speed_mps: float,
    line_km: float,
    spacing_km: float,
    heading_deg: float = 0.0,
    altitude_m: float = 300.0,
    turn_radius_m: float | None = None,
    max_lines: int | None = None,
    max_accel_mps2: float | None = None,
    climb_rate_mps: float = 5.0,
    internal_rate_hz: float = CRUISE_INTERNAL_RATE_HZ,
    earth: str = "ellipsoid",
) -> FlightProfile:
    """A lawn-mower survey of about ``hours`` (total profile duration) starting at rest at ``origin``.

    The first line runs from the origin along ``heading_deg``; following lines lie ``spacing_km`` to its right.
    The flight stays in the box of ``line_km`` x (lines - 1) ``spacing_km`` (fly-by turns cut the corners
    inside it). Modes: STABILIZE on the ground, AUTO for the survey, LAND (or LOITER at sea level) at the end.
    ``earth``: "ellipsoid" (default; rotating WGS84 Earth, truth lat/lon integrated on the ellipsoid) or "flat".
    The lines, spacing and box are laid out in the profile's local-level metres (``pos_ned_m``).
    """
    if not hours > 0:
        raise ValueError("hours must be positive")
    if not speed_mps > 0:
        raise ValueError("cruise speed must be positive")
    if altitude_m < 0:
        raise ValueError("altitude must be >= 0")
    line_m, spacing_m = line_km * 1e3, spacing_km * 1e3
    radius = turn_radius_m if turn_radius_m is not None else default_turn_radius_m(speed_mps, spacing_m)
    accel = max_accel_mps2 if max_accel_mps2 is not None else default_accel_mps2(speed_mps)
    head: list[Leg] = [Hold(_GROUND_HOLD_S[0], mode="STABILIZE"), Hold(_GROUND_HOLD_S[1], mode="AUTO")]
    if altitude_m > 0:
        head += [Climb(altitude_m, rate_mps=climb_rate_mps, blend_s=3.0), Hold(2.0)]
    tail: list[Leg] = [Hold(5.0)]
    if altitude_m > 0:
        tail += [Land(rate_mps=climb_rate_mps, final_rate_mps=0.5, flare_m=3.0, mode="LAND"), Hold(5.0, mode="STABILIZE")]
    else:
        tail += [Hold(10.0, mode="LOITER")]
    # the survey's own time: the rest of the budget, flown at cruise speed; corrected once from the built profile
    target_s = hours * 3600.0
    accel_s = BLEND_PEAK * speed_mps / accel
    fixed_s = sum(_GROUND_HOLD_S) + 7.0 + (2 * (altitude_m / climb_rate_mps + 5.0) if altitude_m > 0 else 10.0)
    distance = speed_mps * (target_s - fixed_s - accel_s)
    min_distance = speed_mps * accel_s + 2.0 * radius
    profile = None
    for _ in range(3):
        distance = max(distance, min_distance)
        wps = survey_waypoints(distance, line_m, spacing_m, heading_deg, max_lines)
        wps = _fit_last_segment(wps, speed_mps, accel, radius)
        legs = legs_through_waypoints(
            wps, start_ne_m=(0.0, 0.0), start_heading_deg=heading_deg, speed_mps=speed_mps, turn_radius_m=radius,
            max_accel_mps2=accel, turn_blend_s=4.0,
        )
        profile = FlightProfile(head + legs + tail, origin, start_heading_deg=heading_deg, internal_rate_hz=internal_rate_hz,
                                earth=earth)
        err_s = target_s - profile.duration_s
        if abs(err_s) < 1.0 or distance <= min_distance:
            break
        distance += err_s * speed_mps
    return profile


def _fit_last_segment(wps, speed_mps: float, accel_mps2: float, radius_m: float):
    """Drop a final partial segment too short to turn into and stop on (the survey ends at the previous corner)."""
    stop_m = speed_mps * BLEND_PEAK * speed_mps / accel_mps2 / 2.0
    while len(wps) >= 2:
        last = math.dist(wps[-1], wps[-2])
        if last >= stop_m + 1.5 * radius_m + 4.0 * speed_mps:
            break
        wps = wps[:-1]
    return wps
