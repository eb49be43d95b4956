"""The command line's argument types and the ``sim`` subcommand's options (companion.cli builds the parser)."""

from __future__ import annotations

import argparse
import math
import re
import sys


class OneLineParser(argparse.ArgumentParser):
    """A usage error is one line on stderr and exit 2 (the promise for every error), not the usage block."""

    def error(self, message: str):
        from companion.logsetup import stderr_line

        sub = " ".join(self.prog.split()[1:])  # "companion run" -> "run"
        stderr_line(f"companion: error: {sub + ': ' if sub else ''}{message} (--help for usage)")
        sys.exit(2)  # (companion.cli.EXIT_ERROR)


#: the status line's shortest period: a floor that keeps the log calm (1e-9 s wrote 31,777 lines in 2 s)
MIN_STATUS_EVERY_S = 1.0


def _status_period(text: str) -> float:
    v = _positive_float(text)
    if not (math.isfinite(v) and v >= MIN_STATUS_EVERY_S):
        raise argparse.ArgumentTypeError(f"{text!r} must be >= {MIN_STATUS_EVERY_S:g} s")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number > 0")
    return v



def add_sim_parser(sub) -> argparse.ArgumentParser:
    """``companion sim``: a simulated ArduPilot vehicle on a MAVLink link."""
    v = sub.add_parser("sim", help="simulated ArduPilot vehicle on a MAVLink link, for hardware-in-the-loop tests")
    v.add_argument("--listen", default="tcpin:127.0.0.1:5760", help="tcpin:HOST:PORT (like SITL) or udpout:HOST:PORT")
    v.add_argument("--log", help="play this .tlog (default: a generated flight, the sample flight's profile)")
    v.add_argument("--profile", choices=("sample", "circuit", "cruise"), default="sample",
                   help="generated flight: the sample flight, 200 m circuits that can loop, or an hours-long lawn-mower survey cruise")
    v.add_argument("--loops", type=int, default=1, help="play the source this many times, boot time running on (0: until stopped)")
    v.add_argument("--gnss-hz", type=_positive_float, default=None, help="generated flight: GNSS rate (default 10; cruise 5)")
    v.add_argument("--imu-hz", type=_positive_float, default=None, help="generated flight: IMU rate (default 50; cruise 25)")
    v.add_argument("--attitude-hz", type=_positive_float, default=10.0, help="generated flight: ATTITUDE rate (default 10)")
    v.add_argument("--sensors", choices=("drone", "aircraft"), default="drone",
                   help="generated flight: sensor set (drone: MEMS IMU + AHRS; aircraft: tactical IMU, navigation-grade "
                        "attitude/heading), see companion.sim.flight.SENSOR_SETS")
    c = v.add_argument_group("cruise (--profile cruise): a lawn-mower survey from --origin, lines along --cruise-heading")
    c.add_argument("--hours", type=_positive_float, default=3.0, help="flight duration in hours (default 3)")
    c.add_argument("--cruise-speed", type=_positive_float, default=150.0,
                   help="cruise speed m/s (default 150, an aircraft; below 30 the ship defaults apply: 0 m, 20 km lines 2 km apart)")
    c.add_argument("--origin", metavar="LAT,LON", default=None, help="start (survey box corner) in degrees (default -40.5,155.6, Tasman Sea)")
    c.add_argument("--line-km", type=_positive_float, default=None, help="survey line length km (default 300; ship 20)")
    c.add_argument("--spacing-km", type=_positive_float, default=None, help="distance between lines km (default 25; ship 2)")
    c.add_argument("--cruise-heading", type=float, default=0.0, help="direction of the first line, deg from north (default 0); later lines lie to its right")
    c.add_argument("--cruise-alt", type=float, default=None, help="survey height above the origin m (default 300; ship 0)")
    c.add_argument("--max-lines", type=int, default=None, help="turn back across the box after this many lines (default: keep adding lines)")
    # let "--origin -40.5,155.6" read as a value, not an option (argparse only knows plain negative numbers)
    v._negative_number_matcher = re.compile(r"^-\d+$|^-\d*\.?\d+(,-?\d*\.?\d+)?$")
    gr = v.add_argument_group("gravimeter: NAMED_VALUE_FLOAT readings of a gravity map at the true position (generated flights)")
    gr.add_argument("--gravity-map", metavar="FILE", default=None, help="gravity anomaly grid (netCDF, mGal, lat/lon axes)")
    gr.add_argument("--gravity-name", default="GRAV", help="NAMED_VALUE_FLOAT name (default GRAV, at most 10 characters)")
    gr.add_argument("--gravity-sigma-mgal", type=float, default=1.0, help="gravimeter white noise (default 1 mGal; seeded by --seed)")
    gr.add_argument("--gravity-hz", type=_positive_float, default=1.0, help="gravimeter reading rate (default 1 Hz)")
    v.add_argument("--seed", type=int, default=None, help="generated flight / noise seed")
    v.add_argument("--speed", type=_positive_float, default=1.0, help="playback speed (1 = real time)")
    v.add_argument("--start", type=float, default=0.0, help="start at this playback time (s)")
    v.add_argument("--end", type=float, default=None, help="stop at this playback time (s)")
    v.add_argument("--streams", choices=("requested", "all"), default="requested", help="send streams only once requested (default), or all")
    v.add_argument("--gnss-off", type=float, nargs=2, metavar=("FROM", "TO"), help="GNSS cut window (playback s)")
    v.add_argument("--imu-off", type=float, nargs=2, metavar=("FROM", "TO"), help="IMU stop window (playback s)")
    v.add_argument("--link-drop", type=float, nargs=2, metavar=("FROM", "TO"), help="link drop window (playback s)")
    v.add_argument("--reboot-at", type=float, default=None, help="reboot at this playback time (s)")
    v.add_argument("--reboot-downtime", type=float, default=2.0, help="silence during a reboot (s, default 2)")
    v.add_argument("--noise", action="store_true", help="bad input once a second: garbage, bad CRC, other systems, NaN, duplicates")
    v.add_argument("--signing-key-file", default=None, help="sign what we send, accept only signed frames")
    v.add_argument("--record", help="JSON-lines record of every GPS_INPUT received (with truth and error)")
    v.add_argument("--gps-mav-instance", type=int, choices=(0, 1), default=None, metavar="N",
                   help="GPS instance N (0 or 1, = the companion's gps_id) is a MAVLink GPS (GPS{N+1}_TYPE=14) as "
                        "ArduPilot has it: arming waits for a 3D GPS_INPUT for it at most 1 s old (the flight follows "
                        "later; 'PreArm: GPS {N+1}: Bad fix' meanwhile); the record marks GPS_INPUT the autopilot ignores")
    v.add_argument("--idle-exit", type=float, default=10.0, metavar="SECONDS",
                   help="end once the companion has gone quiet this long after it was heard (default 10: a companion "
                        "reconnects within its 8 s back-off; 0: serve until the flight ends or SIGTERM)")
    return v
