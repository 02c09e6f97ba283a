"""The folders import only what ``docs/architecture.md`` allows them (its "may import" column).

Every source file is parsed (imports inside functions count too); an import of one of the
project's top-level packages that the table does not allow for the importing folder fails, with
the file and the line.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "architecture.md"


def _rules() -> dict[str, set[str] | None]:
    """``folder -> allowed top-level packages`` from the table (``None``: anything)."""
    rules: dict[str, set[str] | None] = {}
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not re.fullmatch(r"`[\w.]+/`", cells[0]):
            continue
        folder = cells[0].strip("`/")
        allowed = cells[2]
        rules[folder] = None if allowed == "anything" else set(re.findall(r"`(\w+)`", allowed))
    return rules


RULES = _rules()
#: The project's own top-level packages (an import of anything else is a dependency).
PROJECT = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()} | {"tests"}


def _imports(path: Path) -> list[tuple[int, str]]:
    """``(line, top-level package)`` of every absolute import in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name.split(".")[0]) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module.split(".")[0]))
    return found


def test_the_table_covers_every_python_package():
    assert {"gripper_env", "tuners", "rig", "benchmarks", "tests"} <= set(RULES)
    tops = [p for p in ROOT.iterdir() if p.is_dir() and not p.name.startswith(".")]
    code = {p.name for p in tops if p.name != "build" and next(p.rglob("*.py"), None)}
    assert code <= set(RULES), f"folders with Python code missing from {DOC.name}: {code}"
    assert RULES["gripper_env"] == {"gripper_env"}  # the library stands alone


def test_every_import_is_allowed_by_the_architecture():
    bad = []
    for folder, allowed in RULES.items():
        if allowed is None:
            continue
        for path in sorted((ROOT / folder).rglob("*.py")):
            for line, top in _imports(path):
                if top in PROJECT and top not in allowed:
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {top}")
    assert not bad, f"imports that {DOC.relative_to(ROOT)} does not allow:\n" + "\n".join(bad)


def test_the_rule_catches_a_forbidden_import(tmp_path):
    # the parser sees imports inside functions, aliased and dotted ones
    src = tmp_path / "m.py"
    src.write_text("def f():\n    import tuners.cli as c\n    from rig import deploy\n")
    assert [top for _, top in _imports(src)] == ["tuners", "rig"]
