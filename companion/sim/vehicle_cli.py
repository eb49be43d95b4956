"""``companion sim``: the simulated vehicle (companion.sim.vehicle.VehicleSim) from the command line: which flight
(the sample, looping circuits, an hours-long cruise, or a .tlog), faults, a gravity map for its gravimeter."""

from __future__ import annotations

import math
import signal
import time
from pathlib import Path

import numpy as np

from companion.nav.frame import LocalFrame
from companion.sim.playback import gravity_readings, playback_from_flight, playback_from_tlog
from companion.sim.vehicle import Faults, VehicleSim


def circuit_profile(circuits: int = 2):
    """Take off, fly ``circuits`` 200 m squares at 8 m/s, land where it started and yaw back to north:
    it ends as it began (on the ground at the origin, nose north), so it can be looped for soak runs."""
    from companion.sim.flight import CANBERRA_FIELD
    from companion.sim.trajectory import Climb, FlightProfile, Hold, Land, Speed, Yaw
    from companion.sim.waypoints import legs_through_waypoints

    wps = [(200.0, 0.0), (200.0, 200.0), (0.0, 200.0), (0.0, 0.0)] * circuits
    legs = [
        Hold(6.0, mode="STABILIZE"),
        Hold(4.0, mode="AUTO"),
        Climb(20.0, rate_mps=2.5),
        Hold(2.0),
        *legs_through_waypoints(wps, start_ne_m=(0.0, 0.0), start_heading_deg=0.0, speed_mps=8.0, turn_radius_m=20.0),
        Speed(0.0),
        Hold(2.0),
        Land(rate_mps=1.5, final_rate_mps=0.5, flare_m=3.0, mode="LAND"),
        Yaw(90.0),
        Hold(4.0, mode="STABILIZE"),
    ]
    return FlightProfile(legs, CANBERRA_FIELD, start_heading_deg=0.0)


_NOTES: list[str] = []  # details printed after the listening line


def _lat_lon(text: str, what: str) -> tuple[float, float]:
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{what} {text!r}: expected LAT,LON in degrees") from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0):
        raise ValueError(f"{what} {text!r}: latitude must be within +-90 deg and longitude within -180..360 deg")
    return lat, lon


def _cruise_from_args(args):
    """``--profile cruise``: a lawn-mower survey (aircraft defaults at >= 30 m/s, ship defaults below)."""
    from companion.sim.cruise import AIRCRAFT, SHIP, cruise_profile

    speed = args.cruise_speed
    preset = AIRCRAFT if speed >= 30.0 else SHIP
    lat, lon = _lat_lon(args.origin, "--origin") if args.origin else (-40.5, 155.6)
    return cruise_profile(
        LocalFrame(lat, lon, 0.0), hours=args.hours, speed_mps=speed,
        line_km=args.line_km if args.line_km is not None else preset["line_km"],
        spacing_km=args.spacing_km if args.spacing_km is not None else preset["spacing_km"],
        heading_deg=args.cruise_heading,
        altitude_m=args.cruise_alt if args.cruise_alt is not None else preset["altitude_m"],
        max_lines=args.max_lines,
    )


def _gravity_from_args(args, profile) -> tuple[np.ndarray, np.ndarray]:
    """``--gravity-map``: readings along the flight; one-line errors for a bad file or a flight off the map."""
    from companion.gravity.maps import LocalGravityMap, MapFormatError, load_grid

    if not 1 <= len(args.gravity_name.encode("ascii", "replace")) <= 10:
        raise ValueError(f"--gravity-name {args.gravity_name!r}: NAMED_VALUE_FLOAT names are 1-10 characters")
    try:
        lmap = LocalGravityMap.around(load_grid(args.gravity_map))
    except (MapFormatError, OSError, ValueError, KeyError) as err:
        first = (str(err).splitlines() or [type(err).__name__])[0]  # xarray's hints run over several lines
        raise ValueError(f"gravity map {args.gravity_map}: {first}") from None
    if lmap.frame is None:
        raise ValueError(f"gravity map {args.gravity_map}: needs lat/lon axes to fly a generated flight over it")
    f = profile.frame
    n0, e0 = lmap.frame.to_ned_m(f.ref_lat_deg, f.ref_lon_deg, 0.0)[:2]
    if not math.isfinite(float(lmap.interp_ne(n0, e0))):
        raise ValueError(f"the flight starts at {f.ref_lat_deg:.4f},{f.ref_lon_deg:.4f}, off the gravity map "
                         f"{args.gravity_map} (lon {lmap.gmap.x[0]:g}..{lmap.gmap.x[-1]:g}, lat {lmap.gmap.y[0]:g}..{lmap.gmap.y[-1]:g})")
    hz = args.gravity_hz
    seed = args.seed if args.seed is not None else 0
    t, v = gravity_readings(profile, lmap, hz=hz, sigma_mgal=args.gravity_sigma_mgal, seed=seed)
    expected = int(math.floor((profile.duration_s - 0.05) * hz + 1e-9)) + 1
    off = expected - len(t)
    _NOTES.append(f"sim: gravimeter {len(t)} readings at {hz:g} Hz as NAMED_VALUE_FLOAT {args.gravity_name!r} "
          f"(sigma {args.gravity_sigma_mgal:g} mGal, map {Path(args.gravity_map).name})"
          + (f"; {off} positions off the map send nothing" if off else ""))
    return t, v


def run_sim(args) -> int:
    """``companion sim`` entry point (argparse namespace from companion.cli)."""
    from companion.config import load_signing_key

    _NOTES.clear()
    if args.log:
        if getattr(args, "gravity_map", None):
            raise ValueError("--gravity-map works with a generated flight (--profile), not with --log")
        playback = playback_from_tlog(args.log)
    else:
        from companion.sim.flight import SAMPLE_SEED, SENSOR_SETS, SimConfig, sample_profile, simulate_flight

        cruise = args.profile == "cruise"
        if cruise:
            profile = _cruise_from_args(args)
        else:
            profile = circuit_profile() if args.profile == "circuit" else sample_profile()
        gravity = _gravity_from_args(args, profile) if getattr(args, "gravity_map", None) else None
        imu_hz = args.imu_hz or (25.0 if cruise else 50.0)
        gnss_hz = args.gnss_hz or (5.0 if cruise else 10.0)
        t0 = time.perf_counter()
        flight = simulate_flight(
            profile, args.seed if args.seed is not None else SAMPLE_SEED,
            SimConfig(gnss_rate_hz=gnss_hz, imu_rate_hz=imu_hz, attitude_rate_hz=getattr(args, "attitude_hz", 10.0),
                      **SENSOR_SETS[getattr(args, "sensors", "drone")]),
        )
        playback = playback_from_flight(flight, gravity=gravity, gravity_name=getattr(args, "gravity_name", "GRAV"))
        _NOTES.append(f"sim: built {profile.duration_s / 3600:.2f} h flight in {time.perf_counter() - t0:.1f} s "
                      f"(IMU {imu_hz:g} Hz, GNSS {gnss_hz:g} Hz, attitude {getattr(args, 'attitude_hz', 10.0):g} Hz, "
                      f"{getattr(args, 'sensors', 'drone')} sensors)")
    faults = Faults(
        gnss_off=tuple(args.gnss_off) if args.gnss_off else None,
        imu_off=tuple(args.imu_off) if args.imu_off else None,
        link_drop=tuple(args.link_drop) if args.link_drop else None,
        reboot_at=args.reboot_at,
        reboot_downtime_s=args.reboot_downtime,
        noise=args.noise,
    )
    key = load_signing_key(args.signing_key_file) if args.signing_key_file else None
    if args.record:  # its folder made as `companion run` makes its record's
        Path(args.record).parent.mkdir(parents=True, exist_ok=True)
    sim = VehicleSim(
        playback, args.listen, faults=faults, speed=args.speed, start_s=args.start, end_s=args.end,
        streams=args.streams, loops=args.loops, record=args.record, key=key, seed=args.seed or 0,
        idle_exit_s=args.idle_exit, gps_mav_instance=getattr(args, "gps_mav_instance", None),
    )
    if sim.arming is not None and sim.arm_gate_s is None:
        _NOTES.append(f"sim: --gps-mav-instance: no arming check (the flight arms at {playback.arm_s} s, played from "
                      f"{sim.start_s:g} to {sim.end_s:g} s)")
    signal.signal(signal.SIGTERM, sim.stop)
    signal.signal(signal.SIGINT, sim.stop)
    print(f"sim: {playback.description} on {args.listen} from {args.start:g} s at x{args.speed:g}", flush=True)
    for note in _NOTES:  # after the first line, which says the simulator is about to listen
        print(note, flush=True)
    _NOTES.clear()
    st = sim.run()
    print(f"sim: sent {sum(st.sent.values())} messages, received {st.gps_input} GPS_INPUT "
          f"({st.gps_input_signed} signed), {len(st.requests)} interval requests, {st.connections} connections; "
          f"pacing: max lag {st.max_lag_s:.3f} s playback ({st.max_lag_s / sim.speed * 1e3:.1f} ms wall), "
          f"{st.late_messages} messages > 10 ms late", flush=True)
    return 0
