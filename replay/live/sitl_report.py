"""Tables, verdicts and the plot of the SITL A/B harness (replay.live.sitl) from its analysed arms
(replay.live.sitl_core.ArmResult). Pure apart from the plot and ``write_results``, which writes replay/results."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from replay.live.sitl_core import MARK_STEP_S, OWN_MARKS, PHASES, SCENARIOS, ArmResult

ARM_NAMES = {"A": "ArduPilot alone", "AD": "alone, drag fusion + DR failsafe", "B": "+ companion (takeover)",
             "BD": "drag fusion + DR failsafe + companion"}
ARM_COLOURS = {"A": "tab:blue", "AD": "tab:green", "B": "tab:red", "BD": "tab:brown"}
COMPANION_ARMS = {"B": "A", "BD": "AD"}  # each companion arm and the arm it adds the companion to
LATLON_STEP_M = 0.011  # GLOBAL_POSITION_INT's lat/lon step (1e-7 deg) in metres
FAILSAFE_CHECK_S = 0.1  # ArduCopter's EKF failsafe check period


def _f(v: float, nd: int = 2) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.{nd}f}"


def _fixes(d: dict[int, int]) -> str:
    return " ".join(f"{k}:{v}" for k, v in d.items()) if d else "—"


def md(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def _run(r: ArmResult) -> str:
    return str(r.run)


def phase_table(results: list[ArmResult]) -> str:
    rows = []
    for r in results:
        cells = [r.scenario, _run(r), ARM_NAMES.get(r.arm, r.arm), "yes" if r.armed else "NO"]
        for p in PHASES:
            s = r.phases.get(p)
            cells.append(f"{_f(s[0])} / {_f(s[1])}" if s else "")
        cells += [_f(r.failsafe_s, 1), _f(r.dead_reckoning_s, 1), _f(r.left_guided_s, 1)]
        rows.append(cells)
    return md(["scenario", "run", "arm", "armed", "hover mean / max (m)", "route mean / max (m)",
               "denial mean / max (m)", "recovery mean / max (m)", "EKF failsafe (+s)", "dead reckoning (+s)",
               "left GUIDED (+s)"], rows)


def marks_table(results: list[ArmResult]) -> str:
    denied = [r for r in results if r.marks_err]
    if not denied:
        return ""
    n = max(len(r.marks_err) for r in denied)
    header = ["scenario", "run", "arm"] + [f"+{int(k * MARK_STEP_S)}" for k in range(n)]
    rows = []
    for r in denied:
        vals = [_f(e, 1) for _o, e in r.marks_err]
        rows.append([r.scenario, _run(r), r.arm] + vals + [""] * (n - len(vals)))
    return md(header, rows)


def events_lines(results: list[ArmResult]) -> str:
    lines = []
    for r in results:
        if r.events:
            ev = "; ".join(f"+{t:.1f} s {txt}" for t, txt in r.events[:8])
            lines.append(f"- {r.scenario} run {_run(r)} {r.arm}: {ev}")
    return "\n".join(lines)


def companion_table(results: list[ArmResult]) -> str:
    rows = []
    for r in results:
        if r.arm not in COMPANION_ARMS:
            continue
        tr = r.trust
        trust = (f"{'fit' if tr.get('fit') else 'unfit'}: heading sigma {_f(math.degrees(tr['yaw_sigma_rad']), 1)} deg, "
                 f"manoeuvres {_f(tr.get('manoeuvre_mps'), 1)} m/s" if tr and tr.get("yaw_sigma_rad") is not None
                 else "—")
        rows.append([r.scenario, _run(r), r.arm, r.takeover or "—", trust, _fixes(r.sent_fix), _fixes(r.gps2_fix_denial),
                     _f(r.own_healthy_mean)] + [_f(r.own_err_at.get(o, math.nan), 1) for o in OWN_MARKS]
                    + [f"{_f(100 * r.within_2hacc, 1)} % of {r.fixes_with_hacc}", _f(r.last_hacc_m, 1),
                       _f(r.return_jump_m, 2), kept_up(r)])
    if not rows:
        return ""
    return md(["scenario", "run", "arm", "decision at the loss", "trust at the loss", "fix types sent (type:count)",
               "GPS2_RAW during denial", "own error before denial, mean (m)"]
              + [f"own error +{int(o)} s (m)" for o in OWN_MARKS]
              + ["3D fixes within 2x h_acc", "h_acc standing at GPS1's return (m)", "EKF jump at GPS1 back (m)",
                 "kept up (IMU samples coalesced)"], rows)


#: a companion that coalesced more IMU samples than this (1 s at 50 Hz) fell behind its link: its run is not valid
MAX_COALESCED = 50


def kept_up(r: ArmResult) -> str:
    n = r.imu_coalesced[0]
    return f"{'yes' if n <= MAX_COALESCED else 'NO'} ({n})"


def lag_table(results: list[ArmResult]) -> str:
    rows = [[r.scenario, _run(r), ARM_NAMES.get(r.arm, r.arm), _f(r.ekf_lag_s), _f(r.ekf_lag_err),
             _f(r.own_lag_s) if r.arm in COMPANION_ARMS else "", _f(r.own_lag_err) if r.arm in COMPANION_ARMS else ""]
            for r in results if math.isfinite(r.ekf_lag_s)]
    if not rows:
        return ""
    return md(["scenario", "run", "arm", "EKF delay vs truth (s)", "EKF error at that delay (m)",
               "GPS_INPUT delay vs its time_usec (s)", "GPS_INPUT error at that delay (m)"], rows)


def arming_lines(results: list[ArmResult]) -> str:
    lines = []
    for r in results:
        ref = "; ".join(r.refusals[:4]) if r.refusals else "none"
        lines.append(f"- {r.scenario} run {_run(r)} {r.arm}: armed {'yes' if r.armed else 'NO'} "
                     f"(boot +{_f(r.arm_time_s, 1)} s); refusals seen: {ref}" + (f"; {'; '.join(r.notes)}" if r.notes else ""))
    return "\n".join(lines)


# -- verdicts against the targets ---------------------------------------------------------------------------------------
def _denial_marks(r: ArmResult) -> list[tuple[float, float]]:
    d = SCENARIOS[r.scenario].deny_s if r.scenario in SCENARIOS else math.inf
    return [(o, e) for o, e in r.marks_err if o <= d + 1e-9]


def _takes_over(r: ArmResult) -> bool:
    return r.takeover.startswith("takeover")


def ab_verdicts(results: list[ArmResult]) -> list[str]:
    """The targets, per scenario, run and companion arm: healthy flight, the denial after a manoeuvre, the denial where
    the companion stays out, honesty of the stated accuracy, the return of GNSS; against ArduPilot alone (A) and alone
    at its best (AD)."""
    by = {(r.scenario, _run(r), r.arm): r for r in results}
    out: list[str] = []
    pooled: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for (sc, run, arm), b in sorted(by.items()):
        if arm not in COMPANION_ARMS:
            continue
        who = f"{sc} run {run} {arm}"
        for ref in ("A", "AD"):
            a = by.get((sc, run, ref))
            if a is None:
                continue
            for p in ("hover", "route"):
                if p in a.phases and p in b.phases and math.isfinite(a.phases[p][0]) and math.isfinite(b.phases[p][0]):
                    pooled[f"{p} {arm}/{ref}"].append((a.phases[p][0], b.phases[p][0]))
            if not (a.marks_err and b.marks_err):
                continue
            pairs = list(zip(_denial_marks(a), _denial_marks(b)))
            worse = [(o, eb - ea) for (o, ea), (_o, eb) in pairs if math.isfinite(ea) and math.isfinite(eb) and eb > ea + 0.5]
            worst = (f" (worst +{int(max(worse, key=lambda w: w[1])[0])} s: +{max(w[1] for w in worse):.1f} m)"
                     if worse else "")
            if _takes_over(b):
                better = [o for (o, ea), (_o, eb) in pairs if math.isfinite(ea) and math.isfinite(eb) and eb < ea - 0.5]
                out.append(f"- {who} vs {ref}: better by > 0.5 m at {len(better)} of {len(pairs)} denial marks, worse at "
                           f"{len(worse)}{worst}; left GUIDED: {arm} {_f(b.left_guided_s, 1)} s, {ref} "
                           f"{_f(a.left_guided_s, 1)} s")
            elif ref == COMPANION_ARMS[arm]:  # staying out, it must be its own base arm, so only that one is compared
                late = (math.isfinite(b.failsafe_s) and math.isfinite(a.failsafe_s)
                        and b.failsafe_s > a.failsafe_s + FAILSAFE_CHECK_S)
                out.append(f"- {who}, companion stayed out ({b.takeover or 'no decision recorded'}), vs {ref}: marks "
                           f"worse by > 0.5 m: {len(worse)} of {len(pairs)}{worst}; EKF failsafe {arm} "
                           f"{_f(b.failsafe_s, 1)} s vs {ref} {_f(a.failsafe_s, 1)} s"
                           + (" (later: NOT met)" if late else " (met)" if not worse else " (NOT met)"))
        if _takes_over(b) and b.marks_err:
            d = SCENARIOS[sc].deny_s if sc in SCENARIOS else math.inf
            marks = _denial_marks(b)
            if d <= 30:
                worst_m = max((e for _o, e in marks if math.isfinite(e)), default=math.nan)
                ok = not math.isfinite(b.left_guided_s) and worst_m <= 3.0
                out.append(f"- {who}: took over; no failsafe: {'yes' if not math.isfinite(b.left_guided_s) else 'NO'}, "
                           f"EKF error <= {_f(worst_m, 1)} m at every 5 s mark (target <= 3 m, no failsafe: "
                           f"{'met' if ok else 'NOT met'})")
            else:
                flew = b.left_guided_s if math.isfinite(b.left_guided_s) else d
                worst45 = max((e for o, e in marks if o <= 45.0 and math.isfinite(e)), default=math.nan)
                ok = flew >= 45.0 and worst45 <= 5.0
                out.append(f"- {who}: took over; flew on {_f(flew, 1)} s of the {d:g} s denial, <= "
                           f"{_f(worst45, 1)} m to +45 s (target >= 45 s at <= 5 m: {'met' if ok else 'NOT met'})")
        if b.fixes_with_hacc:
            out.append(f"- {who}: {100 * b.within_2hacc:.1f} % of {b.fixes_with_hacc} 3D fixes sent within 2x "
                       f"their h_acc (target >= 95 %: {'met' if b.within_2hacc >= 0.95 else 'NOT met'})")
        if math.isfinite(b.return_jump_m) and math.isfinite(b.last_hacc_m) and _takes_over(b):
            out.append(f"- {who}: EKF jump at GPS1's return {b.return_jump_m:.2f} m, last stated h_acc "
                       f"{b.last_hacc_m:.1f} m ({'met' if b.return_jump_m <= b.last_hacc_m else 'NOT met'})")
    for key, pairs in sorted(pooled.items()):
        ma, mb = (float(np.mean(x)) for x in zip(*pairs))
        ratio = mb / max(ma, 1e-6)
        verdict = "met" if ratio <= 1.1 or mb - ma < LATLON_STEP_M else "NOT met"
        out.append(f"- healthy flight, {len(pairs)} flights pooled, {key}: mean EKF error {ratio:.2f}x ({mb:.3f} vs "
                   f"{ma:.3f} m; target <= 1.1x: {verdict})")
    return out


# -- the plot -------------------------------------------------------------------------------------------------------
def plot(results: list[ArmResult], path: Path) -> None:
    """One panel per scenario (its first run; the others are in the tables): every arm's EKF error after the loss,
    the companion's 3D fixes' own error and twice their stated h_acc, and when each arm left its route."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    denied = [r for r in results if math.isfinite(r.deny_on)]
    scen = list(dict.fromkeys(r.scenario for r in denied))
    if not scen:
        return
    cols = min(3, len(scen))
    rows = math.ceil(len(scen) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.ravel()[len(scen):]:
        ax.axis("off")
    handles = {}
    for ax, sc in zip(axes.ravel(), scen):
        first = min(r.run for r in denied if r.scenario == sc)
        d = SCENARIOS[sc].deny_s
        ax.axvspan(0, d, color="0.92")
        x0, x1 = -10.0, d + SCENARIOS[sc].recover_s
        for r in (x for x in denied if x.scenario == sc and x.run == first):
            col = ARM_COLOURS.get(r.arm, "k")
            tx = r.t_err - r.deny_on
            handles[r.arm] = ax.plot(tx, r.err, color=col, lw=1.2)[0]
            if math.isfinite(r.left_guided_s):
                ax.axvline(r.left_guided_s, color=col, ls=":", lw=1.2)
            if r.arm in COMPANION_ARMS and len(r.own_t):
                ox = r.own_t - r.deny_on
                used = r.own_fix >= 3
                handles[f"own {r.arm}"] = ax.plot(ox[used], r.own_err[used], ".", color=col, ms=1.5, alpha=0.5)[0]
                if r.arm == "B":
                    handles["2h"] = ax.plot(ox[used], 2 * r.own_hacc[used], ".", color="tab:purple", ms=1)[0]
        ax.set_xlim(x0, x1)
        ax.set_ylim(0, 30.0)
        ax.set_title(f"{sc} (denied {d:g} s, shaded)", fontsize=9)
        ax.set_xlabel("time since GPS1 denied (s)", fontsize=8)
        ax.set_ylabel("horizontal error (m)", fontsize=8)
        ax.grid(alpha=0.3)
    labels = {**{k: f"EKF, {v}" for k, v in ARM_NAMES.items()},
              **{f"own {k}": f"companion's 3D fixes sent ({k})" for k in COMPANION_ARMS},
              "2h": "2x their stated h_acc (B)"}
    keys = [k for k in labels if k in handles]
    fig.legend([handles[k] for k in keys], [labels[k] for k in keys], loc="lower center", ncol=4, fontsize=8,
               title="dotted vertical line: the arm left its route (failsafe mode change); errors above 30 m clipped",
               title_fontsize=8)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)
