"""The structure of the code, checked like its behaviour (docs/developing.md says what each check protects).

- import-linter's contracts (pyproject.toml): sim above lfd and robots, lfd and robots
  independent, sim's groups in layers, lfd's core below its tools, private modules private to
  their package, no import cycle inside a package, imports inside functions included;
- no file of the library, the scripts or the examples over ``MAX_LINES`` lines;
- no module docstring over ``MAX_MODULE_DOCSTRING`` lines;
- no docstring or comment that carries an issue number, and no docstring with a measured figure
  (timings, speed-ups: those belong in reports/);
- the public faces: at most ``MAX_SIM_NAMES`` names in ``sim`` and ``MAX_ROBOTS_NAMES`` in ``robots``;
- ``sim`` grouped by idea: at most ``MAX_SIM_MODULES`` modules directly in sim/, the rest in its groups;
- no module uses another module's private names (``test_no_module_uses_another_modules_private_names``);
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
MAX_SIM_MODULES = 12
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


def test_sim_is_grouped_by_idea() -> None:
    """At most ``MAX_SIM_MODULES`` modules directly in sim/ (``__init__.py`` aside); the rest live in its
    groups (sim/run, sim/scene, sim/control, sim/media, sim/studies, sim/speed)."""
    top = sorted(p.name for p in (ROOT / "sim").glob("*.py") if p.name != "__init__.py")
    assert len(top) <= MAX_SIM_MODULES, f"{len(top)} modules directly in sim/ (at most {MAX_SIM_MODULES}): {top}"


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


#: names of other libraries that are their public interface though spelled with one underscore
OTHER_LIBRARIES_PRIVATE_NAMES = {
    "_exit": "os._exit: the documented exit without clean-up (a forked or interrupted worker)",
    "_version": "torch.Tensor._version: the in-place version counter, the one sign of an in-place change",
    "_address": "MuJoCo's MjModel and MjData: the C struct's address, the bindings' handle for compiled code",
}


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _on_own_object(node: ast.Attribute) -> bool:
    """``self._x``, ``cls._x`` or ``super()._x``."""
    v = node.value
    return (isinstance(v, ast.Name) and v.id in ("self", "cls")) or (
        isinstance(v, ast.Call) and isinstance(v.func, ast.Name) and v.func.id == "super")


def _defined_names(tree: ast.AST) -> set[str]:
    """Every name the module itself defines: functions, methods and classes, names assigned (globals, class
    attributes, annotations), attributes assigned on ``self`` or ``cls``, names imported, keyword names."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            out.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _on_own_object(node):
            out.add(node.attr)
        elif isinstance(node, ast.alias):
            out.add((node.asname or node.name).split(".")[0])
        elif isinstance(node, ast.keyword) and node.arg:
            out.add(node.arg)
    return out


def _is_module(package: str, name: str) -> bool:
    folder = ROOT.joinpath(*package.split("."))
    return (folder / f"{name}.py").is_file() or (folder / name / "__init__.py").is_file()


def private_name_uses(source: str, module: str) -> list[str]:
    """The uses of another module's private names in ``source``, the text of module ``module``, as
    'line: expression'.

    A private name starts with one underscore (dunder names are not private). Flagged:

    - ``X._name`` (read, written or called) where X is not ``self``, ``cls`` or ``super()`` and ``_name``
      is not defined in this module (``_defined_names``: a function, method or class, an assigned name,
      an attribute assigned on ``self`` or ``cls``, an imported name, a keyword name) nor one of
      ``OTHER_LIBRARIES_PRIVATE_NAMES``;
    - ``from M import _name`` where ``M._name`` is not a module. A private module (``sim.control._control_kernel``)
      imported for its public names, even under a private alias (``from sim.control._kernel_layout import
      HEADER as _HEADER``), is fine; that it is imported only inside its own package is import-linter's
      ``private_modules`` contract (pyproject.toml).

    The check goes by name, without types: ``other._x`` passes where this module defines ``_x`` itself.
    """
    tree = ast.parse(source)
    own = _defined_names(tree)
    package = module if module.endswith(".__init__") else module.rpartition(".")[0]
    package = package.removesuffix(".__init__")
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _is_private(node.attr):
            if not (_on_own_object(node) or node.attr in own or node.attr in OTHER_LIBRARIES_PRIVATE_NAMES):
                out.append(f"{node.lineno}: {ast.unparse(node)}")
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
            for alias in node.names:
                if _is_private(alias.name) and not _is_module(base, alias.name):
                    out.append(f"{node.lineno}: from {'.' * node.level}{node.module or ''} import {alias.name}")
    return out


def _module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts)


def test_no_module_uses_another_modules_private_names() -> None:
    """No module of lfd/, robots/, sim/, scripts/ or examples/ reads, writes or imports a private name that
    another module defines (``private_name_uses`` says exactly what counts): the owner gives it a public name."""
    hits = [f"{p.relative_to(ROOT)}:{hit}" for p in _files(*PACKAGES, "scripts", "examples")
            for hit in private_name_uses(p.read_text(encoding="utf-8"), _module_name(p))]
    assert not hits, "uses of another module's private names:\n" + "\n".join(hits)


#: what the check above flags (the cases it was written for) and what it lets through
PRIVATE_FLAGGED = {
    "own = self.ik._impl.gains": "self.ik._impl",
    "_, pos, rot = self.kin._placement()": "self.kin._placement",
    "state = self.controller._qdot_prev": "self.controller._qdot_prev",
    "self.controller._qdot_prev = state": "self.controller._qdot_prev",
    "sdf, n = o._sdf(y)": "o._sdf",
    "path = sources._resolve_uri(uri, folder)": "sources._resolve_uri",
    "from lfd.obstacles.groups import _group": "from lfd.obstacles.groups import _group",
}
PRIVATE_ALLOWED = (
    "self._x = 1\ny = self._x + cls._y + super()._z",
    "class A:\n    def __init__(self):\n        self._n = 0\n\ndef f(a: A) -> int:\n    return a._n",
    "_CACHE = {}\ndef f(m):\n    return m._CACHE, m.__dict__, m.__name__",
    "from sim.control._kernel_layout import HEADER as _HEADER",
    "from sim.control import _control_kernel",
    "import os\nos._exit(0)",
    "parser.set_defaults(_run=run)\nargs._run(args)",
)


@pytest.mark.parametrize("source", PRIVATE_FLAGGED)
def test_the_private_name_check_flags_the_cases_it_was_written_for(source: str) -> None:
    assert [h.split(": ", 1)[1] for h in private_name_uses(source, "sim.control.task")] == [PRIVATE_FLAGGED[source]]


@pytest.mark.parametrize("source", PRIVATE_ALLOWED)
def test_the_private_name_check_lets_own_names_and_private_modules_through(source: str) -> None:
    assert private_name_uses(source, "sim.control.controller") == []
