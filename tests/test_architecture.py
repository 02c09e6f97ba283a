"""The layers import only what ``docs/architecture.md`` allows them (its "may import" column).

Every source file is parsed (imports inside functions count too). Each file and each imported
module of the project belongs to the most specific folder of the table that holds it; an import
from one row into another that the importing row does not list fails, with the file and the line.
The module graph has no cycles either, at any level (function-level imports included).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "architecture.md"
PACKAGES = ("gripper_env", "tuners")


def _rules() -> dict[str, set[str] | None]:
    """``folder (dotted) -> allowed entries`` from the table (``None``: anything)."""
    rules: dict[str, set[str] | None] = {}
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3:
            continue
        folders = re.findall(r"`([\w/]+)/`", cells[0])
        if not folders or not all(re.fullmatch(r"(`[\w/]+/`(, )?)+", cells[0]) for _ in [0]):
            continue
        allowed = None if cells[2] == "anything" else set(re.findall(r"`([\w.*]+)`", cells[2]))
        for folder in folders:
            rules[folder.replace("/", ".")] = allowed
    return rules


RULES = _rules()


def _module(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


MODULES = {_module(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def _row(module: str) -> str:
    """The most specific row of the table that holds ``module``."""
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in RULES:
            return ".".join(parts[:n])
    raise AssertionError(f"{module} is in no row of {DOC.name}")


def _imports(path: Path, module: str) -> list[tuple[int, str]]:
    """``(line, imported module)`` of every import of the project's modules in ``path``; a
    ``from package import name`` counts the submodule ``name`` when there is one."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            subs = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in MODULES]
            found += [(node.lineno, s) for s in subs] or [(node.lineno, base)]
    return [(line, m) for line, m in found if m.split(".")[0] in {*PACKAGES, "tests"}]


def _allowed(entries: set[str], module: str, row: str) -> bool:
    for entry in entries:
        if entry.endswith(".*"):
            if module == entry[:-2] or module.startswith(entry[:-1]):
                return True
        elif entry in (row, module):
            return True
    return False


def test_the_table_covers_every_python_package():
    assert {"gripper_env", "tuners", "tests", "examples"} <= set(RULES)
    tops = [p for p in ROOT.iterdir() if p.is_dir() and not p.name.startswith(".")]
    code = {p.name for p in tops if p.name != "build" and next(p.rglob("*.py"), None)}
    assert code <= set(RULES), f"folders with Python code missing from {DOC.name}: {code}"
    for module in MODULES:
        _row(module)  # every module has a row
    # the layers the issue names
    assert "gripper_env.envs" not in str(RULES["gripper_env.sim"])
    assert not {"gripper_env.hardware", "gripper_env.evaluation"} & {
        e.split(".*")[0] for e in RULES["gripper_env.sim"] or ()
    }


def test_every_import_is_allowed_by_the_architecture():
    bad = []
    for module, path in MODULES.items():
        row = _row(module)
        allowed = RULES[row]
        if allowed is None:
            continue
        for line, imported in _imports(path, module):
            if imported.split(".")[0] == "tests":
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {imported}")
                continue
            target = _row(imported) if imported in MODULES or "." in imported else imported
            if target != row and not _allowed(allowed, imported, target):
                bad.append(f"{path.relative_to(ROOT)}:{line} ({row}) imports {imported} ({target})")
    assert not bad, f"imports that {DOC.relative_to(ROOT)} does not allow:\n" + "\n".join(bad)


def test_no_module_imports_itself_in_a_circle():
    graph = {
        m: {i for _, i in _imports(p, m) if i in MODULES and i != m} for m, p in MODULES.items()
    }
    circles = []
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            scc = []
            while True:
                w = stack.pop()
                on.discard(w)
                scc.append(w)
                if w == v:
                    break
            if len(scc) > 1:
                circles.append(sorted(scc))

    for v in graph:
        if v not in index:
            visit(v)
    assert not circles, f"modules importing each other in a circle: {circles}"


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("def f():\n    import tuners.cli as c\n", ["tuners.cli"]),
        ("from gripper_env.hardware import protocol\n", ["gripper_env.hardware.protocol"]),
        ("from gripper_env import Plant\n", ["gripper_env"]),
    ],
)
def test_the_parser_sees_every_kind_of_import(tmp_path, source, expected):
    src = tmp_path / "m.py"
    src.write_text(source)
    assert [m for _, m in _imports(src, "gripper_env.m")] == expected


def test_the_rule_catches_a_forbidden_import():
    # the core importing an environment, evaluation or the hardware is refused
    allowed = RULES["gripper_env.sim"]
    assert allowed is not None
    for imported in ("gripper_env.envs.servo", "gripper_env.evaluation.metrics",
                     "gripper_env.hardware.host.device", "tuners.cli"):  # fmt: skip
        assert not _allowed(allowed, imported, _row(imported)), imported
    assert _allowed(allowed, "gripper_env.model.pid", _row("gripper_env.model.pid"))
