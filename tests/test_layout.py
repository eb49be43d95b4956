"""The layout's rules, checked on the source: no import cycle in the package, no product module over 600 lines,
no issue numbers in file names or docstrings, no MAVLink enum value re-declared (they come from the dialect)."""

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
