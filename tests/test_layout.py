"""The layout's rules, checked on the source: no import cycle in the package or the benchmarks, no product module over
600 lines, no issue numbers in file names or docstrings, no MAVLink enum value re-declared (they come from the
dialect), and no docstring or comment that is a lab notebook (those are decision records)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "companion"
MAX_LINES = 600


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules(root: Path) -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(root.rglob("*.py"))}


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """Modules of the package this module imports (anywhere in it, function bodies included)."""
    tree = ast.parse(path.read_text())
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg.split(".")[: len(pkg.split(".")) - node.level + 1] + ([base] if base else []))
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        else:
            continue
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_companion_import_graph_has_no_cycle():
    mods = _modules(PACKAGE)
    known = set(mods)
    # a package's __init__ is not an edge of its submodules: importing a.b runs a/__init__ first, but a cycle only
    # bites when modules import each other
    graph = {n: {m for m in _imports(p, n, known) if not n.startswith(m + ".")} for n, p in mods.items()}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def test_replay_import_graph_has_no_cycle():
    """The benchmarks too (type-checking imports included: a cycle there is still two modules that need each other)."""
    mods = _modules(REPO / "replay")
    known = set(mods)
    graph = {n: {m for m in _imports(p, n, known) if not n.startswith(m + ".")} for n, p in mods.items()}
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def test_the_cycle_check_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(REPO)))
def test_no_product_module_over_600_lines(path):
    assert len(path.read_text().splitlines()) <= MAX_LINES


_ISSUE = re.compile(r"\bissues?\s*#?\d+|#\d+\b|\bissue-\d+|\bpart I{1,2}\b", re.I)


def _docstrings(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield doc


def test_no_issue_numbers_in_file_names_or_docstrings():
    bad = []
    for root in (PACKAGE, REPO / "replay"):
        for p in sorted(root.rglob("*")):
            rel = str(p.relative_to(REPO))
            if re.search(r"issue|gravity2|part[12]", p.name, re.I):
                bad.append(f"file name {rel}")
            if p.suffix == ".py":
                for doc in _docstrings(ast.parse(p.read_text())):
                    m = _ISSUE.search(doc)
                    if m:
                        bad.append(f"{rel}: {m.group(0)!r}")
    assert not bad, bad


_MAVLINK_ENUM = re.compile(r"^(MAV_|GPS_FIX_TYPE|GPS_INPUT_IGNORE|IGNORE_|MAVLINK_MSG_ID)")


def test_no_mavlink_enum_value_is_redeclared():
    """MAVLink enum values come from pymavlink's dialect (companion.mavlink.dialect), never as literals."""
    bad = []
    for root in (PACKAGE, REPO / "replay", REPO / "tests"):
        for p in sorted(root.rglob("*.py")):
            for node in ast.walk(ast.parse(p.read_text())):
                if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, int):
                    for t in node.targets:
                        if isinstance(t, ast.Name) and _MAVLINK_ENUM.match(t.id):
                            bad.append(f"{p.relative_to(REPO)}:{node.lineno} {t.id} = {node.value.value}")
            src = p.read_text()
            for m in re.finditer(r"^\s+(NO_GPS|NO_FIX|FIX_2D|FIX_3D) = \d+$", src, re.M):
                bad.append(f"{p.relative_to(REPO)}: {m.group(0).strip()}")
    assert not bad, bad


@pytest.mark.parametrize("core", ["nav", "gravity"])
def test_numerical_cores_import_no_io_machinery(core):
    """nav/ and gravity/ never import asyncio, pymavlink, sockets or threads themselves (the matchers' compute-time
    measurement with time.perf_counter is their only clock)."""
    banned = ("asyncio", "pymavlink", "socket", "threading", "serial", "select")
    bad = []
    for p in sorted((PACKAGE / core).rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            bad += [f"{p.relative_to(REPO)}: {n}" for n in names if n.split(".")[0] in banned]
    assert not bad, bad


# the code says what it does and why; tuning tables, per-log results and rejected experiments are decision records
# (docs/decisions/): a docstring or comment naming a shared log, a pooled or held-out score, or a before -> after
# number is a lab-notebook entry, and so is a docstring longer than a page
MAX_DOC_LINES = 50
MAX_COMMENT_LINES = 15
_NOTEBOOK = re.compile(r"\b(ac313|erle|log171|pooled|held[- ]out|tuning logs?|tuning seeds?)\b|"
                       r"\d+\.\d+ -> \d+\.\d+", re.I)


def _comment_blocks(src: str):
    """(first line, text) of every run of consecutive comment lines."""
    import io
    import tokenize

    lines: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            lines[tok.start[0]] = tok.string
    block: list[int] = []
    for n in sorted(lines) + [-1]:
        if block and n != block[-1] + 1:
            yield block[0], "\n".join(lines[k] for k in block)
            block = []
        if n > 0:
            block.append(n)


def _notebook_entries(root: Path) -> list[str]:
    bad = []
    for p in sorted(root.rglob("*.py")):
        rel, src = p.relative_to(root.parent), p.read_text()
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node, clean=False)
                if not doc:
                    continue
                name = getattr(node, "name", "module")
                if doc.count("\n") + 1 > MAX_DOC_LINES:
                    bad.append(f"{rel} {name}: docstring of {doc.count(chr(10)) + 1} lines")
                m = _NOTEBOOK.search(doc)
                if m:
                    bad.append(f"{rel} {name}: {m.group(0)!r}")
        for line, text in _comment_blocks(src):
            if text.count("\n") + 1 > MAX_COMMENT_LINES:
                bad.append(f"{rel}:{line}: comment of {text.count(chr(10)) + 1} lines")
            m = _NOTEBOOK.search(text)
            if m:
                bad.append(f"{rel}:{line}: {m.group(0)!r}")
    return bad


def test_no_docstring_or_comment_is_a_lab_notebook():
    bad = _notebook_entries(PACKAGE)
    assert not bad, "move these to a decision record (docs/decisions/) and link it from the setting:\n" + "\n".join(bad)


def test_the_notebook_check_finds_one(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "m.py").write_text('"""Chosen on ac313."""\n\nx = 1  # pooled 8 s\ny = 2  # 3.23 -> 3.18 m\n\nz = 3\n'
                              + "\n".join("# line" for _ in range(MAX_COMMENT_LINES + 1)) + "\n\n\n"
                              + 'def f():\n    """' + "\n" * MAX_DOC_LINES + '"""\n')
    bad = _notebook_entries(pkg)
    assert bad == ["pkg/m.py module: 'ac313'", "pkg/m.py f: docstring of 51 lines", "pkg/m.py:3: 'pooled'",
                   "pkg/m.py:7: comment of 16 lines"], bad


def test_every_decision_record_named_in_the_code_exists():
    named = set()
    for p in PACKAGE.rglob("*.py"):
        named |= set(re.findall(r"docs/decisions/(\d{4})", p.read_text()))
    have = {p.name[:4] for p in (REPO / "docs" / "decisions").glob("*.md")}
    assert named and named <= have, sorted(named - have)
