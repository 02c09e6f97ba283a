"""The examples run as a user runs them, with small budgets, and leave the checkout as it was.

Each script in ``examples/`` runs as a subprocess (this interpreter, from a temporary folder,
with the checkout first on ``PYTHONPATH`` so that the examples use this tree's code) and must exit
0 and print its key line; the notebook is executed with nbclient on a ``python3`` kernel of this
interpreter. Around each run, ``git status --porcelain`` of the checkout must not change: the
examples write only where they are told to (``--out``) or nowhere.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # the end-to-end tier (pytest -m slow)

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"

#: The scripts, each run by a test below.
SCRIPTS = ("deploy_virtual.py", "identify.py", "joint_mujoco.py", "train_rl.py", "tune_optuna.py")


def _git_status() -> str | None:
    """``git status --porcelain`` of the checkout, or None outside a git checkout."""
    if shutil.which("git") is None:
        return None
    result = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all"],
        cwd=ROOT, capture_output=True, text=True, check=False,
    )  # fmt: skip
    return result.stdout if result.returncode == 0 else None


@pytest.fixture
def checkout_unchanged():
    """Fails the test if the checkout's ``git status`` changed while it ran."""
    before = _git_status()
    yield
    if before is not None:
        assert _git_status() == before, "an example wrote into the repository"


def _env() -> dict[str, str]:
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    return dict(os.environ, PYTHONPATH=path, MPLBACKEND="Agg")


def run_example(name: str, *args: str, cwd: Path) -> str:
    """Run ``examples/<name> args`` from ``cwd``; its stdout (it must exit 0)."""
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args],
        cwd=cwd, env=_env(), capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert result.returncode == 0, f"{name} exited {result.returncode}:\n{result.stderr}"
    return result.stdout


def test_every_example_is_run_here_and_described():
    scripts = {p.name for p in EXAMPLES.glob("*.py")}
    assert scripts == set(SCRIPTS), f"add a test of each example: {sorted(scripts ^ set(SCRIPTS))}"
    readme = (EXAMPLES / "README.md").read_text()
    for name in [*scripts, "quickstart.ipynb"]:
        assert name in readme, f"examples/README.md does not mention {name}"


@pytest.fixture(scope="module")
def tuned(tmp_path_factory):
    """``tune_optuna.py --out out`` (16 trials): its folder, stdout and gains file."""
    folder = tmp_path_factory.mktemp("tune")
    before = _git_status()
    out = run_example("tune_optuna.py", "--trials", "16", "--eval-seeds", "3", "--out", "out",
                      cwd=folder)  # fmt: skip
    assert _git_status() == before, "tune_optuna.py wrote into the repository"
    return folder, out, folder / "out" / "test2" / "optuna.json"


def test_tune_optuna(tuned):
    folder, out, gains = tuned
    for line in (
        "test2: 16 Optuna trials",
        "gains: P=",
        "held-out seeds",
        "margins with the servo",
    ):
        assert line in out, out
    assert "wrote out/test2/optuna.json" in out
    assert json.loads(gains.read_text())["format"] == "gripper-gains"
    assert [p.name for p in folder.iterdir()] == ["out"]  # only where it was told


def test_deploy_virtual_paper_gains(tmp_path, checkout_unchanged):
    out = run_example("deploy_virtual.py", cwd=tmp_path)
    assert "the paper's tuned gains on test2 are stable" in out, out
    assert "complete True" in out and "to the simulation's prediction" in out, out
    assert not list(tmp_path.iterdir()), "wrote files without being asked to"


def test_deploy_virtual_tuned_gains_file(tuned, tmp_path, checkout_unchanged):
    out = run_example("deploy_virtual.py", "--gains", str(tuned[2]), cwd=tmp_path)
    assert "optuna.json on test2 are stable" in out and "complete True" in out, out


def test_identify(tmp_path, checkout_unchanged):
    out = run_example("identify.py", cwd=tmp_path)
    assert "identified: (" in out and "fit on a validation record: identified" in out, out
    assert not list(tmp_path.iterdir()), "wrote files without being asked to"


def test_joint_mujoco(tmp_path, checkout_unchanged):
    """The SO-101 elbow identified on the virtual bus, tuned, exported and run in MuJoCo: no
    packet to another joint, the payload found, the exact runtime within a tick of the virtual
    servo, and the plot written."""
    pytest.importorskip("mujoco")
    out = run_example("joint_mujoco.py", "--trials", "20", "--polish", "20", "--out", "out",
                      cwd=tmp_path)  # fmt: skip
    assert "packets to the other joints: 0" in out
    rms = re.search(r"exact runtime ([\d.]+) deg, native class ([\d.]+) deg", out)
    assert rms and float(rms.group(1)) < 0.088, out
    assert (tmp_path / "out" / "joint_mujoco.png").stat().st_size > 10_000


def test_train_rl(tmp_path, checkout_unchanged):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("torch")
    out = run_example("train_rl.py", "--timesteps", "512", "--episodes", "1", cwd=tmp_path)
    assert "trained PPO on gripper_env/GripperServo-v0" in out and "zero action: return" in out
    assert not list(tmp_path.iterdir()), "wrote files without being asked to"


def test_notebook_is_committed_without_outputs():
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.read(EXAMPLES / "quickstart.ipynb", as_version=4)
    nbformat.validate(nb)
    assert nb.nbformat == 4
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, "clear the outputs"


def test_notebook_executes(tmp_path, monkeypatch, checkout_unchanged):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    nb = nbformat.read(EXAMPLES / "quickstart.ipynb", as_version=4)
    # the kernel is this interpreter, running this checkout's code (not an installed copy)
    nb.cells.append(
        nbformat.v4.new_code_cell(
            "import sys, gripper_env\nprint(sys.executable, gripper_env.__file__)"
        )
    )
    for key, value in _env().items():
        monkeypatch.setenv(key, value)
    monkeypatch.delenv("MPLBACKEND")  # the kernel's inline backend: figures become outputs
    client = nbclient.NotebookClient(
        nb, timeout=120, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()  # raises CellExecutionError on the first failing cell

    def text(cell) -> str:
        return "".join(o.get("text", "") for o in cell.outputs if o.output_type == "stream")

    where = text(nb.cells[-1]).split()
    assert Path(where[0]).resolve() == Path(sys.executable).resolve()
    assert Path(where[1]).resolve().is_relative_to(ROOT)
    out = "".join(text(c) for c in nb.cells if c.cell_type == "code")
    assert "Optuna: P=" in out and "paper (tuned)" in out, out
    figures = [
        o for c in nb.cells for o in c.get("outputs", []) if "image/png" in o.get("data", {})
    ]
    assert len(figures) == 2
    assert not list(tmp_path.iterdir()), "the notebook wrote files"
