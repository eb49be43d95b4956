"""A simulated gravimeter as its own component on an ArduPilot SITL vehicle: it reads the simulator's truth
(SIMSTATE) from a spare SITL MAVLink port and sends its readings as NAMED_VALUE_FLOAT ``GRAV`` (mGal) with the
autopilot's system id, which ArduPilot routes to its other links -- where the companion takes them like any
gravimeter's (companion.mavlink.gravimeter). On a boat, ``--speed-log NAME`` adds a water-speed log
(companion.sim.speed_log) the same way (companion.mavlink.speed_log), through the water of SITL's tide.

    python -m companion.sim.sitl_gravimeter_link --connect tcp:127.0.0.1:5763 --map GRID.nc --seed 1 --record g.jsonl

Time: SIMSTATE has no time field; each is stamped with the newest ``time_boot_ms`` seen before it (ATTITUDE is
requested at the same rate), and a reading goes out every ``--period-s`` of that vehicle time with it as its
``time_boot_ms``. The sensor model is companion.sim.truth_gravimeter; ``--record`` keeps every reading beside the
truth and the map value at it (JSON lines).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20.ardupilotmega import MAV_COMP_ID_AUTOPILOT1, MAV_MODE_FLAG_SAFETY_ARMED

from companion.gravity.maps import LocalGravityMap, load_grid
from companion.mavlink.gravimeter import DEFAULT_NAMED_VALUE
from companion.sim.gravity_residuals import ship_minus_satellite_mgal
from companion.sim.speed_log import SpeedLog, SpeedLogSpec
from companion.sim.truth_gravimeter import GravimeterSpec, TruthGravimeter

#: MAV_COMP_ID_PERIPHERAL: the gravimeter speaks as a peripheral of the vehicle's system
GRAVIMETER_COMPONENT = 158


class GravimeterOnLink:
    """Message in -> readings out: ``on_message`` returns the (time_boot_ms, mGal) readings due (pure, testable)."""

    def __init__(self, meter: TruthGravimeter, period_s: float = 1.0):
        self.meter = meter
        self.period_s = float(period_s)
        self.t_boot_s: float | None = None
        self.next_s: float | None = None
        self.last_truth: tuple[float, float] | None = None
        self.sent = 0

    def on_message(self, m) -> list[tuple[int, float]]:
        kind = m.get_type()
        tb = getattr(m, "time_boot_ms", None)
        if tb is not None and kind != "SIMSTATE":
            self.t_boot_s = tb / 1000.0 if self.t_boot_s is None else max(self.t_boot_s, tb / 1000.0)
            return []
        if kind != "SIMSTATE" or self.t_boot_s is None:
            return []
        lat, lon = m.lat * 1e-7, m.lng * 1e-7
        if lat == 0.0 and lon == 0.0:
            return []
        t = self.t_boot_s
        self.meter.sample(t, lat, lon)
        self.last_truth = (lat, lon)
        if self.next_s is None:
            self.next_s = t + self.period_s
        if t + 1e-9 < self.next_s:
            return []
        self.next_s += self.period_s * max(1, math.floor((t - self.next_s) / self.period_s) + 1)
        v = self.meter.read(t)
        if v is None or not math.isfinite(v):
            return []
        self.sent += 1
        return [(int(round(t * 1000.0)), v)]


#: SITL's tide (SIM_Sailboat): its speed and the direction it comes from, as parameters
TIDE_PARAMS = ("SIM_TIDE_SPEED", "SIM_TIDE_DIR")


class SitlTide:
    """The water's current SITL moves its boat by, from what the autopilot says: PARAM_VALUE of SIM_TIDE_SPEED and
    SIM_TIDE_DIR (sent to every link when set, and on request), applied only while the vehicle is armed
    (SIM_Sailboat: ``tide_velocity_ef = -(cos dir, sin dir) * speed`` when soft-armed)."""

    def __init__(self, system_id: int = 1) -> None:
        self.system_id = system_id
        self.speed_mps = 0.0
        self.dir_deg = 0.0
        self.armed = False

    def on_message(self, m) -> None:
        kind = m.get_type()
        if kind == "PARAM_VALUE":
            name = str(m.param_id).rstrip("\x00")
            if name == "SIM_TIDE_SPEED" and math.isfinite(m.param_value):
                self.speed_mps = float(m.param_value)
            elif name == "SIM_TIDE_DIR" and math.isfinite(m.param_value):
                self.dir_deg = float(m.param_value)
        elif (kind == "HEARTBEAT" and m.get_srcSystem() == self.system_id
              and m.get_srcComponent() == MAV_COMP_ID_AUTOPILOT1):
            self.armed = bool(m.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)

    def current_ne_mps(self) -> tuple[float, float]:
        if not self.armed or self.speed_mps == 0.0:
            return 0.0, 0.0
        d = math.radians(self.dir_deg)
        return -math.cos(d) * self.speed_mps, -math.sin(d) * self.speed_mps


def speed_log_values(log: SpeedLog, gl: GravimeterOnLink, m, tide: SitlTide | None = None) -> list[tuple[int, float]]:
    """The speed log's (time_boot_ms, m/s) values due after ``gl`` took ``m``: a SIMSTATE with a position, stamped
    as the gravimeter stamps it (the newest time_boot_ms seen before it), through the water of ``tide``."""
    if m.get_type() != "SIMSTATE" or gl.t_boot_s is None or (m.lat == 0 and m.lng == 0):
        return []
    cur = tide.current_ne_mps() if tide is not None else (0.0, 0.0)
    return [(int(round(t * 1000.0)), v) for t, v in log.truth(gl.t_boot_s, m.lat * 1e-7, m.lng * 1e-7, cur)]


def build_meter(map_path: str, seed: int, spec: GravimeterSpec, origin: tuple[float, float] | None = None) -> TruthGravimeter:
    gmap = load_grid(map_path)
    lmap = LocalGravityMap.around(gmap)
    rng = np.random.default_rng(seed)
    return TruthGravimeter(lmap, spec, rng, ship_minus_satellite_mgal() if spec.misfit else None, origin)


def raise_on_eof(link) -> None:
    """pymavlink's TCP link without auto-reconnect reports the peer's close by printing "EOF on TCP socket" and
    returning nothing, at every read, for ever: a reader then spins. Make the close a ConnectionError instead."""

    def eof() -> None:
        raise ConnectionError(f"the peer closed {getattr(link, 'address', 'the link')}")

    if hasattr(link, "handle_eof"):
        link.handle_eof = eof


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m companion.sim.sitl_gravimeter_link", description=__doc__.splitlines()[0])
    ap.add_argument("--connect", required=True, help="pymavlink address of a spare SITL port, e.g. tcp:127.0.0.1:5763")
    ap.add_argument("--map", required=True, help="gravity grid (netCDF, mGal)")
    ap.add_argument("--origin", default=None, help="LAT,LON that (0, 0) of a grid in a local metric frame stands for")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--period-s", type=float, default=1.0)
    ap.add_argument("--sigma-mgal", type=float, default=GravimeterSpec.white_sigma_mgal)
    ap.add_argument("--bias-sigma-mgal", type=float, default=GravimeterSpec.bias_sigma_mgal)
    ap.add_argument("--drift-sigma-mgal-per-h", type=float, default=GravimeterSpec.drift_sigma_mgal_per_h)
    ap.add_argument("--window-s", type=float, default=GravimeterSpec.window_s)
    ap.add_argument("--no-eotvos", action="store_true", help="send Eotvos-corrected readings")
    ap.add_argument("--no-misfit", action="store_true", help="no real map misfit")
    ap.add_argument("--name", default=DEFAULT_NAMED_VALUE)
    ap.add_argument("--system-id", type=int, default=1, help="the vehicle's system id")
    ap.add_argument("--record", default=None, help="JSON lines of every reading with its truth")
    ap.add_argument("--rate-hz", type=float, default=10.0, help="SIMSTATE/ATTITUDE rate asked of the autopilot")
    ap.add_argument("--speed-log", metavar="NAME", default="",
                    help="also a boat's water-speed log (companion.sim.speed_log), sent as NAMED_VALUE_FLOAT NAME (m/s)")
    ap.add_argument("--speed-log-scale-sigma", type=float, default=SpeedLogSpec.scale_sigma)
    ap.add_argument("--speed-log-sigma-mps", type=float, default=SpeedLogSpec.white_sigma_mps)
    a = ap.parse_args(argv)
    if len(a.speed_log) > 10 or a.speed_log == a.name:
        ap.error("--speed-log: a NAMED_VALUE_FLOAT name of 1-10 characters other than --name")
    spec = GravimeterSpec(a.sigma_mgal, a.bias_sigma_mgal, a.drift_sigma_mgal_per_h, a.window_s, not a.no_eotvos,
                          not a.no_misfit)
    origin = tuple(float(x) for x in a.origin.split(",")) if a.origin else None
    meter = build_meter(a.map, a.seed, spec, origin)
    gl = GravimeterOnLink(meter, a.period_s)
    # its own generator, derived from the seed: the gravimeter's draws are the same with or without the log
    slog = (SpeedLog(SpeedLogSpec(scale_sigma=a.speed_log_scale_sigma, white_sigma_mps=a.speed_log_sigma_mps),
                     np.random.default_rng([a.seed, 1])) if a.speed_log else None)

    from pymavlink import mavutil

    deadline = time.monotonic() + 60.0
    while True:
        try:
            link = mavutil.mavlink_connection(a.connect, dialect="ardupilotmega", source_system=a.system_id,
                                              source_component=GRAVIMETER_COMPONENT, retries=0)
            break
        except OSError as e:
            if time.monotonic() > deadline:
                print(f"gravimeter: cannot connect {a.connect}: {e}", file=sys.stderr)
                return 2
            time.sleep(0.2)
    raise_on_eof(link)
    stop = {"v": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(v=True))
    rec = open(a.record, "w") if a.record else None
    mav = link.mav
    mav.srcSystem, mav.srcComponent = a.system_id, GRAVIMETER_COMPONENT
    print(f"gravimeter: {a.connect} bias {meter.bias_mgal:+.2f} mGal drift {meter.drift_mgal_per_s * 3600:+.2f} mGal/h "
          f"window {spec.window_s:g} s" + (f"; speed log {a.speed_log}: scale {slog.scale:.4f}, bias "
                                           f"{slog.bias_mps:+.3f} m/s" if slog is not None else ""), flush=True)
    tide = SitlTide(a.system_id)
    asked = 0.0
    try:
        while not stop["v"]:
            now = time.monotonic()
            if now - asked > 5.0:  # (re)ask for the truth streams until they flow
                asked = now
                for mid in (mavutil.mavlink.MAVLINK_MSG_ID_SIMSTATE, mavutil.mavlink.MAVLINK_MSG_ID_ATTITUDE):
                    mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid,
                                          1e6 / a.rate_hz, 0, 0, 0, 0, 0)
                mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GENERIC, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                if slog is not None:  # the tide's parameters (sent to every link when they change, too)
                    for name in TIDE_PARAMS:
                        mav.param_request_read_send(a.system_id, 1, name.encode(), -1)
            m = link.recv_match(blocking=True, timeout=0.2)
            if m is None:
                continue
            for tb_ms, v in gl.on_message(m):
                mav.named_value_float_send(tb_ms, a.name.encode(), float(v))
                if rec is not None:
                    lat, lon = gl.last_truth
                    rec.write(json.dumps({"t_s": tb_ms / 1000.0, "mgal": v, "lat": lat, "lon": lon,
                                          "map_mgal": meter.truth_value_mgal(lat, lon)}) + "\n")
            if slog is not None:
                tide.on_message(m)
                for tb_ms, v in speed_log_values(slog, gl, m, tide):
                    mav.named_value_float_send(tb_ms, a.speed_log.encode(), float(v))
    except (ConnectionError, OSError) as e:
        print(f"gravimeter: link closed: {e}", flush=True)
    finally:
        if rec is not None:
            rec.close()
        print(f"gravimeter: {gl.sent} readings sent", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
