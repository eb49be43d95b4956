"""Gravity-aided flight through a long GNSS denial, live: `companion sim` flies an hours-long cruise over a real gravity
grid and sends the gravimeter as NAMED_VALUE_FLOAT; the real `companion run` process (gravity stage, GPS_INPUT in
inject mode) keeps injecting; the simulator records every GPS_INPUT with the truth at its time.

Two runs on the same flight and seed, same navigator settings (companion.gravity.stage.gravity_nav_config):
  aided  -- the gravity stage's fixes go into the navigator (``--matcher``: the Viterbi window matcher with its
            acceptance test, or the sequential filter of companion.gravity.sequential_stage);
  INS    -- the Viterbi stage with every fix rejected (accept_min_signal_ratio = 1e9): the navigator's INS alone.
The playback runs `--speed-up` times faster than real time; vehicle time comes from the messages only.

Validity: a run is scored only if the companion kept up with its input. Its summary says how long its input waited
before processing (``lag`` line: the longest wait and how many events waited more than ``inject.max_lag_s``); a run
with any input event processed later than ``max_lag_s`` after its arrival fell behind its input (it coalesced IMU samples and withheld stale states, so its
errors are those of an overloaded machine, not of the method) and is reported invalid, not scored. The simulator's
own pacing lag is stated beside it.

    nice -n 5 .venv/bin/python -m replay.live.long_denial --hours 3 --speed-up 10
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from companion.gravity.data import TASMAN, shared_gravity_dir
from replay.harness.results import RESULTS_DIR as RESULTS
from replay.harness.results import md_table
from replay.live import free_port

#: the companion's summary line on how far its processing fell behind its input (companion.runtime.runner)
LAG_RE = re.compile(r"at most ([0-9.]+) s after it arrived; (\d+) of (\d+) events beyond inject.max_lag_s ([0-9.]+) s")

MAP = shared_gravity_dir() / TASMAN
CLI = [sys.executable, "-m", "companion.cli"]
#: companion-side [navigator] settings matching the simulator's sensor set (companion.sim.flight.SENSOR_SETS):
#: the defaults describe a multicopter's MEMS IMU and AHRS; an aircraft's tactical IMU and navigation-grade
#: attitude/heading reference are told to the filter (heading from ATTITUDE fused: it is the better reference there)
NAV_SETTINGS = {
    "drone": {},
    "aircraft": {"accel_noise_mps2_rthz": 0.01, "gyro_noise_radps_rthz": 0.001, "accel_bias_sigma_mps2": 0.005,
                 "gyro_bias_sigma_radps": 0.0005, "att_sigma_tilt_rad": 0.001, "att_sigma_yaw_rad": 0.002,
                 "fuse_attitude_yaw": True},
}


def _velocity_note(a) -> str:
    """Title suffix when the sequential filter's fixes carry its velocity estimate (gravity.seq_velocity_fixes)."""
    on = any(kv.replace(" ", "").lower() == "gravity.seq_velocity_fixes=true" for kv in a.set)
    return ", with velocity fixes" if on else ""


def summary_lines(text: str) -> list[str]:
    """The companion's summary with each wrapped entry on one line: it wraps a long entry to the terminal's width
    (80 columns in a pipe), its continuation lines indented under the text (companion.cli._summary_line)."""
    lines: list[str] = []
    for line in text.splitlines():
        if lines and line.startswith(" " * 13) and line[13:14] not in (" ", ""):
            lines[-1] += " " + line[13:]
        else:
            lines.append(line)
    return lines


def run_once(a, variant: str, work: Path) -> dict:
    """One sim + companion pair; returns the GPS_INPUT records and the companion's summary lines."""
    port = free_port()
    rec = work / f"sim_{variant}.jsonl"
    sim_cmd = [*CLI, "sim", "--profile", "cruise", "--hours", a.hours, "--cruise-speed", a.cruise_speed,
               "--origin", a.origin, "--line-km", a.line_km, "--spacing-km", a.spacing_km,
               "--gravity-map", a.map, "--gravity-sigma-mgal", a.sigma_mgal, "--seed", a.seed,
               "--imu-hz", a.imu_hz, "--gnss-hz", a.gnss_hz, "--gnss-off", a.gnss_off_s, 1e9, "--sensors", a.sensors,
               "--listen", f"tcpin:127.0.0.1:{port}", "--speed", a.speed_up, "--record", rec]
    sim = subprocess.Popen(list(map(str, sim_cmd)), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = sim.stdout.readline()
    if not first.startswith("sim:"):
        raise SystemExit(f"simulator did not start: {first}{sim.stderr.read()}")
    comp_cmd = [*CLI, "run", "--connect", f"tcp:127.0.0.1:{port}", "--out", work / f"companion_{variant}.mcap",
                "--inject", "inject", "--gravity-map", a.map, "--set", f"gravity.sigma_mgal={a.sigma_mgal}",
                "--set", "record.segment_s=900", "--set", "inject.max_speed_mps=400"]
    for k, v in NAV_SETTINGS[a.sensors].items():
        comp_cmd += ["--set", f"navigator.{k}={str(v).lower() if isinstance(v, bool) else v}"]
    if variant == "ins":
        comp_cmd += ["--set", "gravity.matcher=viterbi", "--set", "gravity.accept_min_signal_ratio=1e9"]
    else:
        comp_cmd += ["--set", f"gravity.matcher={a.matcher}"] + [x for kv in a.set for x in ("--set", kv)]
    comp = subprocess.Popen(list(map(str, comp_cmd)), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    sim_out, sim_err = sim.communicate()
    wall = time.monotonic() - t0
    comp.send_signal(signal.SIGTERM)
    out, err = comp.communicate(timeout=120)
    if sim.returncode or "Traceback" in sim_err:
        raise SystemExit(f"simulator failed:\n{sim_err[-3000:]}")
    if "Traceback" in err:
        raise SystemExit(f"companion failed:\n{err[-3000:]}")
    recs = [json.loads(line) for line in rec.read_text().splitlines()]
    gi = [r for r in recs if r["event"] == "gps_input" and "err_h_m" in r]
    lines = summary_lines(out)
    grav = next((line for line in lines if line.startswith("gravity ")), "")
    lat = next((line for line in lines if line.startswith("latency ")), "")
    lag_line = next((line for line in lines if line.startswith("lag ")), "")
    m = LAG_RE.search(lag_line)
    if m is None:
        raise SystemExit(f"companion summary has no lag line:\n{out[-3000:]}")
    end = next((r for r in recs if r["event"] == "end"), {})
    lag = {"max_s": float(m.group(1)), "late": int(m.group(2)), "events": int(m.group(3)),
           "max_lag_s": float(m.group(4)), "sim_max_lag_s": float(end.get("max_lag_s", float("nan"))),
           "sim_late": int(end.get("late_messages", -1))}
    lag["valid"] = lag["late"] == 0
    print(f"{variant}: {len(gi)} GPS_INPUT with truth, {wall:.0f} s wall; {grav}; {lag_line}", flush=True)
    return {"end_s": end.get("play_s", float("nan")), "t_s": np.array([r["state_play_s"] for r in gi]),
            "err_m": np.array([r["err_h_m"] for r in gi]), "fix_type": np.array([r["fix_type"] for r in gi]),
            "h_acc_m": np.array([r["h_acc_m"] for r in gi]), "gravity": grav, "latency": lat, "wall_s": wall, "lag": lag}


def draw_origin(seed: int, speed_mps: float, hours: float, line_km: float, spacing_km: float, cut_s: float,
                min_track_std_mgal: float) -> tuple[float, float, float]:
    """A survey start over features, drawn as the marine benchmark draws its tracks (replay.gravity.marine.draw_track,
    Gao 2022 sec. 3): starts uniform in the Tasman strong-feature area (45 km margin) from ``seed``, the first whose
    survey (this script's lines, first line north) lies on valid map with the map's STD along it after the GNSS cut
    >= ``min_track_std_mgal``. Returns (lat, lon, STD)."""
    from companion.sim.cruise import survey_waypoints
    from replay.gravity.marine import map_case

    case = map_case("Tasman")
    lmap = case.filter_map
    rng = np.random.default_rng(seed)
    n0, n1, e0, e1 = case.box_ne_m
    wps = np.array([(0.0, 0.0)] + survey_waypoints(speed_mps * hours * 3600.0, line_km * 1e3, spacing_km * 1e3, 0.0))
    step_m = 30.0 * speed_mps
    pts = []
    for p0, p1 in zip(wps[:-1], wps[1:]):
        k = max(1, int(np.hypot(*(p1 - p0)) / step_m))
        pts += [p0 + (p1 - p0) * i / k for i in range(k)]
    path = np.array(pts)
    first_after_cut = int(cut_s * speed_mps / step_m)
    for _ in range(2000):
        start = np.array([rng.uniform(n0 + 45e3, n1 - 45e3), rng.uniform(e0 + 45e3, e1 - 45e3)])
        g = lmap.interp_ne(path[:, 0] + start[0], path[:, 1] + start[1])
        if np.all(np.isfinite(g)) and np.std(g[first_after_cut:]) >= min_track_std_mgal:
            lon, lat = lmap.ne_to_xy(np.array(start[0]), np.array(start[1]))
            return float(lat), float(lon), float(np.std(g[first_after_cut:]))
    raise SystemExit("no survey start with that much map signal in the Tasman strong-feature area")


def _ins_run(a, work: Path) -> dict:
    """The INS-alone run, reused from ``work`` when the same scenario was flown there before and kept up with its
    input (it does not depend on the aided run's matcher or settings)."""
    key = [a.hours, a.speed_up, a.cruise_speed, a.origin, a.line_km, a.spacing_km, a.gnss_off_s, a.sigma_mgal, a.seed,
           a.imu_hz, a.gnss_hz, a.sensors, str(Path(a.map).resolve())]
    cache = work / "ins_runs.json"
    known = json.loads(cache.read_text()) if cache.exists() else []
    for entry in known:
        if entry["key"] == key and entry["run"]["lag"]["valid"]:  # an invalid run is flown again
            print("ins: reused from an earlier run of the same scenario in", work, flush=True)
            r = entry["run"]
            return {**r, **{k: np.array(r[k]) for k in ("t_s", "err_m", "fix_type", "h_acc_m")}, "reused": True}
    r = run_once(a, "ins", work)
    if not r["lag"]["valid"]:
        return r
    known.append({"key": key, "run": {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in r.items()}})
    cache.write_text(json.dumps(known))
    return r


def _at(run, t_s):
    i = np.searchsorted(run["t_s"], t_s)
    return float(run["err_m"][min(i, run["t_s"].size - 1)]) if run["t_s"].size else float("nan")


def _lag_text(name: str, r: dict, speed_up: float) -> str:
    g = r["lag"]
    verdict = ("valid: kept up with its input" if g["valid"] else
               f"INVALID: {g['late']} input events waited longer than max_lag_s = {g['max_lag_s']:g} s (it fell behind "
               "its input: not scored)")
    return (f"- {name}: input processed at most {g['max_s']:.3f} s (wall) after it arrived, {g['late']} of "
            f"{g['events']} events beyond max_lag_s {g['max_lag_s']:g} s -- {verdict}; simulator pacing lag at most "
            f"{g['sim_max_lag_s']:.3f} s playback ({g['sim_max_lag_s'] / speed_up * 1e3:.0f} ms wall), "
            f"{g['sim_late']} messages > 10 ms late")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=3.0)
    ap.add_argument("--speed-up", type=float, default=10.0)
    ap.add_argument("--cruise-speed", type=float, default=150.0, help="m/s")
    ap.add_argument("--origin", default="-40.5,155.6",
                    help="LAT,LON of the survey's start, or draw: over features (see --min-track-std-mgal)")
    ap.add_argument("--line-km", type=float, default=300.0)
    ap.add_argument("--spacing-km", type=float, default=20.0)
    ap.add_argument("--gnss-off-s", type=float, default=1200.0, help="GNSS cut from this playback time to the end")
    ap.add_argument("--sigma-mgal", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--min-track-std-mgal", type=float, default=15.0,
                    help="with --origin draw: the map STD the survey must see after the cut (the marine benchmark's rule)")
    ap.add_argument("--imu-hz", type=float, default=25.0)
    ap.add_argument("--gnss-hz", type=float, default=5.0)
    ap.add_argument("--sensors", choices=tuple(NAV_SETTINGS), default="aircraft", help="simulated sensor set")
    ap.add_argument("--matcher", default="viterbi", choices=("viterbi", "sequential"), help="the aided run's gravity stage")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="extra companion setting for the aided run (e.g. gravity.seq_gyro_bias_degph=1)")
    ap.add_argument("--name", default=None, help="results file stem suffix (default: the sensor set)")
    ap.add_argument("--map", default=str(MAP))
    ap.add_argument("--work", default="out/gravity_live")
    ap.add_argument("--no-write", action="store_true", help="print only (no results file, no plot)")
    a = ap.parse_args(argv)
    a.name = a.name or a.sensors
    origin_note = ""
    if a.origin == "draw":
        lat, lon, std = draw_origin(a.seed, a.cruise_speed, a.hours, a.line_km, a.spacing_km, a.gnss_off_s,
                                    a.min_track_std_mgal)
        a.origin = f"{lat:.3f},{lon:.3f}"
        origin_note = (f" (drawn: `--origin draw --min-track-std-mgal {a.min_track_std_mgal:g}`, seed {a.seed}; map "
                       f"STD along the track after the cut {std:.1f} mGal)")
        print(f"origin drawn: {a.origin}{origin_note}", flush=True)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    runs = {"aided": run_once(a, "aided", work), "ins": _ins_run(a, work)}
    valid = {k: r["lag"]["valid"] for k, r in runs.items()}
    cut = a.gnss_off_s
    scored = {k: r for k, r in runs.items() if valid[k] and r["t_s"].size}
    end = min((r["t_s"][-1] for r in scored.values()), default=cut)
    marks = np.arange(cut, end + 1e-9, 600.0)
    rows = [[f"{(m - cut) / 60:.0f}"] + [round(_at(runs[k], m), 1) if k in scored else "invalid" for k in ("aided", "ins")]
            for m in marks]
    summary = []
    for name, r in runs.items():
        if name not in scored:
            summary.append([name, "invalid: fell behind its input (see below)"] + ["-"] * 10)
            continue
        sel = r["t_s"] >= cut
        e = r["err_m"][sel]
        h = r["h_acc_m"][sel]
        before = r["err_m"][(r["t_s"] > 60.0) & (r["t_s"] < cut)]
        hours = []
        for h0 in np.arange(cut, end, 3600.0):
            w = (r["t_s"] >= h0) & (r["t_s"] < h0 + 3600.0)
            hours.append(f"{np.mean(r['err_m'][w]):.0f}" if w.any() else "-")
        ft = r["fix_type"][sel]
        types = ", ".join(f"{k}: {np.mean(ft == k):.0%}" for k in sorted(set(ft.tolist())))
        summary.append([name, f"{np.median(before):.1f}" if before.size else "-", f"{np.mean(e):.0f}",
                        f"{np.percentile(e, 95):.0f}", f"{np.max(e):.0f}", " / ".join(hours),
                        f"{np.mean(h):.0f}", f"{np.mean(e <= h):.0%}", f"{np.mean(e <= 2 * h):.0%}", types,
                        f"{sel.sum()}", f"{(r['t_s'][-1] - cut) / 60:.0f} of {(r['end_s'] - cut) / 60:.0f}"])
    cmd = (f"nice -n 5 .venv/bin/python -m replay.live.long_denial --hours {a.hours:g} --speed-up {a.speed_up:g} "
           f"--cruise-speed {a.cruise_speed:g} --origin={a.origin} --line-km {a.line_km:g} --spacing-km {a.spacing_km:g} "
           f"--gnss-off-s {a.gnss_off_s:g} --sigma-mgal {a.sigma_mgal:g} --seed {a.seed} --sensors {a.sensors}"
           + (f" --matcher {a.matcher}" if a.matcher != "viterbi" else "") + "".join(f" --set {kv}" for kv in a.set)
           + (f" --name {a.name}" if a.name != a.sensors else ""))
    stage_text = ("Viterbi RVBMP-2i with the navigator's own sigma as the prior, readings averaged per map cell of "
                  "track, fix acceptance on" if a.matcher == "viterbi" else
                  "the sequential filter (companion.gravity.sequential_stage: every reading, marginalised particle "
                  f"filter, its fixes the filter's posterior with the navigator's prior divided out; settings "
                  f"{', '.join(a.set) or 'defaults'})")
    text = "\n".join([
        f"# Gravity-aided {'voyage' if a.cruise_speed < 30 else 'flight'} through a long GNSS denial, live "
        f"(`companion sim` + `companion run`), {a.cruise_speed:g} m/s, {a.sensors} sensors"
        + (f", {a.matcher} filter" if a.matcher != "viterbi" else "") + _velocity_note(a),
        "",
        f"`{cmd}`",
        "",
        f"Simulated {'ship' if a.cruise_speed < 30 else 'aircraft'}: {a.hours:g} h lawn-mower survey at {a.cruise_speed:g} m/s from {a.origin}{origin_note} over the Tasman "
        f"grid (Sandwell & Smith V15.2, ~2.9 km cells), lines {a.line_km:g} km, {a.spacing_km:g} km apart; "
        f"{a.sensors} sensors (companion.sim.flight.SENSOR_SETS; navigator settings "
        f"{NAV_SETTINGS[a.sensors] or 'defaults'}); IMU "
        f"{a.imu_hz:g} Hz, GNSS {a.gnss_hz:g} Hz until {a.gnss_off_s:g} s, then cut to the end; gravimeter 1 Hz "
        f"NAMED_VALUE_FLOAT, map value at the truth + N(0, {a.sigma_mgal:g} mGal). `companion run` ({stage_text}; "
        "barometric altitude from GLOBAL_POSITION_INT as the vertical aid) injects GPS_INPUT; the simulator scores every "
        f"GPS_INPUT against its truth. Played at x{a.speed_up:g}; wall time aided {runs['aided']['wall_s']:.0f} s, "
        f"INS {runs['ins']['wall_s']:.0f} s"
        + (" (the INS-alone run of this scenario from an earlier invocation, same flight and seed)."
           if runs["ins"].get("reused") else "."),
        "",
        "Playback lag (a run whose processing fell behind its input by more than max_lag_s is invalid and not scored):",
        "",
        _lag_text("aided", runs["aided"], a.speed_up),
        _lag_text("INS", runs["ins"], a.speed_up),
        "",
        "Horizontal error of the injected positions (m):",
        "",
        md_table(["run", "median before the cut", "mean after the cut", "p95 after", "max after",
                  "mean per hour of denial", "mean reported h_acc after (m)", "error <= h_acc", "error <= 2 h_acc",
                  "fix_type sent after", "GPS_INPUT after the cut", "last GPS_INPUT, min after the cut"], summary),
        "",
        "The injector stops sending when the fused state fails its plausibility checks (e.g. a horizontal speed above "
        "inject.max_speed_mps = 400 m/s once an INS has diverged): see the last column. "
        "fix_type follows the reported accuracy with the default [inject] bounds (3D <= 10 m, 2D <= 50 m, else 1 = no "
        "fix): km-level gravity fixes go out as fix_type 1 with an honest h_acc; an operator who wants the autopilot "
        "to use them raises inject.max_h_acc_2d_m.",
        "",
        "Error at 10-minute marks after the cut (m):",
        "",
        md_table(["minutes after cut", "aided", "INS alone"], rows),
        "",
        f"- aided: {runs['aided']['gravity'].removeprefix('gravity').strip()}",
        f"- INS: {runs['ins']['gravity'].removeprefix('gravity').strip()}",
        f"- wall-clock latency at x{a.speed_up:g} playback, aided run (not the real-time figure, which is in live.md): "
        f"{runs['aided']['latency'].removeprefix('latency').strip()}",
        "",
        f"![error over time](gravity_live_{a.name}_error.png)",
    ])
    print(text)
    if a.no_write:
        return 0 if all(valid.values()) else 3
    (RESULTS / f"gravity_live_{a.name}.md").write_text(text + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.5))
    span_h = 0.0
    for name, key, c in (("INS alone", "ins", "tab:red"), ("gravity-aided", "aided", "tab:blue")):
        r = runs[key]
        if key not in scored:
            ax.plot([], [], color=c, label=f"{name}: invalid (fell behind its input), not shown")
            continue
        x = (r["t_s"] - cut) / 3600.0
        ax.plot(x, r["err_m"] / 1000.0, color=c, lw=0.8, label=f"{name}: error")
        ax.plot(x, 2.0 * r["h_acc_m"] / 1000.0, color=c, lw=0.6, ls=":", label=f"{name}: 2 x reported h_acc")
        if len(x):
            span_h = max(span_h, float(x[-1] - x[0]))
            if x[-1] < (r["end_s"] - cut) / 3600.0 - 0.05:  # the injector stopped before the flight's end
                ax.plot(x[-1], r["err_m"][-1] / 1000.0, "x", color=c, ms=8,
                        label=f"{name}: last GPS_INPUT, {x[-1] * 60:.0f} min after the cut")
    ax.axvline(0.0, color="k", lw=0.6, ls="--")
    ax.set_xlabel("hours after the GNSS cut")
    ax.set_ylabel("injected position error (km)")
    if scored:  # a log scale needs data: with every run invalid the axes stay empty (and say why)
        ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize=8)  # beside the data
    # the span drawn, from the data: the planned flight is longer when the injector stopped early
    planned = "" if span_h >= a.hours - 0.05 else f" (of a {a.hours:g} h flight)"
    ax.set_title(f"companion run, live GPS_INPUT over {span_h:.1f} h{planned}: survey at {a.cruise_speed:g} m/s, "
                 f"{a.sensors} sensors" + (f", {a.matcher}" if a.matcher != "viterbi" else "") + _velocity_note(a),
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(RESULTS / f"gravity_live_{a.name}_error.png", dpi=110)
    plt.close(fig)
    return 0 if all(valid.values()) else 3


if __name__ == "__main__":
    raise SystemExit(main())
