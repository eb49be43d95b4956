"""The sequential gravity filter on air-data dead reckoning, as a pipeline stage between the navigator and the injector.

    ... --> Navigator --> FusedState --> AirDataGravityStage --> (its own state in a GNSS outage) --> Injector

On a fixed wing (and a boat) the navigator's INS on the autopilot's MEMS IMU does not hold through a long GNSS loss
(docs/decisions/0012). This stage keeps a reference of its own, independent of the navigator and of anything the
companion sends: the receiver's fixes while it has them, then airspeed along the heading plus the wind learnt over the
GNSS period (companion.gravity.air_data); on a boat (``speed_log``) its water-speed log along the heading plus the
current learnt the same way. The sequential filter (companion.gravity.sequential, ``InsErrorSpec.air_data``)
estimates that reference's position error and the held wind's error from every gravimeter reading; while GNSS is good
it is pinned to the receiver and learns the map misfit. In an outage, once the filter has estimated on its own, each
navigator state is replaced by this stage's (the navigator's own is withheld from the stages after it): position and
horizontal velocity (low-passed: AirDataReckoner.output_velocity) corrected by the filter, both at the state's own
time, covariance from the filter, altitude the autopilot's, ``measurement``
``gravity_airdata`` while the filter's covariance stands (AIDED: an aid the autopilot lacks: companion.inject.gps_input's
``outage_aids``), else ``airdata`` -- on a boat ``speed_log``, also an aid: the autopilot has no water-speed log. Nothing goes back to the navigator.

Feedback: the reference takes the autopilot's airspeed (pitot) and a heading. Airspeed does not depend on the EKF;
ATTITUDE yaw is EKF3's, which fuses the fixes sent (through its covariance: measured in replay.live.sitl_gravity,
ATTITUDE yaw against SIMSTATE). ``heading = "gyro"`` takes the first IMU's gyro instead, its bias learnt against that
yaw only while GNSS is good and frozen in an outage: EKF3's roll and pitch level it, nothing of its yaw reaches it.

A reading describes the vehicle ``reading_delay_s`` before its stamp (a gravimeter's output filter: half its
averaging window): the filter gets the reference at that earlier time. Pure: vehicle time only.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, fields, replace
from typing import Any, ClassVar

import numpy as np

from companion.events import (Attitude, AirData, AutopilotAltitude, Event, FixType, GnssFix, GravityReading, ImuSample,
                               MagField, WaterSpeed)
from companion.gravity.air_data import AirDataConfig, AirDataReckoner, HeadingOffset, mag_heading_rad, tas_from_eas_mps
from companion.gravity.gyro_heading import DEGPH, GyroHeading, GyroHeadingConfig
from companion.gravity.jump_guard import CHI2_2_99, JumpGuard
from companion.gravity.eotvos import eotvos_from_ne_mgal
from companion.gravity.maps import LocalGravityMap
from companion.gravity.sequential import SeqGravConfig, SeqGravEstimate, SequentialGravityFilter
from companion.gravity.sequential_backends import eotvos_jacobian_mgal_per_mps
from companion.gravity.sequential_stage import SequentialRecord
from companion.nav.outputs import FusedState
from companion.pipeline.stage import Stage

#: the aid name an air-data state carries while the gravity filter tracks (companion.inject.gps_input outage_aids)
AID = "gravity_airdata"
#: the aid name of a boat's state that the gravity filter does not (yet) inform: its dead reckoning on a water-speed
#: log, which the autopilot lacks (ArduRover has no such sensor) and which it cannot feed back into
SPEED_LOG_AID = "speed_log"
#: filter states whose covariance stands (tracking; or no map signal / two modes for now, the covariance growing or
#: spanning them): the state is an aid; "reinit" and "off_map" are not
AIDED = frozenset({"ok", "no_signal", "multimodal"})
#: the receiver position's variance the filter is pinned with while GNSS is good (m^2 per axis)
GNSS_VAR_M2 = 4.0


@dataclass(frozen=True, slots=True)
class AirDataState(FusedState):
    """The stage's state in a GNSS outage, in place of the navigator's (same fields; module doc)."""

    topic: ClassVar[str] = "/gravity/air_data_state"


#: where the reference's heading comes from: the autopilot's ATTITUDE yaw (EKF3's, which the fixes sent can move), its
#: compass (RAW_IMU's field levelled by ATTITUDE roll and pitch) plus the offset to ATTITUDE yaw learnt with GNSS, or its
#: first gyro integrated (companion.gravity.gyro_heading: bias and alignment learnt with GNSS, frozen in an outage; its
#: error and residual bias are states of the gravity filter)
HEADINGS = ("attitude", "magnetometer", "gyro")


class AirDataGravityStage(Stage):
    """Attitude, AirData, AutopilotAltitude, GnssFix, GravityReading and the navigator's FusedState in; in an outage
    AirDataState out in place of FusedState; SequentialRecord per reading (module doc)."""

    filters = True

    def __init__(self, lmap: LocalGravityMap, cfg: SeqGravConfig, air: AirDataConfig | None = None, *,
                 sigma_mgal: float = 1.0, reading_delay_s: float = 0.0, source: str = "gravity:air_data",
                 seed: int = 0, receiver_instance: int = 0, gnss_timeout_s: float = 0.6,
                 speed_sigma_floor_mps: float = 0.0, heading: str = "attitude",
                 gyro: GyroHeadingConfig | None = None, gyro_imu_index: int = 0,
                 jump_chi2: float = CHI2_2_99, speed_log: bool = False, correction_rate_mps: float = 0.0) -> None:
        if heading not in HEADINGS:
            raise ValueError(f"heading must be one of {', '.join(HEADINGS)}, not {heading!r}")
        if (heading == "gyro") != cfg.ins.air_heading:
            raise ValueError("heading = \"gyro\" goes with SeqGravConfig.ins.air_heading = True (and only it)")
        self.heading = heading
        self.speed_log = bool(speed_log)  # the speed through the medium is a boat's log (WaterSpeed), not AirData
        if not correction_rate_mps >= 0:
            raise ValueError("correction_rate_mps must be >= 0 (0: no limit)")
        self.correction_rate_mps = float(correction_rate_mps)
        self._err_out: tuple[float, np.ndarray] | None = None  # (t, the correction the last state carried)
        self.gyro = GyroHeading(gyro) if heading == "gyro" else None
        self.gyro_imu_index = int(gyro_imu_index)
        self._gyro_at_loss = ""
        self._att: Attitude | None = None
        self._mag_offset = HeadingOffset(self.dr_window(air))
        if not cfg.ins.air_data:
            raise ValueError("the air-data stage needs SeqGravConfig.ins.air_data = True")
        if lmap.frame is None:
            raise ValueError("the air-data stage needs a geographic map")
        if not (sigma_mgal > 0 and reading_delay_s >= 0):
            raise ValueError("sigma_mgal must be > 0 and reading_delay_s >= 0")
        self.lmap = lmap
        self.cfg = cfg
        self.dr = AirDataReckoner(air)
        self.filter = SequentialGravityFilter(lmap, cfg, np.random.default_rng(seed))
        self.sigma_mgal = float(sigma_mgal)
        self.delay_s = float(reading_delay_s)
        self.source = source
        self.receiver_instance = int(receiver_instance)
        self.gnss_timeout_s = float(gnss_timeout_s)
        self.speed_sigma_floor_mps = float(speed_sigma_floor_mps)
        self._alt_m: float | None = None
        self._last_reading_t: float | None = None
        self._gust_inst = 0.0  # the gusts' 1-sigma per axis in one sample (m/s)
        self._gust = (0.0, 0.0)  # (m/s over a reading window, m/sqrt(s)) at the last loss (_hold)
        self._good_t: float | None = None
        self._bad_t: float | None = None
        self._outage_t: float | None = None  # the last good fix before the outage in progress
        self._pending: deque[GravityReading] = deque()
        self._est: SeqGravEstimate | None = None  # the filter's last estimate on its own in this outage
        self._anchored_est: SeqGravEstimate | None = None  # ... and its last one pinned to GNSS
        self.jumps = JumpGuard(jump_chi2)  # adds a jump the filter's covariance did not allow to what is stated
        self._withhold = False  # the navigator's state just seen is replaced (passes says False)
        self.n_readings = self.n_states = 0
        self.status_counts: Counter = Counter()

    @staticmethod
    def dr_window(air: AirDataConfig | None) -> float:
        return (air or AirDataConfig()).wind_window_s

    # -- stream ------------------------------------------------------------------------------------
    def process(self, item: Any) -> list[Event]:
        if isinstance(item, FusedState):
            return self._state(item)
        if isinstance(item, ImuSample):
            if self.gyro is not None and item.imu_index == self.gyro_imu_index:
                self.gyro.gyro(item.t_s, item.gyro_frd_radps)
                h = self.gyro.heading_rad(item.t_s)
                if h is not None:
                    self.dr.heading(item.t_s, h)
        elif isinstance(item, Attitude):
            self._att = item
            if self.gyro is not None:  # learns while GNSS is good; ATTITUDE yaw only until the fit stands
                g = self.gyro
                g.attitude(item.t_s, item.roll_rad, item.pitch_rad, item.yaw_rad,
                           learn=self._good_t is not None and not self._receiver_out(item.t_s))
                if g.frozen_t is None and g.line() is None:
                    self.dr.heading(item.t_s, item.yaw_rad)
            elif self.heading == "attitude":
                self.dr.heading(item.t_s, item.yaw_rad)
        elif isinstance(item, MagField):
            self._mag(item)
        elif isinstance(item, AirData):
            if self._alt_m is not None and not self.speed_log:
                self.dr.airspeed(item.t_s, tas_from_eas_mps(item.airspeed_mps, self._alt_m))
        elif isinstance(item, WaterSpeed):
            if self.speed_log:  # through the water: no density correction; the current takes the wind's place
                self.dr.airspeed(item.t_s, item.speed_mps)
        elif isinstance(item, AutopilotAltitude):
            if math.isfinite(item.alt_msl_m):
                self._alt_m = float(item.alt_msl_m)
        elif isinstance(item, GnssFix):
            self._gnss(item)
        elif isinstance(item, GravityReading):
            if math.isfinite(item.gravity_mgal):
                self._pending.append(item)
            return self._readings(item.t_s)
        return []

    def passes(self, item: Any) -> bool:
        return not (self._withhold and type(item) is FusedState)

    def _mag(self, m: MagField) -> None:
        """Magnetometer heading: learns its offset to the autopilot's yaw while GNSS is good (not in an outage, where
        that yaw may follow the fixes sent), then gives the reference its heading."""
        a = self._att
        if self.heading != "magnetometer" or a is None or abs(m.t_s - a.t_s) > 0.5:
            return
        h = mag_heading_rad(m.field_frd_gauss, a.roll_rad, a.pitch_rad)
        if not self._receiver_out(m.t_s) and self._good_t is not None:
            self._mag_offset.add(m.t_s, a.yaw_rad, h)
        off = self._mag_offset.offset_rad
        if off is not None:
            self.dr.heading(m.t_s, h + off)

    def _gnss(self, fix: GnssFix) -> None:
        if fix.instance != self.receiver_instance:
            return
        if fix.fix_type >= FixType.FIX_3D and fix.has_position:
            v = (fix.vel_n_mps, fix.vel_e_mps) if fix.vel_n_mps is not None and fix.vel_e_mps is not None else None
            self.dr.gnss(fix.t_s, fix.lat_deg, fix.lon_deg, v)
            self._good_t = fix.t_s
            if self.gyro is not None:
                self.gyro.thaw()
            if self._outage_t is not None:
                self.filter.cfg = self.cfg
            self._outage_t = None
            self._est = None
            self._err_out = None
            self.jumps.reset()
        else:
            self._bad_t = fix.t_s

    def _receiver_out(self, t_s: float) -> bool:
        g, b = self._good_t, self._bad_t
        return g is not None and (t_s - g > self.gnss_timeout_s or (b is not None and b > g))

    def _readings(self, t_s: float) -> list[Event]:
        if self._receiver_out(t_s):
            if self._outage_t is None:
                self._outage_t = self._good_t
                self._hold(t_s)
            self.dr.advance(t_s)
        out: list[Event] = []
        while self._pending and self.dr.t is not None and self._pending[0].t_s - self.delay_s <= self.dr.t:
            out += self._reading(self._pending.popleft())
        return out

    def _hold(self, t_s: float) -> None:
        """At the loss: the gusts' effect measured over the GNSS period sets the reading noise they add (through
        the Eotvos term) and the position random walk they drive (never below the configured one); a gyro heading is
        frozen and its fit's uncertainty becomes the filter's prior on the heading error and the residual bias."""
        self._gust = self.dr.gust_stats(2.0 * self.delay_s)
        self._gust_inst = self.dr.gust_stats(0.0)[0]
        cfg = replace(self.cfg, pos_noise_m_rts=max(self.cfg.pos_noise_m_rts, self._gust[1]))
        if self.gyro is not None:
            self.gyro.freeze(self._outage_t if self._outage_t is not None else t_s)
            sg = self.gyro.sigmas()
            if sg is not None:
                sa, sb, arw, walk = sg
                cfg = replace(cfg, ins=replace(cfg.ins, init_heading_sigma_rad=sa, gyro_bias_degph=sb / DEGPH,
                                               gyro_arw_deg_rthr=math.degrees(arw) * 60.0,
                                               gyro_bias_walk_degph_rth=walk * 60.0 / DEGPH))
                b = self.gyro.bias_radps or 0.0
                self._gyro_at_loss = (f"bias {b / DEGPH:.1f} deg/h, sigma {sb / DEGPH:.2f} deg/h, alignment sigma "
                                      f"{math.degrees(sa):.2f} deg")
        self.filter.cfg = cfg
        self.jumps.set_process_noise(cfg.ins.wind_walk_mps_rts, cfg.pos_noise_m_rts)

    def _reading(self, r: GravityReading) -> list[Event]:
        t_ref = r.t_s - self.delay_s
        ref = self.dr.at(t_ref)
        if ref is None:
            return []
        lat, lon, vn, ve = ref
        ne, vel = self._map_state(lat, lon, vn, ve)
        g = float(r.gravity_mgal)
        sigma = float(r.sigma_mgal) if r.sigma_mgal is not None and r.sigma_mgal > 0 else self.sigma_mgal
        anchored = self._outage_t is None or t_ref <= self._outage_t
        if not r.eotvos_corrected:
            # the reading averages the Eotvos term over its window (twice its delay): so does the correction; without
            # GNSS the reference velocity's fast part (gusts the held wind does not know) stays in it
            v_avg = self.dr.mean_velocity(r.t_s - 2.0 * self.delay_s, r.t_s) if self.delay_s > 0 else None
            v_eot = np.array([vn, ve]) if v_avg is None else v_avg
            g -= float(eotvos_from_ne_mgal(v_eot, lat))
            if not anchored and self._gust[0] > 0:  # correlated over the window: counted once per window
                j = float(np.hypot(*eotvos_jacobian_mgal_per_mps(v_eot, lat)))
                period = r.t_s - self._last_reading_t if self._last_reading_t is not None else 1.0
                n = max(1.0, 2.0 * self.delay_s / max(period, 1e-3))
                sigma = math.sqrt(sigma**2 + n * (j * self._gust[0]) ** 2)
        self._last_reading_t = float(r.t_s)
        air = None
        w = self.dr.wind_held
        if self.gyro is not None and w is not None and not anchored:  # the air velocity a heading error turns
            air = self._map_state(lat, lon, vn - float(w[0]), ve - float(w[1]))[1]
        e = self.filter.feed(t_ref, g, ne, vel, sigma, ref_cov_ne_m2=np.eye(2) * GNSS_VAR_M2 if anchored else None,
                             lat_deg=lat, eotvos_from_reference=not r.eotvos_corrected, anchor=anchored,
                             air_vel_ne_mps=air)
        if e is None:
            return []
        self.n_readings += 1
        self.status_counts[e.status] += 1
        if anchored:
            self._anchored_est = e
        else:
            self._est = e
            if e.status == "reinit":
                self.jumps.restart()
            else:
                self.jumps.observe(e.t_s, e.err_ne_m, e.cov_ne_m2, e.vel_err_ne_mps, e.vel_cov_ne_m2ps2)
        return [SequentialRecord(float(r.t_s), e.status, float(e.pos_ne_m[0]), float(e.pos_ne_m[1]), e.lat_deg,
                                 e.lon_deg, float(e.h_acc_m), math.nan, float(e.n_eff), float(e.signal_ratio),
                                 float(e.nis_mean), int(e.reinit_count), float(e.map_bias_mgal), False, math.nan,
                                 math.nan, float(e.cpu_s))]

    def _limit_rate(self, t_s: float, err: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The correction a state carries moves towards the filter's at most ``correction_rate_mps`` beyond the
        reckoning's own motion, and what it has not yet taken is added to the covariance it states (it is that far
        from the filter's estimate). An autopilot that fuses the states checks their velocity against its own, which
        follows their positions: a correction of hundreds of metres in seconds, which the stated velocity does not
        show, fails that check (ArduRover's EKF failsafe then holds the boat: docs/decisions/0020). 0: no limit."""
        if self.correction_rate_mps <= 0:
            return err, cov
        if self._err_out is None:
            self._err_out = (t_s, err.copy())
            return err, cov
        t0, out = self._err_out
        step = err - out
        room = self.correction_rate_mps * max(t_s - t0, 0.0)
        d = float(np.hypot(*step))
        if d > room:
            step = step * (room / d)
        out = out + step
        self._err_out = (t_s, out)
        pending = err - out
        return out, cov + np.outer(pending, pending)

    def _map_state(self, lat: float, lon: float, vn: float, ve: float) -> tuple[np.ndarray, np.ndarray]:
        """Map NE of a position and the map-frame velocity (1 s of motion on the map)."""
        from companion.gravity.air_data import radii_m

        ne = np.array(self.lmap.xy_to_ne(lon, lat), float)
        rm, rn = radii_m(lat)
        lat1 = lat + math.degrees(vn / rm)
        lon1 = lon + math.degrees(ve / (rn * math.cos(math.radians(lat))))
        return ne, np.array(self.lmap.xy_to_ne(lon1, lat1), float) - ne

    def _state(self, s: FusedState) -> list[Event]:
        self._withhold = False
        out = self._readings(s.t_s)
        e = self._est
        # a boat's log carries it from the loss: until the first reading after it (a reading describes the vehicle
        # reading_delay_s before its stamp) the state is the reckoning from the last GNSS-pinned estimate
        early = e is None and self.speed_log and self._outage_t is not None
        if early:
            e = self._anchored_est
        if e is None or not self._receiver_out(s.t_s) or self.dr.t is None or not self.dr.advance(s.t_s):
            return out
        # at the state's own time: a reading stamped after it may already have carried the reckoning further
        ref, v_out = self.dr.at(s.t_s), self.dr.output_velocity(s.t_s)
        if ref is None or v_out is None:
            return out
        lat, lon = ref[0], ref[1]
        vn, ve = float(v_out[0]), float(v_out[1])
        ne, _ = self._map_state(lat, lon, vn, ve)
        # (early: the pinned estimate describes the reference at the loss, the reckoning's error grows from there)
        dt = max(s.t_s - (self._outage_t if early else e.t_s), 0.0)
        dv = e.vel_err_ne_mps if e.vel_err_ne_mps is not None else np.zeros(2)
        err = e.err_ne_m + dv * dt
        cov = e.cov_ne_m2 + (e.vel_cov_ne_m2ps2 * dt * dt if e.vel_cov_ne_m2ps2 is not None else 0.0)
        cov = cov + self.jumps.cov_ne_m2 + np.eye(2) * (self.filter.cfg.pos_noise_m_rts**2 * dt if early else 0.0)
        err, cov = self._limit_rate(s.t_s, err, cov)
        lon_o, lat_o = self.lmap.ne_to_xy((ne - err)[0], (ne - err)[1])
        v_n, v_e = vn - float(dv[0]), ve - float(dv[1])
        pv = np.diag(e.vel_cov_ne_m2ps2) if e.vel_cov_ne_m2ps2 is not None else np.full(2, 1e4)
        # the instantaneous velocity also carries the gusts the held wind does not know; and a speed accuracy stated
        # no better than speed_sigma_floor_mps keeps the autopilot from steering its own heading by this velocity
        # (it is made of that heading: EKF3 fuses a GPS velocity with the stated accuracy, AP_NavEKF3_PosVelFusion)
        pv = np.maximum(pv + self._gust_inst**2, self.speed_sigma_floor_mps**2)
        cd = list(s.cov_diag) + [0.0] * max(0, 6 - len(s.cov_diag))
        cd[0], cd[1], cd[3], cd[4], cd[5] = float(cov[0, 0]), float(cov[1, 1]), float(pv[0]), float(pv[1]), 1.0
        alt = self._alt_m if self._alt_m is not None else s.alt_msl_m
        self._withhold = True
        self.n_states += 1
        st = AirDataState(**{f.name: getattr(s, f.name) for f in fields(FusedState)})
        st = replace(st, lat_deg=float(lat_o), lon_deg=float(lon_o), alt_msl_m=float(alt), vel_n_mps=v_n,
                     vel_e_mps=v_e, vel_d_mps=0.0, yaw_rad=math.atan2(v_e, v_n), cov_diag=tuple(cd),
                     sigma_h_m=math.sqrt(max(float(np.trace(cov)), 1e-6)),
                     measurement=(AID if e.status in AIDED and not early
                                  else SPEED_LOG_AID if self.speed_log else "airdata"))
        return out + [st]

    # -- reporting ---------------------------------------------------------------------------------
    def metadata(self) -> dict[str, str]:
        w = self.dr.wind_ne_mps
        return {"matcher": "sequential-air-data", "readings": str(self.n_readings), "states": str(self.n_states),
                "status": ", ".join(f"{k}={v}" for k, v in sorted(self.status_counts.items())),
                "reading_delay_s": f"{self.delay_s:g}", "wind_ne_mps": "none" if w is None else f"{w[0]:.2f},{w[1]:.2f}",
                "air_stale_steps": str(self.dr.stale_steps),
                "wind_shifts_s": ", ".join(f"{t:.0f}" for t in self.filter.wind_shift.shifts_t_s) or "none",
                "jumps": ", ".join(f"{j.t_s:.0f} s {j.shift_m:.0f} m (d2 {j.d2:.0f})" for j in self.jumps.jumps) or "none",
                "gust_at_loss": f"{self._gust[0]:.2f} m/s per reading window, {self._gust[1]:.2f} m/sqrt(s)",
                **({} if self.gyro is None else {
                    "gyro_heading_at_loss": self._gyro_at_loss or "none",
                    "gyro_gaps": f"{self.gyro.gaps} gaps > {self.gyro.cfg.max_gap_s:g} s, {self.gyro.unlevelled} "
                                 "samples without a recent roll/pitch"})}

    def summary_lines(self) -> list[str]:
        st = ", ".join(f"{k} {v}" for k, v in sorted(self.status_counts.items())) or "none"
        return [f"gravity      {self.n_readings} readings (sequential on air data), {self.n_states} states in outages; "
                f"status: {st}; {self.dr.stale_steps} dead-reckoning steps without a recent airspeed/heading; "
                f"{len(self.filter.wind_shift.shifts_t_s)} wind shifts; {len(self.jumps.jumps)} jumps beyond the stated "
                "covariance"]
