"""Shared test helpers: where the real data lives (companion.shared_data), a free local port.

A test that needs the shared data calls `require(path)`: it skips with the reason when the data is missing, and
FAILS instead when the environment says the data must be there (``COMPANION_REQUIRE_SHARED=1``, set by .ci/run).
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest

from companion.shared_data import REQUIRE_ENV_VAR, shared_dir, shared_gravity_dir, shared_logs_dir, shared_required

REPO = Path(__file__).resolve().parents[1]
SHARED = shared_dir()
SHARED_LOGS = shared_logs_dir()
SHARED_GRAVITY = shared_gravity_dir()
SAMPLE_LOG = REPO / "logs" / "sample_flight.tlog"

LOG171 = SHARED_LOGS / "ac33dev_pixhawk1_quad_2015-11-21_dronekit-la-testdata_log171.bin"
LOG_AC313 = SHARED_LOGS / "ac313_pixhawk1_frame10_2014-10-18_20-04-24_joeydouglas.bin"
LOG_ERLE = SHARED_LOGS / "ac33dev_erle-pxf_quad_2014-11-06_GPS_issues1_inflight-gps-loss.bin"
LOG_AC402 = SHARED_LOGS / "ac402_pixracer_quad_2020-03-03_diaven-sample02_no-imu.bin"
LOG_TLOG = SHARED_LOGS / "ac357_pixhawk-px4v3_quad_2018-09-25_15-36-53_phoenix-mission2.tlog"
REAL_LOGS = [LOG171, LOG_AC313, LOG_ERLE, LOG_AC402, LOG_TLOG]

AK_MAP = SHARED_GRAVITY / "AK_gulf_grav.nc"
TASMAN_MAP = SHARED_GRAVITY / "tasman_grav_west_145E-160E.nc"


def require(path: Path) -> Path:
    """The shared file, or skip (fail where the shared data is required) with the reason."""
    if not path.exists():
        why = f"shared data not found: {path} (set COMPANION_SHARED)"
        if shared_required():
            pytest.fail(f"{why}; {REQUIRE_ENV_VAR} is set, so the shared data must be there", pytrace=False)
        pytest.skip(why)
    return path


def sitl_binary(env_var: str, program: str, waf_target: str) -> str:
    """The ArduPilot SITL binary ``env_var`` names (built outside this repository), or skip with how to get one."""
    path = os.environ.get(env_var)
    if not path:
        pytest.skip(f"{env_var} not set: point it at an {program} SITL binary (build/sitl/bin/{program.lower()} of an "
                    f"ArduPilot checkout, built with `./waf configure --board sitl && ./waf {waf_target}`)")
    if not (os.path.isfile(path) and os.access(path, os.X_OK)):
        pytest.skip(f"{env_var}={path} is not an executable file")
    return path


@pytest.fixture
def shared_data() -> Path:
    """The shared data directory (skips, or fails where required, when it is missing)."""
    return require(SHARED)


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port nobody listens on at 127.0.0.1 right now (TCP by default; socket.SOCK_DGRAM for UDP)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
