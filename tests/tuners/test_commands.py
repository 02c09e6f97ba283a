"""Every command follows the same conventions (tuners.conventions, tuners.commands): one
``gripper`` command lists and runs them, each names itself as the user ran it, answers
``--version``, says each default once, and answers ``--help`` and a bad name before the library
loads (checked by what is imported, not by timing: tests never time things)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from gripper_env._version import __version__
from tuners import commands
from tuners.conventions import HelpFormatter, command_parser, program_name

REPO = Path(__file__).resolve().parents[2]
#: What --help and a refused name must not load: the core's compiler, python-control, plots,
#: the search and the learning libraries, the simulation core and the environments' classes
#: (seconds of imports on a busy machine; gymnasium's registry alone is light and allowed).
HEAVY = ("numba", "control", "matplotlib", "scipy", "optuna", "torch", "stable_baselines3",
         "gripper_env.sim", "gripper_env.envs.control_env", "gripper_env.envs.servo",
         "gripper_env.envs.pid_tune")  # fmt: skip
#: The commands whose --help and --version are light (and the tuners' refusal of a bad name).
LIGHT = ("manual", "classical", "optuna", "rl", "benchmark", "leaderboard", "results", "sysid",
         "reproduce", "calibrate", "record", "deploy", "bus-calibrate", "bus-record",
         "bus-identify", "bus-deploy")  # fmt: skip

PROBE = """
import json, runpy, sys
sys.argv = [sys.argv[1], *sys.argv[2:]]
try:
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
except SystemExit as exc:
    code = exc.code
heavy = sorted(m for m in {heavy!r} if m in sys.modules)
print(json.dumps({{"code": code, "heavy": heavy}}), file=sys.stderr)
"""


def _probe(module: str, *args: str) -> tuple[int, list[str], str]:
    """Run ``python -m module args``; its exit code, the heavy modules it loaded, its stderr."""
    env = dict(os.environ, MPLBACKEND="Agg")
    result = subprocess.run(
        [sys.executable, "-c", PROBE.format(heavy=HEAVY), module, *args],
        cwd=REPO, capture_output=True, text=True, env=env, timeout=120, check=False,
    )  # fmt: skip
    *lines, last = result.stderr.strip().splitlines()
    facts = json.loads(last)
    return facts["code"], facts["heavy"], "\n".join(lines)


def test_the_console_scripts_are_the_commands_table():
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts.pop("gripper") == "tuners.commands:main"
    table = {f"gripper-{c.name}": c.entry for c in commands.COMMANDS if c.script}
    assert scripts == table


def test_every_command_module_exists_and_has_its_entry_point():
    import importlib.util

    for c in commands.COMMANDS:
        module, _, _function = c.entry.partition(":")
        assert importlib.util.find_spec(module) is not None, c
        assert importlib.util.find_spec(c.module) is not None, c


def test_gripper_lists_and_runs_the_commands(capsys):
    assert commands.main([]) == 0
    listing = capsys.readouterr().out
    for c in commands.COMMANDS:
        assert f"  {c.name} " in listing
    assert commands.main(["nosuch"]) == 2
    assert "unknown command 'nosuch'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        commands.main(["optuna", "--help"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("usage: gripper optuna ")
    assert commands.main(["optuna", "--plant", "nosuch"]) == 2
    assert "unknown plant 'nosuch'" in capsys.readouterr().err


@pytest.mark.parametrize("kind", sorted(commands.LISTS))
def test_gripper_list(kind, capsys):
    assert commands.main(["list", kind]) == 0
    names = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    expected = {"plants": "test2", "presets": "actual", "profiles": "step", "servos": "sts3215"}
    assert expected[kind] in names


def test_gripper_list_finds_the_users_own_plant(tmp_path, monkeypatch, capsys):
    from gripper_env.io import config

    (tmp_path / "plants").mkdir()
    (tmp_path / "plants" / "mine.yaml").write_text(
        "name: mine\ndescription: my gripper\nnum: [1.0]\nden: [0.1, 1.0]\n"
    )
    monkeypatch.setattr(config, "CONFIG_DIR", tmp_path)
    assert commands.main(["list", "plants"]) == 0
    rows = [line.split(None, 1) for line in capsys.readouterr().out.splitlines()]
    assert ["mine", "my gripper"] in rows


def test_a_program_names_itself_as_it_was_run(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/venv/bin/gripper-optuna"])
    assert program_name("tuners.optuna") == "gripper-optuna"
    monkeypatch.setattr(sys, "argv", ["/src/tuners/optuna/__main__.py"])
    assert program_name("tuners.optuna") == "python -m tuners.optuna"


def test_defaults_are_said_once_and_never_as_none():
    parser = command_parser("tuners.x", "x")
    parser.add_argument("--a", default=None, help="the a")
    parser.add_argument("--b", default=3, help="the b")
    parser.add_argument("--c", default=4, help="the c (default: four)")
    parser.add_argument("--out", type=Path, default=Path("runs"), help="where")
    parser.add_argument("--flag", action="store_true", help="a flag")
    text = " ".join(parser.format_help().split())
    assert "None" not in text and "(default: False)" not in text
    assert "the b (default: 3)" in text and "the c (default: four)" in text
    assert text.count("default") == 3 and "where (default: runs)" in text
    assert issubclass(parser.formatter_class, HelpFormatter)


def test_the_method_names_are_the_rules():
    from tuners.classical.command import METHOD_NAMES
    from tuners.classical.rules import METHODS

    assert METHOD_NAMES == tuple(METHODS)


@pytest.mark.parametrize("module", [c.module for c in commands.COMMANDS])
def test_every_command_answers_version(module):
    result = subprocess.run([sys.executable, "-m", module, "--version"], cwd=REPO,
                            capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout == f"gripper-env {__version__}\n"


@pytest.mark.parametrize("name", LIGHT)
def test_help_and_a_bad_name_answer_before_the_library_loads(name):
    module = next(c.module for c in commands.COMMANDS if c.name == name)
    sub = ["train"] if name == "rl" else []
    code, heavy, _ = _probe(module, *sub, "--help")
    assert code == 0 and heavy == [], heavy
    code, heavy, err = _probe(module, "--version")
    assert code == 0 and heavy == []
    if name in ("manual", "classical", "optuna", "rl"):
        extra = ["--gains", "paper-tuned"] if name == "manual" else []
        code, heavy, err = _probe(module, *sub, "--plant", "nosuch", *extra)
        assert code == 2 and heavy == [], (heavy, err)
        assert err.strip() == (
            "error: --plant: unknown plant 'nosuch'; available: test1, test2, test3, test4"
        )


def test_console_scripts_name_themselves_in_usage(tmp_path):
    script = Path(sys.executable).parent / "gripper-optuna"
    if not script.exists():
        pytest.skip("the console scripts are not installed (pip install -e .)")
    result = subprocess.run([str(script), "--plant", "test2", "--bogus"], capture_output=True,
                            text=True, timeout=120, check=False)  # fmt: skip
    assert result.returncode == 2
    assert result.stderr == (
        "gripper-optuna: error: unrecognized arguments: --bogus (see gripper-optuna --help)\n"
    )
    out = subprocess.run([str(script), "--version"], capture_output=True, text=True,
                         timeout=120, check=False)  # fmt: skip
    assert out.stdout.strip() == f"gripper-env {__version__}"
