"""The README, walked as a new user walks it: every command block, as printed, in its order, in a
fresh clone; afterwards ``git status --porcelain`` of the clone is empty (nothing a user runs
writes into the committed tree).

The blocks are parsed from README.md, not copied here, so the test follows the README as it
changes. What a user's machine has and a test's has not is handled by rules, each generic:

* **Setup.** The clone's ``.venv`` is made by this test (a virtual environment that reuses this
  one's packages and imports the clone's code), so ``bash scripts/setup.sh &&`` is dropped from
  a line (CI has just run it on its own fresh clone); lines that set up the machine as root
  (``scripts/system-packages.sh``, ``scripts/start-postgres.sh``) and lines that run the tests
  (``pytest``: this is one of them) are skipped. ``python`` and ``.venv/bin/python`` are the
  clone's.
* **Budgets.** A command whose ``--help`` lists one of :data:`BUDGETS` gets the short value
  (replacing the printed one): fewer trials, timesteps, generations, the quick variant. A
  Python block's ``total_timesteps=`` is shortened the same way.
* **Boards and servos.** A line ending in ``&`` starts in the background (killed when its block
  ends); the first line it prints that names an existing file is its port. ``PORT`` in a line is
  each such port in turn; a block that uses ``PORT`` without starting a board gets the virtual
  board the README names for it (``python -m tuners.rig.virtual``, at full speed). Paths under
  ``/tmp/`` go to this test's own folder.
* **Python blocks** run as scripts from the clone's root and must print something.

The numba kernels compiled by this checkout are copied into the clone (with the sources' time
stamps, which numba's cache checks), so the clone does not compile them again.

Slow (15-20 minutes on 2 cores): marked ``readme`` and deselected by default (pyproject's
``addopts``); CI runs it after the suite (``.ci/run``: ``pytest -m readme``).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import sysconfig
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from kernel_cache_support import share_compiled_kernels

pytestmark = [pytest.mark.readme, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]

#: Budget options and their short values: ``{option: value}``, or ``{option: {module: value}}``
#: where the value depends on the command (``None``: a flag without a value).
BUDGETS: dict[str, str | dict[str, str] | None] = {
    # the bus tuner's TPE needs some trials to meet a feasible register set at all (none in
    # 8 or 24 on the walk's quickly identified STS3215; 48 found one)
    "--trials": {"tuners.bus.tune": "100", "tuners": "8"},
    "--search-seeds": "1",
    "--timesteps": {"tuners.rl": "8192"},
    "--n-timesteps": {"rl_zoo3": "4096"},  # rl-zoo3's own option: one PPO update of the recipe
    "--generations": "4",
    "--quick": None,
}
#: A Python block's training budget (``total_timesteps=...``).
PYTHON_TIMESTEPS = "2048"
#: Lines skipped, by a pattern, and why.
SKIPPED = {
    r"(^|\s)(\S*/)?pytest(\s|$)|-m pytest": "runs the tests: this test is one of them",
    r"scripts/system-packages\.sh|scripts/start-postgres\.sh": "sets up the machine as root "
    "(CI's .ci/run does it before the tests)",
}
#: Dropped from the start of a line: the clone's environment is made by this test.
SETUP_PREFIX = re.compile(r"^bash scripts/setup\.sh\s*&&\s*")
#: What gives a block its ``PORT`` when it starts no board itself (the README's own advice).
DEFAULT_BOARD = "python -m tuners.rig.virtual --speed max"
LINE_TIMEOUT_S = 900
BOARD_START_S = 600


@dataclass
class Block:
    """A fenced block of the README: its language, text and first line number."""

    kind: str
    text: str
    line: int


@dataclass
class Background:
    """A board or a servo started in the background by a line ending in ``&``."""

    command: str
    proc: subprocess.Popen
    log: Path
    port: str | None = None


@dataclass
class Walk:
    """The clone, its environment and what has run."""

    clone: Path
    tmp: Path
    env: dict[str, str]
    log: list[str] = field(default_factory=list)
    helps: dict[str, str] = field(default_factory=dict)


def readme_blocks(text: str) -> list[Block]:
    """The ``bash`` and ``python`` fenced blocks, in order (indented ones too)."""
    blocks = []
    pattern = re.compile(r"^([ \t]*)```(bash|python)[ \t]*\n(.*?)^\1```", re.M | re.S)
    for m in pattern.finditer(text):
        indent = len(m.group(1))
        body = "\n".join(line[indent:] for line in m.group(3).splitlines())
        blocks.append(Block(m.group(2), body, text.count("\n", 0, m.start()) + 1))
    return blocks


def _strip_comment(line: str) -> str:
    """``line`` without a trailing ``# comment`` (outside quotes)."""
    quote = None
    for i, c in enumerate(line):
        if quote:
            quote = None if c == quote else quote
        elif c in "'\"":
            quote = c
        elif c == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip()
    return line.rstrip()


def block_commands(text: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments and blanks dropped."""
    joined = re.sub(r"\s*\\\n\s*", " ", text)
    return [c for c in (_strip_comment(line) for line in joined.splitlines()) if c.strip()]


def _module(command: str) -> str | None:
    m = re.search(r"-m\s+([\w.]+)", command)
    return m.group(1) if m else None


def _help(walk: Walk, command: str) -> str:
    """The ``--help`` of the command a line runs (cached per program and sub-command)."""
    words = shlex.split(command)
    if "-m" not in words:
        return ""
    i = words.index("-m")
    key = " ".join(words[i + 1 : i + 3])
    if key not in walk.helps:
        cmd = ["python", *words[i : i + 2]]
        sub = words[i + 2] if len(words) > i + 2 and not words[i + 2].startswith("-") else None
        if sub is not None and not Path(walk.clone, sub).exists():
            cmd.append(sub)  # a sub-command (python -m tuners.rl train), not a file argument
        result = subprocess.run([*cmd, "--help"], cwd=walk.clone, env=walk.env, text=True,
                                capture_output=True, timeout=120, check=False)  # fmt: skip
        walk.helps[key] = result.stdout
    return walk.helps[key]


def shorten(walk: Walk, command: str) -> str:
    """``command`` with every budget option its ``--help`` lists set to the short value."""
    text = _help(walk, command)
    module = _module(command) or ""
    for option, value in BUDGETS.items():
        if isinstance(value, dict):
            value = next((v for m, v in value.items() if module.startswith(m)), None)
            if value is None:
                continue
        if not re.search(rf"(^|\s|\[){re.escape(option)}\b", text):
            continue
        if value is None:
            if not re.search(rf"\s{re.escape(option)}(\s|$)", command):
                command += f" {option}"
            continue
        pattern = rf"(\s{re.escape(option)})(\s+|=)\S+"
        if re.search(pattern, command):
            command = re.sub(pattern, rf"\g<1> {value}", command)
        else:
            command += f" {option} {value}"
    return command


def _tmp_paths(walk: Walk, command: str) -> str:
    return re.sub(r"(?<![\w/])/tmp/", f"{walk.tmp}/", command)


def _run(walk: Walk, command: str) -> str:
    walk.log.append(f"$ {command}")
    started = time.monotonic()
    result = subprocess.run(["bash", "-c", command], cwd=walk.clone, env=walk.env, text=True,
                            capture_output=True, timeout=LINE_TIMEOUT_S, check=False)  # fmt: skip
    walk.log.append(f"  ({time.monotonic() - started:.0f} s, exit {result.returncode})")
    assert result.returncode == 0, (
        f"README line failed (exit {result.returncode}):\n$ {command}\n"
        f"--- stdout ---\n{result.stdout[-4000:]}\n--- stderr ---\n{result.stderr[-6000:]}"
    )
    return result.stdout


def _start(walk: Walk, command: str) -> Background:
    walk.log.append(f"$ {command} &")
    log = walk.tmp / f"background-{len(walk.log)}.log"
    proc = subprocess.Popen(["bash", "-c", f"exec {command}"], cwd=walk.clone, env=walk.env,
                            stdout=log.open("w"), stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)  # fmt: skip
    bg = Background(command, proc, log)
    deadline = time.monotonic() + BOARD_START_S
    while time.monotonic() < deadline and bg.port is None:
        for line in log.read_text().splitlines():
            word = line.strip()
            if word.startswith("/") and os.path.exists(word):
                bg.port = word
                break
        if bg.port is None and proc.poll() is not None:
            raise AssertionError(f"background line exited {proc.returncode}:\n$ {command}\n"
                                 f"{log.read_text()[-4000:]}")  # fmt: skip
        time.sleep(0.2)
    assert bg.port is not None, f"no port printed in {BOARD_START_S} s by:\n$ {command}"
    return bg


def _stop(backgrounds: list[Background]) -> None:
    for bg in backgrounds:
        if bg.proc.poll() is None:
            os.killpg(bg.proc.pid, signal.SIGTERM)
    for bg in backgrounds:
        try:
            bg.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(bg.proc.pid, signal.SIGKILL)
            bg.proc.wait()


def run_bash(walk: Walk, block: Block) -> None:
    """Every command of a bash block, as the rules above say."""
    backgrounds: list[Background] = []
    try:
        for raw in block_commands(block.text):
            command = _tmp_paths(walk, SETUP_PREFIX.sub("", raw.strip()))
            command = re.sub(r"(^|\s|&&\s*)\.venv/bin/python\b", r"\1python", command)
            why = next((w for p, w in SKIPPED.items() if re.search(p, command)), None)
            if why is not None:
                walk.log.append(f"# skipped ({why}): {raw}")
                continue
            if command.endswith("&"):
                backgrounds.append(_start(walk, shorten(walk, command[:-1].strip())))
                continue
            command = shorten(walk, command)
            if re.search(r"\bPORT\b", command):
                boards = [b for b in backgrounds if b.port]
                if not boards:
                    boards = [_start(walk, DEFAULT_BOARD)]
                    backgrounds += boards
                for board in boards:
                    _run(walk, re.sub(r"\bPORT\b", board.port or "", command))
                continue
            _run(walk, command)
    finally:
        _stop(backgrounds)


def run_python(walk: Walk, block: Block) -> None:
    """A Python block as a script from the clone's root; it must print something."""
    code = re.sub(r"total_timesteps=[\d_]+", f"total_timesteps={PYTHON_TIMESTEPS}", block.text)
    script = walk.tmp / f"block_{block.line}.py"
    script.write_text(code)
    out = _run(walk, f"python {shlex.quote(str(script))}")
    assert out.strip(), f"the Python block at README line {block.line} prints nothing:\n{code}"


def _make_env(clone: Path) -> Path:
    """The clone's ``.venv``: this environment's packages, the clone's code."""
    venv = clone / ".venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    purelib = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                              "['purelib'])"], capture_output=True, text=True,
                             check=True).stdout.strip()  # fmt: skip
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(purelib) / "_gripper_readme.pth").write_text("\n".join([str(clone), *sorted(ours)]))
    return venv


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("the README walk clones the checkout with git")
    tmp = tmp_path_factory.mktemp("readme")
    clone = tmp / "clone"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
    venv = _make_env(clone)
    share_compiled_kernels(clone)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST", "GRIPPER_"))}
    env.update(
        PATH=f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
        VIRTUAL_ENV=str(venv),
        MPLBACKEND="Agg",
        # each board's calibration in the walk's own folder, not the user's ~/.config (two
        # boards are calibrated in turn: one file each, as on a user's machine)
        GRIPPER_CALIBRATION_DIR=str(tmp / "calibrations"),
        HOME=str(tmp / "home"),
        PYTHONDONTWRITEBYTECODE="1",
    )
    env.pop("PYTHONPATH", None)
    (tmp / "home").mkdir()
    return Walk(clone, tmp, env)


def test_readme_blocks_are_found():
    blocks = readme_blocks((ROOT / "README.md").read_text())
    assert sum(b.kind == "bash" for b in blocks) >= 4 and any(b.kind == "python" for b in blocks)
    assert block_commands("a \\\n  b  # c\n# d\n\ne 'x # y'\n") == ["a b", "e 'x # y'"]


def test_every_readme_block_runs_as_printed_and_leaves_the_clone_clean(walk):
    blocks = readme_blocks((walk.clone / "README.md").read_text())
    for block in blocks:
        walk.log.append(f"## README line {block.line} ({block.kind})")
        try:
            (run_bash if block.kind == "bash" else run_python)(walk, block)
        finally:
            (walk.tmp / "walk.log").write_text("\n".join(walk.log) + "\n")
    status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"],
                            cwd=walk.clone, capture_output=True, text=True,
                            check=True).stdout  # fmt: skip
    assert status == "", f"the README's commands changed the committed tree:\n{status}"
