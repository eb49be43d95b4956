"""The simulators: a deterministic flight simulator that emits real MAVLink 2 telemetry, and the simpler models
tests and benchmarks use.

* :mod:`companion.sim.trajectory`: smooth (C2) trajectories from legs or waypoints, with consistent
  attitude, body rates and specific force (pure numpy);
* :mod:`companion.sim.sensors`: IMU, magnetometer, GNSS (with outages) and attitude-estimate models;
* :mod:`companion.sim.flight`: one seeded simulated flight on the autopilot's boot clock, and the sample;
* :mod:`companion.sim.cruise`: hours-long lawn-mower survey cruises (aircraft or ship speed);
* :mod:`companion.sim.motion`: attitude from motion, ZYX Euler angles, what an IMU senses on a rotating Earth;
* :mod:`companion.sim.waypoints`: legs through waypoints (straight lines and turns);
* :mod:`companion.sim.playback`: a flight or a .tlog as time-stamped MAVLink messages;
* :mod:`companion.sim.vehicle`: a simulated ArduPilot on a MAVLink link, with a gravimeter;
  :mod:`companion.sim.vehicle_cli`: ``companion sim``;
* :mod:`companion.sim.gravimeter`: the simulated gravimeter (a Source, and a stage at a GNSS denial's truth);
* :mod:`companion.sim.circle`: an analytic circling flight with exact IMU, for navigator tests with known truth;
* :mod:`companion.sim.gravity_scenario`: the 2-D Monte Carlo scenario model of the gravity benchmarks;
* :mod:`companion.sim.mavlink_out`: ArduCopter-like MAVLink messages and framing;
* :mod:`companion.sim.tlog`: .tlog writing;
* ``python -m companion.sim.make_sample``: regenerates ``logs/sample_flight.tlog``.
"""

from companion.sim.cruise import AIRCRAFT, SHIP, cruise_profile
from companion.sim.flight import SimConfig, SimulatedFlight, sample_flight, sample_profile, simulate_flight
from companion.sim.trajectory import Climb, FlightProfile, Hold, Land, Speed, Straight, Trajectory, Turn, Yaw
from companion.sim.waypoints import legs_through_waypoints

__all__ = [
    "AIRCRAFT",
    "SHIP",
    "cruise_profile",
    "Climb",
    "FlightProfile",
    "Hold",
    "Land",
    "SimConfig",
    "SimulatedFlight",
    "Speed",
    "Straight",
    "Trajectory",
    "Turn",
    "Yaw",
    "legs_through_waypoints",
    "sample_flight",
    "sample_profile",
    "simulate_flight",
]
