"""The one-page summary that opens BENCHMARKS.md: per benchmark what it measures, its headline, whether its target is
met, and links to its section and plots.

Every headline is read from the results file its benchmark wrote (replay/results/*.md), so the summary changes when
a benchmark is rerun; nothing here is a measured number. A headline that can no longer be found (the file's format
changed) says so in the summary, and tests/test_docs.py fails on it.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

MAX_PLOTS = 2  # per row; the rest are listed under "Plots" at the end
MISSING = "headline not found in the results file (its format changed?)"


@dataclass(frozen=True)
class Headline:
    text: str
    target: str = "—"  # "met", "**not met**", "k of n met", or "—" (no target)


class NotFound(LookupError):
    pass


def sections(text: str, level: int = 2) -> dict[str, str]:
    """Heading text -> the text under it, up to the next heading of that level or higher."""
    out: dict[str, str] = {}
    parts = re.split(rf"^(#{{1,{level}}} .*)$", text, flags=re.M)
    for head, body in zip(parts[1::2], parts[2::2]):
        out[head.lstrip("#").strip()] = body
    return out


def section(text: str, start: str, level: int = 2) -> str:
    for head, body in sections(text, level).items():
        if head.startswith(start):
            return body
    raise NotFound(f"no section starting {start!r}")


def tables(text: str) -> list[list[dict[str, str]]]:
    """Every markdown table in ``text`` as a list of rows (header -> cell)."""
    out = []
    lines = text.splitlines()
    i = 0
    while i + 1 < len(lines):
        if lines[i].startswith("|") and re.match(r"^\|[\s:|-]+\|$", lines[i + 1].strip()):
            head = _cells(lines[i])
            rows = []
            i += 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(dict(zip(head, _cells(lines[i]))))
                i += 1
            out.append(rows)
        else:
            i += 1
    return out


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def row(text: str, first_cell: str, column: str) -> str:
    """The cell under ``column`` of the first table row whose first cell starts with ``first_cell``."""
    for tab in tables(text):
        for r in tab:
            if r and next(iter(r.values())).startswith(first_cell) and column in r:
                return r[column]
    raise NotFound(f"no row {first_cell!r} with a column {column!r}")


def number(s: str) -> float:
    m = re.search(r"-?\d[\d,]*(?:\.\d+)?", s)
    if not m:
        raise NotFound(f"no number in {s!r}")
    return float(m.group(0).replace(",", ""))


def find(pattern: str, text: str) -> re.Match:
    m = re.search(pattern, text, re.M)
    if not m:
        raise NotFound(f"no match for {pattern!r}")
    return m


def met(ok: bool) -> str:
    return "met" if ok else "**not met**"


def km(m: float) -> str:
    return f"{m / 1000:.1f} km" if m >= 1000 else f"{m:.0f} m"


# --- one headline per results file --------------------------------------------------------------------------------

def _install(t: str) -> Headline:
    s = section(t, "Core install")
    mb = number(row(s, "./dev.sh setup", "packages MB"))
    ver = number(row(s, "./dev.sh setup", "`companion --version` CPU s"))
    m = find(r"Targets: <= (\d+) MB, `companion --version` <= ([\d.]+) s", s)
    return Headline(f"core install {mb:.0f} MB; `companion --version` {ver:.2f} s CPU",
                    met(mb <= float(m[1]) and ver <= float(m[2])))


def _ingest(t: str) -> Headline:
    s = section(t, "Speed against pymavlink")
    m = find(r"Targets: ratio >= ([\d.]+) and >= (\d+)x real time", s)
    rows = tables(s)[0]
    xrt = [number(r["x real time"]) for r in rows]
    ratio = [number(r["ratio"]) for r in rows]
    rss = number(find(r"Peak RSS of the long replay / the 5 min one: ([\d.]+)", t)[1])
    fast = sum(x >= float(m[2]) for x in xrt)
    return Headline(f"replay with navigator and record {min(xrt):.0f}-{max(xrt):.0f}x real time ({fast} of {len(xrt)} "
                    f"logs >= {m[2]}x); {min(ratio):.2f}-{max(ratio):.2f} x the speed of pymavlink's bare parse "
                    f"(CPU time; "
                    f"target >= {m[1]}); memory of a 3 h replay {rss:.2f} x a 5 min one (target <= 1.2)",
                    f"speed {met(fast == len(xrt) and min(ratio) >= float(m[1]))}, memory {met(rss <= 1.2)}")


def _gap_filling(t: str) -> Headline:
    fill = find(r"in-between fill H RMSE ([\d.]+) m \(target <= ([\d.]+) m\)", t)
    blk = find(r"8 s blockage H RMSE ([\d.]+) m \(target <= ([\d.]+) m\)", t)
    interval = row(section(t, "How far each figure rests", 3), "8", "90 % interval")
    ins = number(row(section(t, "8 s blockage", 3), "INS alone", "H RMSE m"))
    beats = re.findall(r"^- [\d.]+ s: KNN\+INS\+KF H RMSE [\d.]+ m (beats|does NOT beat) the best baseline", t, re.M)
    return Headline(f"8 s blockage {blk[1]} m RMSE (90 % interval {interval} m; INS alone {ins:.2f} m); between 1 Hz "
                    f"fixes {fill[1]} m; beats every baseline at {beats.count('beats')} of {len(beats)} blockage "
                    f"lengths",
                    f"8 s <= {blk[2]} m {met(float(blk[1]) <= float(blk[2]))}; fill <= {fill[2]} m "
                    f"{met(float(fill[1]) <= float(fill[2]))}")


def _live(t: str) -> Headline:
    idle, stress = section(t, "No load added"), section(t, "With `stress-ng")
    p99 = number(row(idle, "latency all", "value").split("p99")[1])
    cpu = number(row(idle, "CPU of the companion", "value"))
    p99_s = number(row(stress, "latency all", "value").split("p99")[1])
    cpu_s = number(row(stress, "CPU of the companion", "value"))
    t99 = number(row(idle, "latency all", "target").split("<=")[1])
    t99_s = number(row(stress, "latency all", "target").split("<=")[1])
    tcpu = number(row(idle, "CPU of the companion", "target").split("<=")[1])
    tcpu_s = number(row(stress, "CPU of the companion", "target").split("<=")[1])
    return Headline(f"GPS_INPUT latency p99 {p99:g} ms, CPU {cpu:g} % of a core (target {tcpu:g} %); beside "
                    f"`stress-ng --cpu 2`: p99 {p99_s:g} ms, {cpu_s:g} %",
                    met(p99 <= t99 and p99_s <= t99_s and cpu <= tcpu and cpu_s <= tcpu_s))


def _yes_no(t: str) -> Headline:
    """The summary table's bold verdicts (Gao, Wu) and the notes' "Target met" / "Target not met" (Li, Liu)."""
    yes = len(re.findall(r"\*\*Yes", t)) + len(re.findall(r"\bTarget met\b", t))
    no = len(re.findall(r"\*\*No\b", t)) + len(re.findall(r"\bTarget not met\b", t))
    if not yes + no:
        raise NotFound("no verdicts")
    return Headline(f"the papers' designs on our 2' altimetry grids: {yes} of {yes + no} of their targets met (each "
                    f"paper's numbers beside ours; the notes say why they differ)", f"{yes} of {yes + no} met")


def _speed(t: str) -> Headline:
    ok = n = 0
    for tab in tables(t):
        for r in tab:
            value = r.get("median ms", r.get("measured", ""))
            try:
                target, v = number(r.get("target", "")), number(value)
            except NotFound:
                continue
            n += 1
            ok += v <= target
    if not n:
        raise NotFound("no timed row with a target")
    return Headline(f"{ok} of {n} matchers and filters within their time budget on one core", f"{ok} of {n} met")


def _marine(t: str) -> Headline:
    s = section(t, "Targets", 3)
    ak = row(s, "ship 8 m/s, 2' map (AK): aided mean <= 0.5", "measured")
    tas = row(s, "ship 8 m/s, 2' map (Tasman): aided mean <= 0.5", "measured")
    verdicts = [r.get("", "") for tab in tables(s) for r in tab]
    ok = sum(v.startswith("met") for v in verdicts)
    return Headline(f"ship, 3 h without GNSS: aided / INS-alone mean error {number(ak):g} (AK) / {number(tas):g} "
                    f"(Tasman) (target 0.5)", f"{ok} of {len(verdicts)} met")


def _long_denial(t: str) -> Headline:
    aided, ins = (number(row(t, r, "mean after the cut")) for r in ("aided", "ins"))
    extra = ""
    for col in ("error <= 2 h_acc", "error <= h_acc"):
        try:
            extra = f"; {row(t, 'aided', col)} of errors {col[6:]}"
            break
        except NotFound:
            continue
    try:
        last = row(t, "aided", "last GPS_INPUT, min after the cut")
        extra += f"; GPS_INPUT sent until minute {last}"
    except NotFound:
        pass
    return Headline(f"mean error after the cut {km(aided)} gravity-aided, {km(ins)} INS alone{extra}")


def _fuzz(t: str) -> Headline:
    out = []
    for head, body in sections(t).items():
        if not head.startswith("After"):
            continue
        try:
            out.append((head, row(body, "**all**", "ok"), row(body, "**all**", "mutants")))
        except NotFound:
            rows = [r for tab in tables(body) for r in tab if "ok" in r]
            if rows:
                out.append((head, str(sum(r["ok"] == "yes" for r in rows)), str(len(rows))))
    if not out:
        raise NotFound("no 'After' section with outcomes")
    parts = [f"{ok} of {n} {'live-link scenarios' if 'live' in head else 'mutated logs'} ok" for head, ok, n in out]
    good = sum(ok == n for _, ok, n in out)
    return Headline("; ".join(parts) + " (exit code, no traceback, bounded time and memory, a readable record)",
                    f"every input handled: {good} of {len(out)} runs")


def _newest_block(t: str) -> str:
    """The results block whose campaign started last (a results file keeps one block per campaign tag)."""
    blocks = re.findall(r"<!-- BEGIN (\S+) -->(.*?)<!-- END \1 -->", t, re.S)
    dated = [(m.group(1), body) for _k, body in blocks if (m := re.search(r"Started (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d)", body))]
    return max(dated)[1] if dated else t


def _sitl(t: str) -> Headline:
    t = _newest_block(t)
    errs = re.findall(r"^- \S+-deny-(\d+)\S* run \d+ \w+: took over; no failsafe: (\w+), "
                      r"EKF error <= ([\d.]+) m at every 5 s mark "
                      r"\(target <= ([\d.]+) m, no failsafe: (NOT met|met)\)", t, re.M)
    longer = re.findall(r"took over; flew on ([\d.]+) s of the (\d+) s denial, <= ([\d.]+) m to \+\d+ s "
                        r"\(target (>= \d+ s at <= [\d.]+ m): (NOT met|met)\)", t)
    honest = re.findall(r"3D fixes sent within 2x their h_acc \(target >= 95 %: (NOT met|met)\)", t)
    if not errs or not honest:
        raise NotFound("no takeover or honesty lines in 'Against the targets'")
    lengths = "/".join(sorted({e[0] for e in errs}, key=int))
    flew = sum(e[1] == "yes" for e in errs)
    worst = max(float(e[2]) for e in errs)
    ok = sum(e[4] == "met" for e in errs)
    fine = sum(h == "met" for h in honest)
    alone = [number(r["EKF failsafe (+s)"]) for tab in tables(t) for r in tab
             if r.get("arm") == "ArduPilot alone" and "EKF failsafe (+s)" in r]
    if not alone:
        raise NotFound("no EKF failsafe times of ArduPilot alone")
    text = (f"ArduPilot alone: EKF failsafe {min(alone):g}-{max(alone):g} s into the outage. With the companion, "
            f"{lengths} s outages: {flew} of {len(errs)} takeover flights flew on without a failsafe, EKF error up "
            f"to {worst:g} m")
    target = f"<= {errs[0][3]} m: {ok} of {len(errs)} met"
    if longer:
        flown = [float(x[0]) for x in longer]
        text += f"; {longer[0][1]} s outages: flew on {min(flown):g}-{max(flown):g} s"
        target += f"; {longer[0][3]}: {sum(x[4] == 'met' for x in longer)} of {len(longer)} met"
    return Headline(text + f"; its 3D fixes within 2x their stated accuracy in {fine} of {len(honest)} flights",
                    target + f"; honesty: {fine} of {len(honest)} met")


def _sitl_gravity(t: str) -> Headline:
    """replay.live.sitl_gravity's results: the EKF error of ArduPilot alone and with the companion over the denial,
    and its verdicts ("target ...: met" / "MISSED ...")."""
    alone, comp = (row(t, arm, "mean") for arm in ("alone", "companion"))
    if "the run is INVALID" in t:
        return Headline(f"EKF error over the GNSS denial, mean: {comp} m with the companion, {alone} m alone "
                        "(an arm did not keep up)", "run invalid: not judged")
    verdicts = re.findall(r"^- .*; target [^:]+: (met|MISSED)", t, re.M)
    if not verdicts:
        raise NotFound("no verdicts under 'Against the targets'")
    ok = verdicts.count("met")
    return Headline(f"EKF error over the GNSS denial, mean: {comp} m with the companion's gravity aiding, {alone} m "
                    f"ArduPilot alone", f"{ok} of {len(verdicts)} met")


def _paper(t: str) -> Headline:
    return Headline("judged in the reproductions' summary (gravity_summary)")


@dataclass(frozen=True)
class Entry:
    what: str
    headline: Callable[[str], Headline]


ENTRIES: dict[str, Entry] = {
    "install.md": Entry("size of the core install and start-up CPU time", _install),
    "ingest.md": Entry("replay speed against pymavlink's own parse, memory over flight length, start-up", _ingest),
    "gap_filling.md": Entry("the navigator's error on the real logs with GNSS blocked 1-30 s, against hold, constant "
                            "velocity, the KNN predictor and the INS alone", _gap_filling),
    "live.md": Entry("`companion run` against a simulated vehicle: GPS_INPUT latency, CPU, memory", _live),
    "gravity_summary.md": Entry("four gravity-matching papers reproduced on real gravity grids", _yes_no),
    "gravity_gao.md": Entry("Gao et al. 2022: KNN, MSD and ICCP matching, Monte Carlo on four areas", _paper),
    "gravity_wu.md": Entry("Wu et al. 2015: RPCM and TERCOM pattern matching", _paper),
    "gravity_li.md": Entry("Li et al. 2022: Viterbi map matching (RVBMP), fusion into a Kalman filter", _paper),
    "gravity_liu.md": Entry("Liu et al. 2019: gravity-gradient particle filters", _paper),
    "gravity_speed.md": Entry("CPU time per match of every gravity matcher and filter", _speed),
    "gravity_marine.md": Entry("the sequential gravity filter offline: ship and aircraft, 3 h, held-out runs",
                               _marine),
    "gravity_live_aircraft.md": Entry("gravity-aided aircraft, 150 m/s, 3 h, GNSS cut after 20 min (live)",
                                      _long_denial),
    "gravity_live_drone.md": Entry("the same with a drone's MEMS IMU (live)", _long_denial),
    "gravity_live_ship.md": Entry("gravity-aided ship, 8 m/s, the Viterbi window matcher (live)", _long_denial),
    "gravity_live_ship_sequential.md": Entry("gravity-aided ship, 8 m/s, the sequential filter (live)", _long_denial),
    "gravity_live_ship_sequential_vel.md": Entry("the same with velocity fixes (live)", _long_denial),
    "gravity_live_ship_s8_pos.md": Entry("the sequential filter, a second ship voyage (live)", _long_denial),
    "gravity_live_ship_s8_vel.md": Entry("the second voyage with velocity fixes (live)", _long_denial),
    "fuzz.md": Entry("mutated logs through `companion replay`, a hostile live link", _fuzz),
    "sitl_ab.md": Entry("ArduCopter SITL, GPS1 lost: ArduPilot alone against ArduPilot + the companion", _sitl),
}


#: results files named by a prefix (one per run of their benchmark)
PREFIXES: dict[str, Entry] = {
    "sitl_gravity_": Entry("ArduPlane / ArduRover SITL with GNSS denied for long: ArduPilot alone against ArduPilot + "
                           "the companion's sequential gravity filter", _sitl_gravity),
}


def entry_of(path: Path) -> Entry | None:
    if path.name in ENTRIES:
        return ENTRIES[path.name]
    return next((e for prefix, e in PREFIXES.items() if path.name.startswith(prefix)), None)


def headline(path: Path) -> Headline:
    entry = entry_of(path)
    if entry is None:
        return Headline("see the section")
    try:
        return entry.headline(path.read_text())
    except (NotFound, KeyError, IndexError, ValueError) as e:
        return Headline(f"{MISSING}: {e}")


def anchors(markdown: str, seen: dict[str, int] | None = None) -> list[str]:
    """The anchors GitHub gives the headings of ``markdown``, in order (a repeated one numbered -1, -2, ...);
    ``seen`` carries the count over from the text before it."""
    seen = {} if seen is None else seen
    out = []
    for line in re.sub(r"^```.*?^```", "", markdown, flags=re.M | re.S).splitlines():
        m = re.match(r"^#{1,6} +(.*?)\s*#*\s*$", line)
        if m:
            slug = re.sub(r"[^\w\- ]", "", m.group(1).lower()).replace(" ", "-")
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            out.append(slug if n == 0 else f"{slug}-{n}")
    return out


def summary(files: list[Path], title_of: Callable[[Path], str], anchor_of: Callable[[Path], str],
            plots_of: Callable[[Path], list[Path]]) -> str:
    """The summary table, one row per results file, in BENCHMARKS.md's order."""
    lines = ["## Summary\n",
             "One row per benchmark: what it measures, its headline and targets, read from the section it links "
             "(which states the command that reproduces it and where it ran).\n",
             "| benchmark | what it measures | headline | target | plots |", "|---|---|---|---|---|"]
    for p in files:
        h = headline(p)
        entry = entry_of(p)
        what = entry.what if entry else ""
        shown = plots_of(p)
        plots = ", ".join(f"[{q.stem}](replay/results/{q.name})" for q in shown[:MAX_PLOTS]) or "—"
        if len(shown) > MAX_PLOTS:
            plots += f", [{len(shown) - MAX_PLOTS} more](#plots)"
        title = title_of(p).replace("|", "/")
        lines.append(f"| [{title}](#{anchor_of(p)}) | {what} | {h.text} | {h.target} | {plots} |")
    return "\n".join(lines) + "\n"
