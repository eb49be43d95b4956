"""Re-run the companion on the inputs it recorded in kept SITL A/B flights (replay.live.sitl), with other settings, and
score its own solution in the outage against SITL's truth: the same inputs, so settings are compared on identical
flights without flying again (the vehicle's path does not change: in a re-run nothing reaches the autopilot).

    python -m replay.live.sitl_rerun DIR [--set navigator.motion_prior=false] [--set trust.min_manoeuvre_mps=0]

DIR is a kept run's directory (its companion_*.mcap records and log_*.json flight logs). Per flight: the takeover
decision and trust measures at the loss, then the companion's error against truth / its stated h_acc / its fix type
every 5 s of the denial, and the share of its 3D fixes (what EKF3 fuses) in the denial within 2x their h_acc.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from companion import events as ev
from companion.config import parse_override
from companion.inject.gps_input import GpsInputRecord, InjectConfig, Injector, InjectorState
from companion.nav.navigator import Navigator, NavigatorConfig
from companion.nav.trust import TrustConfig, TrustVerdict
from companion.pipeline.core import Pipeline
from replay.live import sitl_core as core
from replay.live.sitl import COMPANION_SETS

#: the recorded input topics the navigator and injector use, and their event types
INPUTS = {"/input/imu": ev.ImuSample, "/input/gnss": ev.GnssFix, "/input/attitude": ev.Attitude,
          "/input/heartbeat": ev.Heartbeat, "/input/system_time": ev.SystemTime,
          "/input/altitude": ev.AutopilotAltitude}


def recorded_inputs(mcap: Path) -> list[ev.Event]:
    """The input events of a companion record, in record order (None in a float field is the NaN it was recorded from)."""
    from companion.record.inspect import iter_payloads

    out = []
    for topic, _t, data in iter_payloads(mcap):
        cls = INPUTS.get(topic)
        if cls is None:
            continue
        d = json.loads(data)
        kw = {}
        for f in dataclasses.fields(cls):
            v = d.get(f.name)
            kw[f.name] = tuple(v) if isinstance(v, list) else (math.nan if v is None and f.type == "float" else v)
        out.append(cls(**kw))
    return out


class _Keep:
    def __init__(self) -> None:
        self.items: list = []

    def write(self, item, topic=None) -> None:
        self.items.append(item)

    def write_location(self, *a, **k) -> None:
        pass


def settings(sets: list[str]) -> tuple[NavigatorConfig, InjectConfig, TrustConfig]:
    """The companion arm's settings (replay.live.sitl.COMPANION_SETS) with ``sets`` on top, shadow mode."""
    sec: dict[str, dict] = {"navigator": {}, "inject": {}, "trust": {}}
    for s in COMPANION_SETS + sets:
        key, value = parse_override(s)
        name, _, field = key.partition(".")
        sec[name][field] = value
    inject = {**sec["inject"], "mode": "shadow"}
    return NavigatorConfig(**sec["navigator"]), InjectConfig(**inject), TrustConfig(**sec["trust"])


def rerun(work: Path, tag: str, sets: list[str]) -> dict:
    log = core.FlightLog.from_dict(json.loads((work / f"log_{tag}.json").read_text()))
    nav_c, inj_c, trust_c = settings(sets)
    sink = _Keep()
    pipe = Pipeline(stages=[Navigator(nav_c), Injector(inj_c, trust=trust_c)], sink=sink)
    for e in recorded_inputs(work / f"companion_{tag}.mcap"):
        pipe.process(e)
    pipe.finish()
    t0, t1 = log.marks["deny_on"], log.marks["deny_off"]
    recs = [o for o in sink.items if isinstance(o, GpsInputRecord)]
    t = np.array([r.time_boot_us / 1e6 for r in recs])
    err = core.horizontal_error(t, [r.lat_deg for r in recs], [r.lon_deg for r in recs], log.truth)
    hacc = np.array([r.h_acc_m for r in recs])
    fix = np.array([r.fix_type for r in recs])
    verdict = [v for v in sink.items if isinstance(v, TrustVerdict) and v.t_s <= t0 + 1.0]
    state = [s.reason for s in sink.items if isinstance(s, InjectorState) and s.t_s >= t0 - 1.0]
    marks = {k: (float(err[i]), float(hacc[i]), int(fix[i])) for k in range(5, int(t1 - t0) + 1, 5)
             for i in [int(np.argmin(np.abs(t - (t0 + k))))]}
    den = (t >= t0) & (t < t1) & (fix >= 3) & np.isfinite(err)
    return {"decision": state[0] if state else "", "verdict": verdict[-1] if verdict else None, "marks": marks,
            "within_2hacc": float(np.mean(err[den] <= 2 * hacc[den])) if den.any() else math.nan}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m replay.live.sitl_rerun", description=__doc__.split("\n\n")[0])
    p.add_argument("dir", help="a kept run of python -m replay.live.sitl")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="on top of the companion arm's settings (navigator., inject., trust.)")
    a = p.parse_args(argv)
    work = Path(a.dir)
    tags = sorted(m.stem[len("companion_"):] for m in work.glob("companion_*.mcap") if (work / f"log_{m.stem[10:]}.json").exists())
    if not tags:
        print(f"no companion_*.mcap with its log_*.json in {work}", file=sys.stderr)
        return 2
    print(f"settings: {' '.join(COMPANION_SETS + a.set)}")
    for tag in tags:
        r = rerun(work, tag, a.set)
        v = r["verdict"]
        trust = (f"heading sigma {math.degrees(v.yaw_sigma_rad):.1f} deg, manoeuvres {v.manoeuvre_mps:.1f} m/s, "
                 f"accel bias sigma {v.accel_bias_sigma_mps2:.3f} m/s^2, NIS {v.nis_ratio:.2f}, aided {v.aided_s:.0f} s"
                 if v is not None and math.isfinite(v.yaw_sigma_rad) else "not judged")
        print(f"{tag}: {r['decision']} ({trust})")
        print("   error / h_acc / fix: " + "  ".join(f"+{k}: {e:.1f}/{h:.1f}/{f}" for k, (e, h, f) in r["marks"].items())
              + f"; within 2x h_acc {100 * r['within_2hacc']:.0f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
