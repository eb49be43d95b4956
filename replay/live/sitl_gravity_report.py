"""The table and plot of the gravity-aided SITL A/B (replay.live.sitl_gravity) from its summary.json and flight logs,
with the issue's targets judged from the numbers (each verdict says by how much)."""

from __future__ import annotations

import math

from replay.harness.results import md_table

TARGETS = {"plane": {"ratio": 0.25, "mean_m": 1500.0}, "rover": {"ratio": 0.5, "mean_m": 3000.0}}


def _m(v, unit: str = "") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, float) and abs(v) >= 100:
        return f"{v:.0f}{unit}"
    return f"{v:.1f}{unit}" if isinstance(v, float) else f"{v}{unit}"


def table(summary: dict, vehicle: str) -> str:
    arms = summary["arms"]
    mins = sorted({int(k) for s in arms.values() for k in s["error_m_at_min"]})
    head = ["arm", "kept up"] + [f"{m} min" for m in mins] + ["mean", "max", "healthy mean", "cross-track mean / max",
                                                              "within 2x h_acc", "jump at return", "re-converged"]
    rows = []
    for name, s in arms.items():
        rows.append([name, "yes" if s["kept_up"] else "NO (invalid)"] + [_m(s["error_m_at_min"].get(str(m))) for m in mins]
                    + [_m(s["mean_m"]), _m(s["max_m"]), _m(s.get("healthy_mean_m")),
                       f"{_m(s.get('cross_track_mean_m'))} / {_m(s.get('cross_track_max_m'))}",
                       "-" if s.get("within_2hacc_frac") is None else f"{s['within_2hacc_frac']:.0%} of {s.get('fixes_in_denial', 0)}",
                       _m(s.get("return_jump_m")), _m(s.get("reconverge_s"), " s")])
    out = ["EKF horizontal error vs SITL truth (m), minutes into the GNSS denial:", "", md_table(head, rows), ""]
    for name, s in arms.items():
        fs = "; ".join(f"{m:+.1f} min {t}" for m, t in s["failsafes"]) or "none"
        out.append(f"- {name}: mode changes and failsafe messages after the survey start: {fs}")
        ah = "; ".join(f"{m:+.1f} min {t}" for m, t in s.get("ahrs", [])) or "none"
        out.append(f"- {name}: AHRS messages after the survey start (which estimator flies the vehicle): {ah}")
    out += [""] + verdicts(summary, vehicle)
    return "\n".join(out)


def verdicts(summary: dict, vehicle: str) -> list[str]:
    arms = summary["arms"]
    if not {"alone", "companion"} <= set(arms):
        return []
    A, B = arms["alone"], arms["companion"]
    tg = TARGETS[vehicle]
    out = ["Against the targets:", ""]
    if not (A["kept_up"] and B["kept_up"]):
        out.append("- the run is INVALID (an arm did not keep up): no target is judged")
        return out
    for m in ("30", "60"):
        a, b = A["error_m_at_min"].get(m), B["error_m_at_min"].get(m)
        if a and b is not None:
            r = b / a
            out.append(f"- {m} min: companion {b:.0f} m = {r:.2f}x alone ({a:.0f} m); target <= {tg['ratio']}x: "
                       + ("met" if r <= tg["ratio"] else f"MISSED by {r - tg['ratio']:.2f}x ({b - tg['ratio'] * a:.0f} m)"))
    if B["mean_m"] is not None:
        ok = B["mean_m"] <= tg["mean_m"]
        out.append(f"- mean over the denial: {B['mean_m']:.0f} m; target <= {tg['mean_m']:.0f} m: "
                   + ("met" if ok else f"MISSED by {B['mean_m'] - tg['mean_m']:.0f} m"))
    extra = sorted({t for _m2, t in B["failsafes"]} - {t for _m2, t in A["failsafes"]})
    out.append("- failsafes / mode changes in the companion arm that alone did not have: " + (", ".join(extra) or "none"))
    if A.get("healthy_mean_m") and B.get("healthy_mean_m") is not None:
        r = B["healthy_mean_m"] / A["healthy_mean_m"]
        out.append(f"- healthy phase: {B['healthy_mean_m']:.2f} m = {r:.2f}x alone; target <= 1.1x: "
                   + ("met" if r <= 1.1 else f"MISSED by {r - 1.1:.2f}x"))
    w = B.get("within_2hacc_frac")
    if w is None:
        out.append("- fixes within 2x h_acc: the companion sent no 3D fix in the denial (nothing to judge; EKF3 "
                   "dead-reckoned as alone)")
    else:
        out.append(f"- fixes within 2x h_acc: {w:.0%}; target >= 90 %: " + ("met" if w >= 0.9 else f"MISSED by {0.9 - w:.0%}"))
    j, h = B.get("return_jump_m"), B.get("last_hacc_m")
    if j is not None and h is None:
        out.append(f"- GNSS return: jump {j:.0f} m with no companion fix standing (EKF3's own dead-reckoning error; "
                   f"alone: {_m(A.get('return_jump_m'), ' m')}): MISSED by {j:.0f} m")
    elif j is not None:
        ve, sa = B.get("last_vel_err_mps"), B.get("last_speed_acc_mps")
        out.append(f"- GNSS return: jump {j:.0f} m vs last stated h_acc {h:.0f} m: "
                   + ("met" if j <= h else f"MISSED by {j - h:.0f} m")
                   + (f" (the last fix's velocity, which EKF3 carries past the reset: {ve:.1f} m/s off, stated "
                      f"{_m(sa, ' m/s')})" if ve is not None else ""))
    rc, hw = B.get("reconverge_s"), B.get("healthy_wait_max_s")
    out.append(f"- back to alone's healthy error: {_m(rc, ' s')}; target <= 30 s: "
               + ("met" if rc is not None and rc <= 30 else "MISSED" + (f" by {rc - 30:.0f} s" if rc is not None else " (never)"))
               + (" (the same measure started anywhere in the companion's healthy phase waits at most "
                  f"{_m(hw, ' s')})" if "healthy_wait_max_s" in B else ""))
    return out


def plot(a, flown: dict, png) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import numpy as np

    from replay.live import sitl_core as core

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for name, c in (("alone", "tab:red"), ("companion", "tab:blue")):
        if name not in flown:
            continue
        log = flown[name]["log"]
        t, err = core.ekf_error(log)
        on = log.marks.get("deny_on")
        if on is None or len(t) == 0:
            continue
        sel = t >= log.marks.get("route", on)  # from the survey's start (before take-off EKF3 has no origin)
        ax.plot((t[sel] - on) / 60.0, np.maximum(err[sel], 0.1) / 1000.0, color=c, lw=0.8, label=f"{name}: EKF3 error")
    for name in flown:
        log = flown[name]["log"]
        if "deny_on" in log.marks and "deny_off" in log.marks:
            ax.axvspan(0.0, (log.marks["deny_off"] - log.marks["deny_on"]) / 60.0, color="0.9", zorder=0)
            break
    ax.set_xlabel("minutes after GNSS was denied (shaded: denial)")
    ax.set_ylabel("EKF horizontal error (km)")
    ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"ArduPilot {a.vehicle} SITL over {a.map_path.name} from {a.origin}, seed {a.seed}, x{a.speedup:g}",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def write_results(a, summary: dict, table_text: str, png, results_dir) -> None:
    """replay/results/sitl_gravity_NAME.md (+ its plot): the command, where and how it ran, the set-up, the table."""
    import shutil
    from pathlib import Path

    run = summary["run"]
    name = f"sitl_gravity_{a.results}"
    shutil.copyfile(png, Path(results_dir) / f"{name}.png")
    vehicle = "ArduPlane" if a.vehicle == "plane" else "ArduRover (motorboat)"
    lines = [
        f"# Gravity aiding on {vehicle} SITL: {Path(run['sitl']).name.split(' ')[0]} over {a.map_path.name} from "
        f"{a.origin}, seed {a.seed}",
        "",
        f"`nice -n 5 python -m replay.live.sitl_gravity {' '.join(run['argv'])}`",
        "",
        f"SITL {run['sitl']}, speed-up {run['speedup']:g}; started {run['started']}; machine before: "
        f"{run['load_before']}, after: {run['load_after']} (shared with other work). ArduPilot's defaults "
        f"{', '.join(Path(d).name for d in run['defaults'])}, then the harness's parameters, each read back from the "
        "autopilot before take-off:",
        "",
    ]
    for arm, params in run["params"].items():
        lines.append(f"- {arm}: " + ", ".join(f"{k}={v:g}" for k, v in params.items()))
    sv, sc = run["survey"], run["schedule"]
    lines += [
        f"- the companion: `companion run --inject inject --gps-id 1` with `--set {' '.join(run['companion_sets'])}`"
        if run["companion_sets"] else "",
        "",
        f"Mission: take-off, then {sv['lines']} lines of {sv['line_km']:g} km {sv['spacing_km']:g} km apart from "
        f"{a.origin} (first line heading {sv['heading_deg']:g} deg) at {sv['alt_m']:g} m, flown over and over; map "
        f"along the lines: STD {run['map_along_survey']['std_mgal']:.1f} mGal, mean gradient "
        f"{run['map_along_survey']['grad_mgal_per_km']:.2f} mGal/km. Schedule from the survey start: GNSS "
        f"{sc['healthy_min']:g} min, denied (SIM_GPS1_ENABLE 0) {sc['denial_min']:g} min, back {sc['back_min']:g} "
        + (f"min. Weather: SIM_WIND_SPD {sc['wind_mps']:g} m/s from {sc['wind_dir_deg']:g} deg, SIM_WIND_TURB "
           f"{sc['turb_mps']:g} m/s, the wind turning by {sc['wind_turn_deg']:g} deg every {sc['wind_turn_min']:g} "
           "min of the denial; SITL's airspeed sensor with its default noise." if a.vehicle != "rover" else
           "min. Water: " + (f"SITL's tide carries the boat (SIM_TIDE_SPEED {sc['current_mps']:g} m/s from "
                             f"{sc['current_dir_deg']:g} deg), turning by {sc['current_turn_deg']:g} deg every "
                             f"{sc['wind_turn_min']:g} min of the denial; the wind does not move a motorboat "
                             "(SIM_Sailboat without sail)" if sc.get("current_mps", 0.0) > 0 else
                             "still: SITL's motorboat is moved by neither wind (no sail) nor current (SIM_TIDE_SPEED "
                             "0)")
           + "; its speed log (companion.sim.speed_log, NAMED_VALUE_FLOAT WSPD on the gravimeter's link) reads the "
           "speed through the water with a seeded 1 % scale error, a 0.02 m/s bias and 0.05 m/s noise, 2 Hz.")
        + " Gravimeter (companion.sim.sitl_gravimeter_link, "
        "on SERIAL2, its NAMED_VALUE_FLOAT routed by the autopilot): the map at SITL's true position + the real "
        "ship-minus-satellite misfit + 1 mGal white noise + the Eotvos term at the true velocity + a seeded bias "
        "(2 mGal sigma) and drift (0.5 mGal/h sigma), filtered over 30 s, 1 Hz.",
        "",
        "Truth: SIMSTATE; EKF error: GLOBAL_POSITION_INT against the truth at its time. A run is valid only if the "
        "harness's truth stream has no gap over 2 s and the companion processed every input within "
        "inject.max_lag_s of its arrival (its `lag` summary line).",
        "",
        table_text,
        "",
        f"![EKF error over the flight]({name}.png)",
    ]
    (Path(results_dir) / f"{name}.md").write_text("\n".join(x for x in lines if x is not None) + "\n")
