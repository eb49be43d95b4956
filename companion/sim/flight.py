"""A simulated flight: truth trajectory, sensor outputs and autopilot state on one boot clock.

Trajectory time t = 0 is the autopilot's boot; every sensor stream is sampled on its own uniform grid
k / rate. Randomness: one seed, split with ``numpy.random.SeedSequence.spawn`` so each sensor has its own
stream (changing one model does not reshuffle the others).

The Earth model is the profile's (``FlightProfile(earth=...)``): with "ellipsoid" (cruises) the truth lat/lon, the
GNSS positions and the IMU (Earth rate, transport rate, Coriolis, normal gravity) are those of a rotating WGS84 Earth;
the ATTITUDE estimate and the magnetometer stay relative to local NED on either model.
"""

from __future__ import annotations

import calendar
import math
from dataclasses import dataclass, field

import numpy as np

from companion.mavlink.dialect import mavlink
from companion.nav.frame import LocalFrame
from companion.sim.sensors import (
    AttitudeEstimateModel,
    GnssData,
    GnssModel,
    ImuData,
    ImuModel,
    simulate_attitude_estimate,
    simulate_gnss,
    simulate_imu,
)
from companion.sim.trajectory import Climb, FlightProfile, Hold, Land, Speed, Straight, Trajectory, Turn
from companion.sim.waypoints import legs_through_waypoints

#: ArduPilot SITL's default home: the Canberra Model Aircraft Club field (CMAC), 584 m MSL.
CANBERRA_FIELD = LocalFrame(ref_lat_deg=-35.3632, ref_lon_deg=149.1652, ref_alt_m=584.0)
#: UTC of boot time 0 in the sample flight: 2025-03-15 01:30:00 UTC (12:30 local, Canberra).
SAMPLE_BOOT_EPOCH_US = calendar.timegm((2025, 3, 15, 1, 30, 0, 0, 0, 0)) * 1_000_000

#: ArduCopter flight modes (custom_mode numbers).
COPTER_MODES = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "POSHOLD": 16,
}

MAV_SEVERITY_CRITICAL = mavlink.MAV_SEVERITY_CRITICAL
MAV_SEVERITY_WARNING = mavlink.MAV_SEVERITY_WARNING
MAV_SEVERITY_INFO = mavlink.MAV_SEVERITY_INFO


#: Sensor sets of generated flights, by name (``companion sim --sensors``): "drone" is the multicopter's MEMS IMU and
#: AHRS (the defaults below); "aircraft" is a tactical-grade IMU (200 ug accelerometer bias, ~1 deg/h gyro bias) with a
#: navigation-grade attitude and heading reference (0.02 deg tilt, 0.05 deg heading) -- the class of INS the
#: gravity-matching papers assume. Noise stays above the RAW_IMU quantum (1 mg, 1 mrad/s) so rounding dithers.
SENSOR_SETS: dict[str, dict] = {
    "drone": {},
    "aircraft": {
        "imu": ImuModel(accel_noise_mps2=0.02, gyro_noise_radps=0.0015, accel_bias_sigma_mps2=0.002,
                        gyro_bias_sigma_radps=5e-6),
        "imu2": None,
        "attitude": AttitudeEstimateModel(roll_pitch_sigma_rad=math.radians(0.02), yaw_sigma_rad=math.radians(0.05),
                                          tau_s=60.0, rate_noise_radps=0.0005),
    },
}


@dataclass(frozen=True)
class SimConfig:
    imu_rate_hz: float = 50.0
    gnss_rate_hz: float = 5.0
    #: first GNSS solution at this boot time (then every 1/rate): GPS_RAW_INT.time_usec = 0 means "no time"
    gnss_offset_s: float = 0.1
    attitude_rate_hz: float = 10.0
    imu: ImuModel = ImuModel()
    #: the second IMU (SCALED_IMU2); None to leave it out
    imu2: ImuModel | None = ImuModel(accel_noise_mps2=0.04, gyro_noise_radps=0.0025, temperature_c=41.0)
    gnss: GnssModel = GnssModel()
    attitude: AttitudeEstimateModel = AttitudeEstimateModel()
    boot_epoch_us: int = SAMPLE_BOOT_EPOCH_US
    #: armed interval (boot seconds); None: from 2 s before the first motion to 2 s after the last
    armed_s: tuple[float, float] | None = None


@dataclass
class SimulatedFlight:
    profile: FlightProfile
    config: SimConfig
    seed: int
    truth_imu: Trajectory  # truth at the IMU times
    imu: ImuData
    imu2: ImuData | None
    truth_gnss: Trajectory  # truth at the GNSS times
    gnss: GnssData
    truth_attitude: Trajectory  # truth at the ATTITUDE times
    attitude_euler_rad: np.ndarray
    attitude_rates_radps: np.ndarray
    armed_s: tuple[float, float]
    statustexts: list[tuple[float, int, str]] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return self.profile.duration_s

    def armed_at(self, t_s) -> np.ndarray:
        t = np.asarray(t_s)
        return (t >= self.armed_s[0]) & (t < self.armed_s[1])

    def custom_mode_at(self, t_s) -> list[int]:
        return [COPTER_MODES.get(m or "STABILIZE", 0) for m in self.profile.modes_at(t_s)]


def motion_interval(profile: FlightProfile, rate_hz: float = 50.0) -> tuple[float, float]:
    """First and last time the vehicle moves (speed or climb rate above 1 cm/s)."""
    tr = profile.sample_rate(rate_hz)
    moving = np.linalg.norm(tr.vel_ned_mps, axis=1) > 0.01
    idx = np.flatnonzero(moving)
    if len(idx) == 0:
        return 0.0, 0.0
    return float(tr.t_s[idx[0]]), float(tr.t_s[idx[-1]])


def simulate_flight(
    profile: FlightProfile, seed: int, config: SimConfig = SimConfig(), statustexts=()
) -> SimulatedFlight:
    seqs = np.random.SeedSequence(seed).spawn(4)
    rng_imu, rng_imu2, rng_gnss, rng_att = (np.random.default_rng(s) for s in seqs)
    truth_imu = profile.sample_rate(config.imu_rate_hz)
    n_gnss = int(np.floor((profile.duration_s - config.gnss_offset_s) * config.gnss_rate_hz + 1e-9)) + 1
    truth_gnss = profile.sample(config.gnss_offset_s + np.arange(n_gnss) / config.gnss_rate_hz)
    truth_att = profile.sample_rate(config.attitude_rate_hz)
    imu = simulate_imu(truth_imu, config.imu, rng_imu)
    imu2 = simulate_imu(truth_imu, config.imu2, rng_imu2) if config.imu2 is not None else None
    gnss = simulate_gnss(truth_gnss, profile.frame, config.gnss, rng_gnss)
    att, rates = simulate_attitude_estimate(truth_att, config.attitude, rng_att)
    if config.armed_s is None:
        t0, t1 = motion_interval(profile, config.imu_rate_hz)
        armed = (max(0.0, np.floor((t0 - 2.0) * 10) / 10), min(profile.duration_s, np.ceil((t1 + 2.0) * 10) / 10))
        armed = (float(armed[0]), float(armed[1]))
    else:
        armed = config.armed_s
    return SimulatedFlight(
        profile, config, seed, truth_imu, imu, imu2, truth_gnss, gnss, truth_att, att, rates, armed, list(statustexts)
    )


# ---------------------------------------------------------------------------------------------
# the shipped sample
SAMPLE_SEED = 20250315
SAMPLE_OUTAGE_S = (96.0, 104.0)


def sample_profile() -> FlightProfile:
    """The sample flight: takeoff to 20 m, three legs at 8 m/s with fly-by turns, a 25 m circle at
    6 m/s, a 15 m climb along a straight leg, stop, descent and landing."""
    legs = [
        Hold(6.0, mode="STABILIZE"),  # on the ground, disarmed
        Hold(4.0, mode="AUTO"),  # armed, motors spinning up
        Climb(20.0, rate_mps=2.5),  # takeoff
        Hold(3.0),
        *legs_through_waypoints(
            [(160.0, 0.0), (160.0, 110.0), (20.0, 110.0)],
            start_ne_m=(0.0, 0.0),
            start_heading_deg=30.0,
            speed_mps=8.0,
            turn_radius_m=20.0,
        ),
        Hold(2.0),
        Speed(6.0),
        Turn(360.0, radius_m=25.0),  # a full circle to the right
        Climb(15.0, rate_mps=2.0, wait=False),  # climb while flying straight
        Straight(90.0),
        Speed(0.0),
        Hold(3.0),
        Land(rate_mps=1.5, final_rate_mps=0.5, flare_m=3.0, mode="LAND"),
        Hold(4.0),
    ]
    return FlightProfile(legs, CANBERRA_FIELD, start_heading_deg=30.0)


def sample_flight() -> SimulatedFlight:
    profile = sample_profile()
    config = SimConfig(gnss=GnssModel(outages_s=(SAMPLE_OUTAGE_S,)))
    t0, t1 = SAMPLE_OUTAGE_S
    texts = [
        (0.5, MAV_SEVERITY_INFO, "ArduCopter V4.3.7 (simulated: companion.sim)"),
        (1.0, MAV_SEVERITY_INFO, "Frame: QUAD/X"),
        (t0 + 0.3, MAV_SEVERITY_CRITICAL, "GPS Glitch"),
        (t1 + 0.3, MAV_SEVERITY_CRITICAL, "GPS Glitch cleared"),
    ]
    flight = simulate_flight(profile, SAMPLE_SEED, config, texts)
    flight.statustexts += [
        (flight.armed_s[0], MAV_SEVERITY_INFO, "Arming motors"),
        (flight.armed_s[1], MAV_SEVERITY_INFO, "Disarming motors"),
    ]
    flight.statustexts.sort()
    return flight
