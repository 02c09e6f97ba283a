"""The committed results: which command writes each file, and the one command that rewrites them.

Every file under ``results/`` is written by one of the commands in :data:`COMMANDS`, run from
the repository's root with ``--out results``. Users' own runs go to ``runs/`` (the commands'
default, not committed), so nothing a user runs changes the committed results.

``python -m tuners.results regenerate [NAME ...]`` runs the commands (all, or those named) one
after the other and records in ``results/manifest.json`` which files each wrote;
``python -m tuners.results adopt NAME PATH ...`` records files that command wrote when it ran
elsewhere (the benchmark in a separate checkout, for hours) and were copied here;
``python -m tuners.results check`` compares that manifest with the files git tracks under
``results/``: a file no current command writes is stale and fails the check (so does a listed
file that is missing). ``python -m tuners.results list`` prints the commands.

The benchmark trains the RL rows (hours on 2 cores); its controller studies are reused when
their settings, base gains, seeds and budgets are unchanged (:class:`tuners.rl.tuner.
RLControllerTuner`).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = ["COMMANDS", "Command", "adopt", "check", "main", "regenerate"]

RESULTS = "results"
MANIFEST = "manifest.json"


@dataclass(frozen=True)
class Command:
    """A command that writes committed results: its name and the command line (run from the
    repository's root)."""

    name: str
    argv: tuple[str, ...]
    about: str

    @property
    def line(self) -> str:
        return " ".join(shlex.quote(a) for a in self.argv)


def _py(*args: str) -> tuple[str, ...]:
    return ("python", *args)


#: The commands, in the order ``regenerate`` runs them.
COMMANDS: tuple[Command, ...] = (
    Command("paper", _py("-m", "tuners.paper", "--out", RESULTS),
            "the paper's tables and figures, reproduced"),
    Command("identification", _py("-m", "tuners.sysid", "experiments", "--simulate",
                                  "--plant", "test2", "--disturbance", "actual", "--seed", "0",
                                  "--out", RESULTS),
            "the paper's Table-1 identification experiments on the simulated gripper"),
    Command("identification-coverage", _py("-m", "tuners.sysid", "coverage", "--out",
                                           RESULTS),
            "whether identification's 95 % intervals cover known truths (synthetic records)"),
    Command("benchmark", _py("-m", "tuners.benchmark", "--out", RESULTS),
            "every tuner and learned controller on every plant: the verdict"),
    Command("bus-sts3215", _py("-m", "tuners.bus.tune", "--model", "sts3215", "--out",
                               f"{RESULTS}/bus", "--no-progress"),
            "the STS3215's registers tuned on its shipped model, beside factory and LeRobot"),
    Command("bus-xl330", _py("-m", "tuners.bus.tune", "--model", "xl330", "--out",
                             f"{RESULTS}/bus", "--no-progress"),
            "the XL330's registers tuned on its shipped model, beside the factory's"),
    Command("bus-so101-elbow", _py("-m", "tuners.bus.joint", "tune", "--joint", "elbow_flex",
                                   "--out", f"{RESULTS}/bus", "--no-progress"),
            "the SO-101 elbow's STS3215 registers against gravity and 0-100 g, beside LeRobot's"),
    Command("mujoco-sts3215", _py("-m", "tuners.bus.export", "--verify", "sts3215", "--out",
                                  f"{RESULTS}/mujoco", "--no-plot"),
            "the STS3215 exported to MuJoCo against its virtual servo, Menagerie, mujoco.sysid"),
    Command("mujoco-xl330", _py("-m", "tuners.bus.export", "--verify", "xl330", "--out",
                                f"{RESULTS}/mujoco", "--no-plot"),
            "the XL330 exported to MuJoCo against its virtual servo, Menagerie, mujoco.sysid"),
    Command("grasp", _py("-m", "tuners.benchmark.grasp", "--out", RESULTS),
            "grasp and hold: time to grasp, holding force, overload (committed gains files)"),
    Command("reference-scores", _py("-m", "tuners.rl.reference_scores", "--out", RESULTS),
            "the RL benchmark's tasks: anchors (0 and 100), the best PID, PPO and SAC over seeds"),
    Command("rl-row-squeeze", _py("-m", "tuners.rl", "evaluate",
                                  "tuners.rl.baselines:squeeze_past_contact", "--task", "grasp",
                                  "--name", "squeeze-past-contact", "--out", f"{RESULTS}/rl_rows"),
            "a hand-written grasp (a plain callable) scored on the grasp task"),
    Command("rl-row-controller", _py("-m", "tuners.rl", "evaluate",
                                     "results/rl/controller-test2/seed-0/best", "--task", "servo",
                                     "--name", "rl-controller-test2-seed-0", "--out",
                                     f"{RESULTS}/rl_rows"),
            "the committed RL controller (test2, seed 0) scored on the servo task"),
    Command("rl-row-robust-controller", _py("-m", "tuners.rl", "evaluate",
                                            "results/rl/controller-test2+test3+test4/seed-0/best",
                                            "--task", "robust", "--name",
                                            "rl-controller-robust-seed-0", "--out",
                                            f"{RESULTS}/rl_rows"),
            "the committed robust RL controller (test2-test4, seed 0) on the robust task"),
    Command("rl-leaderboard", _py("-m", "tuners.rl.leaderboard", f"{RESULTS}/rl_rows", "--out",
                                  f"{RESULTS}/rl_leaderboard.md"),
            "the RL leaderboard: the rows of results/rl_rows ranked per task"),
    Command("speed", _py("-m", "tuners.speed.core", "--repeats", "21", "--slow-repeats", "3",
                         "--envs-repeats", "11", "--out", RESULTS),
            "the simulation core's and the environments' speed"),
    Command("envs-speed-loaded", _py("-m", "tuners.speed.envs", "--loaded", "--repeats", "7",
                                     "--out", RESULTS),
            "native vector env against Sync, idle and beside two busy processes; SB3 PPO"),
    Command("schedule-speed", _py("-m", "tuners.speed.schedule", "--repeats", "31",
                                  "--out", RESULTS),
            "the core's chunk scheduling against plain prange"),
    Command("sysid-speed", _py("-m", "tuners.speed.sysid", "--repeats", "5",
                               "--greybox-repeats", "3", "--out",
                               f"{RESULTS}/sysid_speed.md"),
            "identification speed"),
    Command("hardware-speed", _py("-m", "tuners.speed.hardware", "--out", RESULTS),
            "the host-board link over the virtual device"),
    Command("firmware-speed", _py("-m", "tuners.speed.firmware", "--duration", "60",
                                  "--out", RESULTS),
            "the firmware's timing on the emulated Mega 2560"),
)  # fmt: skip


def _root() -> Path:
    here = Path(__file__).resolve().parent.parent
    if not (here / ".git").exists() and not (here / "pyproject.toml").is_file():
        raise ValueError("tuners.results works in the project's source tree (a git checkout)")
    return here


def _tracked(root: Path) -> set[str]:
    out = subprocess.run(["git", "ls-files", RESULTS], cwd=root, capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    return {line for line in out.splitlines() if line and not line.endswith(MANIFEST)}


def _ignored(root: Path, paths: list[str]) -> set[str]:
    if not paths:
        return set()
    proc = subprocess.run(["git", "check-ignore", "--stdin"], cwd=root, input="\n".join(paths),
                          capture_output=True, text=True)  # fmt: skip
    return set(proc.stdout.split())


def _stamps(root: Path) -> dict[str, int]:
    """Every file under results/ and its modification time (ns)."""
    return {str(p.relative_to(root)): p.stat().st_mtime_ns
            for p in (root / RESULTS).rglob("*") if p.is_file()}  # fmt: skip


def _written_since(root: Path, before: dict[str, int]) -> list[str]:
    """Files under results/ written since the snapshot ``before`` (new, or a changed
    modification time: not a time window, which caught the previous command's last files) and
    not ignored by git."""
    found = [path for path, ns in _stamps(root).items()
             if before.get(path) != ns and not path.endswith(MANIFEST)]  # fmt: skip
    ignored = _ignored(root, found)
    return sorted(p for p in found if p not in ignored)


def read_manifest(root: Path) -> dict[str, dict[str, object]]:
    path = root / RESULTS / MANIFEST
    if not path.is_file():
        return {}
    return json.loads(path.read_text())["commands"]


def regenerate(names: list[str] | None = None) -> dict[str, list[str]]:
    """Run the commands (all, or ``names``) and update the manifest; return what each wrote."""
    root = _root()
    chosen = [c for c in COMMANDS if not names or c.name in names]
    unknown = set(names or ()) - {c.name for c in COMMANDS}
    if unknown:
        raise ValueError(f"unknown results command(s) {sorted(unknown)}; choose from "
                         f"{', '.join(c.name for c in COMMANDS)}")  # fmt: skip
    manifest = read_manifest(root)
    wrote: dict[str, list[str]] = {}
    for c in chosen:
        print(f"[{c.name}] {c.line}", flush=True)
        before = _stamps(root)
        argv = [sys.executable, *c.argv[1:]]
        proc = subprocess.run(argv, cwd=root, env=dict(os.environ, MPLBACKEND="Agg"))
        if proc.returncode != 0:
            raise ValueError(f"{c.line} exited {proc.returncode}; the manifest keeps its old list")
        wrote[c.name] = _written_since(root, before)
        manifest[c.name] = {"command": c.line, "about": c.about, "writes": wrote[c.name]}
        _write_manifest(root, manifest)
    return wrote


def adopt(name: str, paths: list[str]) -> list[str]:
    """Record ``paths`` (files under results/, or folders of them) as written by the command
    ``name``, replacing its list: for a command run elsewhere whose output was copied here.
    Files git ignores are left out, as ``regenerate`` leaves them out."""
    root = _root()
    known = {c.name: c for c in COMMANDS}
    if name not in known:
        raise ValueError(f"unknown results command {name!r}; choose from {', '.join(known)}")
    files: list[str] = []
    for raw in paths:
        path = (root / raw).resolve()
        if not path.is_relative_to((root / RESULTS).resolve()):
            raise ValueError(f"{raw}: not under {RESULTS}/")
        if not path.exists():
            raise ValueError(f"{raw}: no such file or folder")
        found = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        files += [str(p.relative_to(root.resolve())) for p in found if p.name != MANIFEST]
    ignored = _ignored(root, files)
    wrote = sorted({f for f in files if f not in ignored})
    manifest = read_manifest(root)
    c = known[name]
    manifest[name] = {"command": c.line, "about": c.about, "writes": wrote}
    _write_manifest(root, manifest)
    return wrote


def _write_manifest(root: Path, manifest: dict[str, dict[str, object]]) -> None:
    from gripper_env.io.files import write_json

    order = {c.name: i for i, c in enumerate(COMMANDS)}
    content = {
        "about": "Every file under results/ and the command that writes it (python -m "
        "tuners.results regenerate rewrites them; check compares this list with git).",
        "commands": dict(sorted(manifest.items(), key=lambda kv: order.get(kv[0], 99))),
    }
    write_json(root / RESULTS / MANIFEST, content)


def check() -> list[str]:
    """Problems with the committed results: tracked files no command writes (stale), listed
    files that are missing, commands in the manifest that no longer exist."""
    root = _root()
    manifest = read_manifest(root)
    problems = []
    known = {c.name: c for c in COMMANDS}
    listed: dict[str, str] = {}
    for name, entry in manifest.items():
        if name not in known:
            problems.append(f"manifest names a command that no longer exists: {name}")
            continue
        if entry["command"] != known[name].line:
            problems.append(f"{name}: manifest says `{entry['command']}`, the command is now "
                            f"`{known[name].line}` (regenerate it)")  # fmt: skip
        for path in entry["writes"]:  # type: ignore[attr-defined]
            listed[path] = name
            if not (root / path).is_file():
                problems.append(f"{path}: listed for {name} but missing")
    for path in sorted(_tracked(root) - set(listed)):
        problems.append(f"{path}: tracked but written by no command (stale: remove it)")
    return problems


def main(argv: list[str] | None = None) -> int:
    """``python -m tuners.results {list, check, regenerate [NAME ...]}``."""
    parser = argparse.ArgumentParser(
        prog="python -m tuners.results",
        description="The committed results/: list the commands that write them, check them "
        "against git, or regenerate them.",
    )
    sub = parser.add_subparsers(dest="what", required=True)
    sub.add_parser("list", help="the commands and what they write")
    sub.add_parser("check", help="stale or missing files under results/")
    regen = sub.add_parser("regenerate", help="run the commands (all, or those named)")
    regen.add_argument("names", nargs="*", help=", ".join(c.name for c in COMMANDS))
    ad = sub.add_parser("adopt", help="record files a command wrote elsewhere (copied here)")
    ad.add_argument("name", help=", ".join(c.name for c in COMMANDS))
    ad.add_argument("paths", nargs="+", help="files or folders under results/")
    from tuners.conventions import conform

    args = conform(parser, "tuners.results").parse_args(argv)
    try:
        if args.what == "list":
            for c in COMMANDS:
                print(f"{c.name:16s} {c.line}\n{'':16s} {c.about}")
            return 0
        if args.what == "check":
            problems = check()
            for p in problems:
                print(p)
            print(f"{len(problems)} problem(s)" if problems else "results/ matches its manifest")
            return 1 if problems else 0
        if args.what == "adopt":
            adopted = adopt(args.name, args.paths)
            print(f"[{args.name}] {len(adopted)} files recorded in {RESULTS}/{MANIFEST}")
            return 0
        wrote = regenerate(args.names)
        for name, files in wrote.items():
            print(f"[{name}] wrote {len(files)} files")
        return 0
    except (ValueError, subprocess.CalledProcessError, OSError) as exc:
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
