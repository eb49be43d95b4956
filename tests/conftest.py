"""Shared test fixtures: where the real data lives (../shared beside the checkout)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("COMPANION_SHARED", REPO.parent / "shared"))
SHARED_LOGS = SHARED / "data" / "logs"
SAMPLE_LOG = REPO / "logs" / "sample_flight.tlog"

LOG171 = SHARED_LOGS / "ac33dev_pixhawk1_quad_2015-11-21_dronekit-la-testdata_log171.bin"
LOG_AC313 = SHARED_LOGS / "ac313_pixhawk1_frame10_2014-10-18_20-04-24_joeydouglas.bin"
LOG_ERLE = SHARED_LOGS / "ac33dev_erle-pxf_quad_2014-11-06_GPS_issues1_inflight-gps-loss.bin"
LOG_AC402 = SHARED_LOGS / "ac402_pixracer_quad_2020-03-03_diaven-sample02_no-imu.bin"
LOG_TLOG = SHARED_LOGS / "ac357_pixhawk-px4v3_quad_2018-09-25_15-36-53_phoenix-mission2.tlog"
REAL_LOGS = [LOG171, LOG_AC313, LOG_ERLE, LOG_AC402, LOG_TLOG]


def require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"shared data not found: {path} (set COMPANION_SHARED)")
    return path
