"""The structure of the code, checked like its behaviour (docs/developing.md says what each check protects).

- import-linter's contracts (pyproject.toml): sim above lfd and robots, lfd and robots
  independent, no import cycle inside a package, imports inside functions included;
- no file of the library, the scripts or the examples over ``MAX_LINES`` lines;
- no module docstring over ``MAX_MODULE_DOCSTRING`` lines;
- no docstring or comment that carries an issue number, and no docstring with a measured figure
  (timings, speed-ups: those belong in reports/);
- the public faces: at most ``MAX_SIM_NAMES`` names in ``sim`` and ``MAX_ROBOTS_NAMES`` in ``robots``;
- no ``sys.path`` edit anywhere;
- a field's kind is decided only in lfd/field.py;
- imports inside functions counted, and capped at today's count.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("lfd", "robots", "sim")
MAX_LINES = 600
MAX_MODULE_DOCSTRING = 25
MAX_SIM_NAMES = 12
MAX_ROBOTS_NAMES = 8
#: imports inside functions, per package: each one keeps a command's start-up cheap (torch, mujoco,
#: matplotlib, numba, ray, ...) or an optional dependency optional; a new one must say why here
MAX_FUNCTION_IMPORTS = {"lfd": 200, "robots": 20, "sim": 80}


def _files(*folders: str) -> list[Path]:
    out: list[Path] = []
    for folder in folders:
        out += sorted(p for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)
    return out


def _library() -> list[Path]:
    return _files(*PACKAGES)


def test_import_contracts_hold() -> None:
    """``lint-imports`` (import-linter) keeps every contract of pyproject.toml."""
    exe = Path(sys.executable).with_name("lint-imports")
    out = subprocess.run([str(exe), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert "BROKEN" not in out.stdout


@pytest.mark.parametrize("folder", [*PACKAGES, "scripts", "examples"])
def test_no_file_is_over_the_size_limit(folder: str) -> None:
    long = {str(p.relative_to(ROOT)): n for p in _files(folder)
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert not long, f"files over {MAX_LINES} lines: {long}"


def test_module_docstrings_are_short() -> None:
    long = {}
    for p in _library():
        doc = ast.get_docstring(ast.parse(p.read_text(encoding="utf-8")), clean=False)
        if doc and len(doc.splitlines()) > MAX_MODULE_DOCSTRING:
            long[str(p.relative_to(ROOT))] = len(doc.splitlines())
    assert not long, f"module docstrings over {MAX_MODULE_DOCSTRING} lines (move derivations to docs/): {long}"


ISSUE = re.compile(r"\b(issue|ticket)\s*#?\d+|(?<![\w&])#\d{2,}\b", re.IGNORECASE)
#: a measured figure: a duration in micro- or milliseconds, or a speed-up/slow-down factor
MEASURED = re.compile(r"\b\d+(\.\d+)?\s*(µs|us|ms)\b(?!\))|\b\d+(\.\d+)?x (faster|slower|a bare|the cost)\b")


def _docstrings(tree: ast.AST) -> list[tuple[int, str]]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                out.append((getattr(node, "lineno", 1), doc))
    return out


def test_no_docstring_carries_an_issue_number_or_a_measured_figure() -> None:
    bad = []
    for p in _library():
        text = p.read_text(encoding="utf-8")
        for line_no, doc in _docstrings(ast.parse(text)):
            for pattern, what in ((ISSUE, "issue number"), (MEASURED, "measured figure")):
                m = pattern.search(doc)
                if m:
                    bad.append(f"{p.relative_to(ROOT)}:{line_no}: {what} '{m.group(0)}'")
        for k, line in enumerate(text.splitlines(), 1):
            if "#" in line and ISSUE.search(line.split("#", 1)[1]):
                bad.append(f"{p.relative_to(ROOT)}:{k}: issue number in a comment")
    assert not bad, "\n".join(bad)


def _all(package: str) -> list[str]:
    tree = ast.parse((ROOT / package / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise AssertionError(f"{package}/__init__.py has no __all__")


def test_public_faces_are_small() -> None:
    assert len(_all("sim")) <= MAX_SIM_NAMES, _all("sim")
    assert len(_all("robots")) <= MAX_ROBOTS_NAMES, _all("robots")


def test_nothing_edits_sys_path() -> None:
    hits = []
    for p in _files(*PACKAGES, "scripts", "examples", "tests"):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == "path" and isinstance(node.value, ast.Name) \
                    and node.value.id == "sys":
                parent_calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)
                                and isinstance(n.func, ast.Attribute) and n.func.value is node
                                and n.func.attr in ("insert", "append", "extend", "remove")]
                if parent_calls:
                    hits.append(f"{p.relative_to(ROOT)}:{node.lineno}")
    assert not hits, f"sys.path edits: {hits}"


#: what decides a field's kind: only lfd/field.py may
KIND_CHECK = re.compile(r"\bis_phased\(|\bis_time_varying\(|isinstance\(\w*field\w*,|hasattr\(\w*field|"
                        r"getattr\(\w*field\w*, \"chart\"|\bfield\w*\.chart is (not )?None|\.kind is FieldKind")


def test_only_lfd_field_decides_a_fields_kind() -> None:
    hits = []
    for p in _files(*PACKAGES, "scripts", "examples"):
        if p == ROOT / "lfd" / "field.py":
            continue
        for k, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1):
            if KIND_CHECK.search(line.split("#", 1)[0]):
                hits.append(f"{p.relative_to(ROOT)}:{k}: {line.strip()}")
    assert not hits, "\n".join(hits)


def function_level_imports(package: str) -> list[str]:
    """Every import statement inside a function of ``package``, as 'file:line module'."""
    out = []
    for p in _files(package):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for sub in ast.walk(node):
                    if isinstance(sub, ast.ImportFrom):
                        out.append(f"{p.relative_to(ROOT)}:{sub.lineno} {'.' * sub.level}{sub.module}")
                    elif isinstance(sub, ast.Import):
                        out.append(f"{p.relative_to(ROOT)}:{sub.lineno} {sub.names[0].name}")
    return sorted(set(out))


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_inside_functions_are_counted_and_capped(package: str) -> None:
    found = function_level_imports(package)
    cap = MAX_FUNCTION_IMPORTS[package]
    assert len(found) <= cap, f"{len(found)} imports inside functions in {package} (cap {cap}):\n" + "\n".join(found)
