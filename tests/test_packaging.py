"""The project installs as a package: the listed packages, the entry points, and a real wheel.

``pyproject.toml`` lists its packages instead of discovering them, because the top-level
``configs/`` folder ships as ``gripper_env.configs``; the first tests make sure the list keeps up
with the source tree. The last one builds the wheel, installs it into a fresh virtual
environment outside the source tree, and tunes there (the configs must come from the wheel).
"""

from __future__ import annotations

import fnmatch
import importlib
import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from kernel_cache_support import share_compiled_kernels

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]
#: What the wheel is built from (the rest of the tree is not packaged).
SOURCES = ("pyproject.toml", "README.md", "gripper_env", "tuners", "configs")


def _package_dir(package: str) -> Path:
    """Source folder of a package, following ``package-dir`` (longest prefix first)."""
    mapping = SETUPTOOLS.get("package-dir", {})
    for prefix in sorted(mapping, key=len, reverse=True):
        if package == prefix or package.startswith(prefix + "."):
            rest = package[len(prefix) :].lstrip(".").split(".") if package != prefix else []
            return ROOT / mapping[prefix] / Path(*rest) if rest else ROOT / mapping[prefix]
    return ROOT / Path(*package.split("."))


def _source_packages() -> set[str]:
    """Every package of the source tree the wheel should carry (tests are not shipped)."""
    found = set()
    for top in SOURCES[2:]:
        for folder in [ROOT / top, *(ROOT / top).rglob("*")]:
            if not folder.is_dir() or "__pycache__" in folder.parts:
                continue
            parts = folder.relative_to(ROOT).parts
            if top == "configs":  # data: every folder is a (data) package of gripper_env.configs
                found.add(".".join(("gripper_env", *parts)))
            elif (folder / "__init__.py").is_file():
                found.add(".".join(parts))
    return found


def test_every_package_of_the_source_tree_is_listed():
    listed = set(SETUPTOOLS["packages"])
    missing, stale = _source_packages() - listed, listed - _source_packages()
    assert not missing, f"add to [tool.setuptools] packages in pyproject.toml: {sorted(missing)}"
    assert not stale, f"listed in pyproject.toml but not in the source tree: {sorted(stale)}"
    # no other top-level package hides beside them (tests are not shipped)
    tops = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()} - {"tests"}
    assert tops <= set(SOURCES), tops
    # the wheel installs no generic top-level name (no `rig`, no `benchmarks`)
    assert {package.split(".")[0] for package in listed} == {"gripper_env", "tuners"}


def test_every_config_file_is_package_data():
    patterns = SETUPTOOLS["package-data"]
    for package in SETUPTOOLS["packages"]:
        folder = _package_dir(package)
        for f in folder.iterdir():
            if f.is_file() and f.suffix != ".py":
                assert any(fnmatch.fnmatch(f.name, pat) for pat in patterns.get(package, [])), (
                    f"{f.relative_to(ROOT)} is not package data of {package} in pyproject.toml"
                )


def test_entry_points_name_existing_commands():
    scripts = PYPROJECT["project"]["scripts"]
    assert {"gripper-optuna", "gripper-calibrate", "gripper-reproduce", "gripper-sysid"} <= set(
        scripts
    )
    for name, target in scripts.items():
        module, _, attr = target.partition(":")
        assert callable(getattr(importlib.import_module(module), attr)), name


def _run(cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run(cmd, capture_output=True, text=True, check=False, **kwargs)
    assert result.returncode == 0, f"{' '.join(map(str, cmd))}\n{result.stdout}\n{result.stderr}"
    return result


@pytest.mark.slow
def test_the_wheel_installs_and_tunes_outside_the_source_tree(tmp_path):
    # build from a copy of what the wheel is made of, so the source tree gets no build/ folder
    src = tmp_path / "src"
    src.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, src / name)
    pip = [sys.executable, "-m", "pip"]
    _run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", tmp_path / "dist", src])
    (wheel,) = (tmp_path / "dist").glob("gripper_env-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for package in SETUPTOOLS["packages"]:
        for f in _package_dir(package).glob("*.*"):
            if f.suffix in (".py", ".yaml"):
                assert f"{package.replace('.', '/')}/{f.name}" in names, f

    # a fresh environment; pip (and its cache) of this one installs the wheel and its dependencies
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    _run([*pip, "--python", python, "install", "-q", "--no-compile", wheel])
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"])
                .stdout.strip())  # fmt: skip
    share_compiled_kernels(site)  # the kernels load instead of compiling (minutes)

    work = tmp_path / "work"  # outside the source tree: nothing of it on the path
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "GRIPPER_CONFIG_DIR")}
    env["MPLBACKEND"] = "Agg"
    check = (
        "import importlib.metadata as md, gripper_env, gripper_env.io.config as c\n"
        "from gripper_env.hardware.emulator.build import EmulatorUnavailable, ensure_built\n"
        "from gripper_env.model.plants import available_plants\n"
        "for ep in md.entry_points(group='console_scripts'):\n"
        "    if ep.dist.name == 'gripper-env': ep.load()\n"
        "try:\n"
        "    ensure_built()\n"
        "except EmulatorUnavailable as exc:\n"
        "    why = str(exc)\n"
        "print(gripper_env.__file__, c.CONFIG_DIR, available_plants(), why, sep='|')\n"
    )
    out = _run([python, "-c", check], cwd=work, env=env).stdout
    where, config_dir, plants, why = out.strip().split("|")
    assert "not installed with the package" in why  # the emulator says what it needs
    for path in (where, config_dir):  # the package and its configs come from the wheel
        assert Path(path).resolve().is_relative_to(venv.resolve()), path
    assert plants == "['test1', 'test2', 'test3', 'test4']"
    assert all((venv / "bin" / name).is_file() for name in PYPROJECT["project"]["scripts"])

    cmd = [python, "-m", "tuners.optuna", "--plant", "test2", "--trials", "16", "--search-seeds",
           "1"]  # fmt: skip
    out = _run(cmd, cwd=work, env=env).stdout
    assert "wrote runs/test2/optuna.json" in out  # users' runs: never the committed results/
    content = json.loads((work / "runs" / "test2" / "optuna.json").read_text())
    assert content["format"] == "gripper-gains" and content["plant"] == "test2"
    assert content["robustness"]["meets_constraints"]
