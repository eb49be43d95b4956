"""The documentation is navigable and the code is not a lab notebook.

- Every relative link in README.md, BENCHMARKS.md and docs/ reaches a file, and its #anchor a heading there.
- README.md stays a front page (<= 200 lines); BENCHMARKS.md opens with its summary, current with the results.
- Docstrings and comments in companion/ say what the code does and why, in a few lines: beside
  tests/test_layout.py's lab-notebook check (a page-long docstring, the shared logs' names, pooled or held-out
  scores, before -> after numbers), no class or function docstring over half a page, no results table, seed or
  value's history ("was 789 m") and no stale qualifier (those go to docs/decisions/, linked from the setting).
"""

from __future__ import annotations

import ast
import io
import re
import subprocess
import sys
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 200
DOCSTRING_MAX_LINES = 25  # a class's or function's: what it does and why (a module's design notes: test_layout.py)

_LINK = re.compile(r"(?<!\!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
_FENCE = re.compile(r"^```.*?^```", re.M | re.S)
_CODE = re.compile(r"`[^`\n]*`")


def doc_files() -> list[Path]:
    return [ROOT / "README.md", ROOT / "BENCHMARKS.md", *sorted((ROOT / "docs").rglob("*.md"))]


def github_anchors(markdown: str) -> dict[str, str]:
    """The anchors GitHub gives the headings of a markdown text (lower case, punctuation dropped, spaces to '-',
    a repeated one numbered -1, -2, ...), each with its heading's text."""
    seen: dict[str, int] = {}
    out = {}
    for line in _FENCE.sub("", markdown).splitlines():
        m = re.match(r"^#{1,6} +(.*?)\s*#*\s*$", line)
        if not m:
            continue
        text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", m.group(1))  # a link's text only
        slug = re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out[slug if n == 0 else f"{slug}-{n}"] = text
    return out


def links(path: Path) -> list[str]:
    text = _CODE.sub("", _FENCE.sub("", path.read_text()))
    return [a or b for a, b in _LINK.findall(text)]


def broken_links(path: Path) -> list[str]:
    bad = []
    for target in links(path):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in github_anchors(dest.read_text()):
            bad.append(f"{target}: no heading #{anchor} in {dest.relative_to(ROOT)}")
    return bad


@pytest.mark.parametrize("path", doc_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_links_resolve(path: Path):
    assert broken_links(path) == []


def test_anchor_rules():
    anchors = github_anchors("# A: b (`c` + `d`), 8 m/s\n## Plots\n## Plots\n```\n# not a heading\n```\n")
    assert set(anchors) == {"a-b-c--d-8-ms", "plots", "plots-1"}


def test_readme_is_a_front_page():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= README_MAX_LINES
    top = text.split("\n## ")[0]  # the two commands before the first section
    assert "./dev.sh replay" in top and "./dev.sh test" in top


def _section_text(markdown: str, anchor: str) -> str:
    """The text under the heading with this anchor, up to the next heading of its level or higher."""
    lines = _FENCE.sub("", markdown).splitlines()
    seen: dict[str, int] = {}
    start = level = None
    for i, line in enumerate(lines):
        m = re.match(r"^(#{1,6}) +(.*?)\s*#*\s*$", line)
        if not m:
            continue
        if start is not None and len(m.group(1)) <= level:
            return "\n".join(lines[start:i])
        slug = re.sub(r"[^\w\- ]", "", m.group(2).lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        if start is None and (slug if n == 0 else f"{slug}-{n}") == anchor:
            start, level = i, len(m.group(1))
    assert start is not None, anchor
    return "\n".join(lines[start:])


def _found(token: str, unit: str, numbers: list[float]) -> bool:
    """A number as the README prints it (its decimals, km for metres) is one of the section's."""
    x = float(token)
    tol = 0.5 * 10 ** -len(token.partition(".")[2]) + 1e-9
    scale = 1000.0 if unit == "km" else 1.0
    return any(abs(y - x) <= tol or abs(y / scale - x) <= tol for y in numbers)


def test_readme_results_are_those_of_the_linked_sections():
    """Every number in the README's results table (the measured column) is in the BENCHMARKS.md section its row
    links: a rerun benchmark whose numbers moved makes the README say so here."""
    readme, bench = (ROOT / "README.md").read_text(), (ROOT / "BENCHMARKS.md").read_text()
    table = readme.split("\n## Results")[1].split("\n## ")[0]
    rows = [_cells(line) for line in table.splitlines() if line.startswith("| ") and "BENCHMARKS.md#" in line]
    assert len(rows) >= 5
    missing = []
    for _what, measured, _target, links_cell in rows:
        anchor = re.search(r"BENCHMARKS\.md#([^)]+)\)", links_cell).group(1)
        numbers = [float(n) for n in re.findall(r"\d+(?:\.\d+)?", _section_text(bench, anchor).replace(",", ""))]
        for m in re.finditer(r"(\d+(?:\.\d+)?)\s*(km)?", measured.replace("`companion --version`", "")):
            if not _found(m.group(1), m.group(2) or "", numbers):
                missing.append(f"{m.group(0)} not in #{anchor}")
    assert missing == []


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_decision_records_are_listed():
    index = (ROOT / "docs" / "decisions" / "README.md").read_text()
    assert sorted(re.findall(r"\]\((\d{4}-[a-z0-9-]+\.md)\)", index)) == sorted(
        p.name for p in (ROOT / "docs" / "decisions").glob("[0-9]*.md"))


@pytest.mark.parametrize("path", sorted((ROOT / "docs" / "decisions").glob("[0-9]*.md")), ids=lambda p: p.name)
def test_decision_records_say_question_command_measured_chosen(path: Path):
    """A decision record: its question, what was measured with the command that measures it, what was chosen; and
    the code links it from the setting it decided."""
    text = path.read_text()
    assert re.match(r"\d{4}-[a-z0-9-]+\.md$", path.name) and text.startswith(f"# {path.name[:4]} ")
    for heading in ("## The question", "## What was measured", "## What was chosen"):
        assert f"\n{heading}" in text, heading
    measured = text.split("## What was measured")[1].split("## What was chosen")[0]
    assert "python -m " in measured or "pytest" in measured or "tests/" in measured, "no command"
    code = "\n".join(p.read_text() for p in [*_code_files(), *sorted((ROOT / "replay").rglob("*.py"))])
    assert f"docs/decisions/{path.name[:4]}" in code, "not linked from companion/ or replay/ (a benchmark's measure)"


#: a sentence about the past, not the present: how a number used to be, or a result that no longer matches the code
#: a value's history: "was 789 m", "were 4.5 km" (a number with its unit; "the fix was 3D" is a state, not a history)
_WAS = r"\b(?:was|were) \d[\d.,]*\s*(?:m|km|s|ms|us|%|mgal|m/s|mib|mb)(?![\w/])"
STALE = re.compile(_WAS + r"|\bnot rerun\b|\bpredate|\bbefore (?:that|this|the) change\b|\bmeasured on 20\d\d-",
                   re.I)


@pytest.mark.parametrize("path", [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_docs_are_current(path: Path):
    """README and the topic pages state what is true now (history belongs to docs/decisions/, git and CHANGELOG)."""
    assert [line for line in path.read_text().splitlines() if STALE.search(line)] == []


def test_benchmarks_open_with_a_current_summary():
    """BENCHMARKS.md is what `python -m replay.collect_benchmarks` writes from replay/results/ now; its summary comes
    first, has one row per results file, each linking the section of that title, and every headline was found."""
    from replay import benchmark_summary, collect_benchmarks

    text = (ROOT / "BENCHMARKS.md").read_text()
    check = subprocess.run([sys.executable, "-m", "replay.collect_benchmarks", "--check"], cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, "rerun `python -m replay.collect_benchmarks`: " + check.stdout + check.stderr
    summary = text.split("\n## ")[1]
    assert summary.startswith("Summary\n")
    assert benchmark_summary.MISSING not in summary
    heading_of = github_anchors(text)
    rows = re.findall(r"^\| \[(.+?)\]\(#([^)]+)\) \|", summary, re.M)
    results = sorted(p.name for p in collect_benchmarks.RESULTS.glob("*.md"))
    assert len(rows) == len(results) and len(summary.splitlines()) < 60
    for title, anchor in rows:
        assert heading_of.get(anchor, "").replace("`", "") == title.replace("`", ""), (title, anchor)


def test_the_summary_reads_a_headline_and_its_verdict(tmp_path):
    from replay.benchmark_summary import MISSING, Headline, _install, headline

    text = ("# Install\n\n## Core install\n\nTargets: <= 350 MB, `companion --version` <= 0.3 s CPU.\n\n"
            "| install | packages MB | `companion --version` CPU s |\n|---|---|---|\n"
            "| ./dev.sh setup (dialects in use) | 360 | 0.06 |\n")
    assert _install(text) == Headline("core install 360 MB; `companion --version` 0.06 s CPU", "**not met**")
    changed = tmp_path / "install.md"  # the results file's format changed: the summary says so
    changed.write_text(text.replace("packages MB", "MB"))
    assert headline(changed).text.startswith(MISSING)


def test_the_summary_reads_the_sitl_gravity_report(tmp_path):
    """The SITL gravity A/B's results file, as its report writes it, gives a headline and its verdicts."""
    from replay.benchmark_summary import headline
    from replay.live.sitl_gravity_report import table

    arm = {"kept_up": True, "error_m_at_min": {"30": 2000.0, "60": 4000.0}, "max_m": 5000.0, "healthy_mean_m": 1.0,
           "cross_track_mean_m": 10.0, "cross_track_max_m": 20.0, "failsafes": [], "fixes_in_denial": 0}
    summary = {"arms": {"alone": {**arm, "mean_m": 3000.0},
                        "companion": {**arm, "error_m_at_min": {"30": 400.0, "60": 900.0}, "mean_m": 800.0,
                                      "within_2hacc_frac": 0.95, "fixes_in_denial": 600, "return_jump_m": 50.0,
                                      "last_hacc_m": 80.0, "reconverge_s": 12.0}}}
    path = tmp_path / "sitl_gravity_plane.md"
    path.write_text("# Gravity aiding on ArduPlane SITL\n\n" + table(summary, "plane") + "\n")
    h = headline(path)
    assert "800 m with the companion" in h.text and "3000 m" in h.text, h
    verdicts = re.findall(r"target [^:]+: (met|MISSED)", path.read_text())
    assert h.target == f"{verdicts.count('met')} of {len(verdicts)} met" and len(verdicts) >= 5


def _docstrings(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=True)
            if doc:
                yield node, doc


def _code_files() -> list[Path]:
    return sorted((ROOT / "companion").rglob("*.py"))


def test_class_and_function_docstrings_are_short():
    long = [f"{path.relative_to(ROOT)}:{node.name}: {len(doc.splitlines())} lines > {DOCSTRING_MAX_LINES}"
            for path in _code_files() for node, doc in _docstrings(ast.parse(path.read_text()))
            if not isinstance(node, ast.Module) and len(doc.splitlines()) > DOCSTRING_MAX_LINES]
    assert long == []


#: what a lab notebook leaves in code besides test_layout.py's patterns: a results table, a shared log's name,
#: a seed (one run's result), a value's history ("was 789 m") and stale qualifiers. Tuning history goes to
#: docs/decisions/ (question, command, measured, chosen) and the setting links it.
NOTEBOOK = re.compile(
    r"^\s*\|.*\|.*\|"  # a markdown table row
    r"|\blog1\d\d\b|\bphoenix\b|\bdiaven\b"  # the shared logs by name
    r"|(?<!-)\bseeds? \d"  # (a command's --seed N is not a result)
    r"|" + _WAS + r"|\bnot rerun\b|\bpredate|\bbefore (?:that|this|the) change\b",
    re.I)


def _comments_and_docstrings(path: Path):
    src = path.read_text()
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string
    for node, _doc in _docstrings(ast.parse(src)):
        first = node.body[0]
        for i, line in enumerate(first.value.value.splitlines()):
            yield first.lineno + i, line


def test_no_notebook_in_code():
    found = [f"{path.relative_to(ROOT)}:{line}: {text.strip()}"
             for path in _code_files() for line, text in _comments_and_docstrings(path) if NOTEBOOK.search(text)]
    assert found == []


def test_notebook_pattern_catches_what_it_should():
    for text in ["| log | 8 s |", "RMSE on log172 2.1 m", "752 m mean (was 789 m)", "seed 8", "not rerun since",
                 "the numbers below predate it", "measured before that change"]:
        assert NOTEBOOK.search(text), text
    for text in ["x | y", "the 2 s a SIGTERM may take", "rejected by the gate", "a map cell", "run --seed 1",
                 "while the fix was 3D"]:
        assert not NOTEBOOK.search(text), text
