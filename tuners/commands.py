"""``gripper``: the one entry point that lists every command and runs it.

``gripper`` alone lists the commands; ``gripper optuna --plant test2`` runs one (the same as
``gripper-optuna --plant test2`` and ``python -m tuners.optuna --plant test2``);
``gripper list plants`` (``presets``, ``profiles``, ``servos``) lists what the configuration
lookup finds, the user's own files first. ``python -m tuners`` is the same command.

:data:`COMMANDS` is the one table of the commands: the console scripts of ``pyproject.toml``
are checked against it (``tests/tuners/test_commands.py``) and the README's command table
follows it. A command is imported only when it runs, so listing them, ``--help`` and
``--version`` answer at once.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence
from dataclasses import dataclass

from tuners.conventions import add_version, command_parser, invoked_as

__all__ = ["COMMANDS", "LISTS", "Command", "list_configs", "main"]


@dataclass(frozen=True)
class Command:
    """A command: its name under ``gripper``, its module (``python -m``), its entry point
    (``module:function``), whether it has a console script ``gripper-<name>``, and what it
    does in a line."""

    name: str
    module: str
    entry: str
    summary: str
    script: bool = True


#: Every command, in the order a user meets them.
COMMANDS: tuple[Command, ...] = (
    Command("manual", "tuners.manual", "tuners.manual:main",
            "evaluate the paper's gains, typed ones, or a gains file"),
    Command("classical", "tuners.classical", "tuners.classical.command:main",
            "textbook robust designs, each knob set under the constraints"),
    Command("optuna", "tuners.optuna", "tuners.optuna.command:main",
            "search PID gains under the robustness constraints"),
    Command("rl", "tuners.rl", "tuners.rl.command:main",
            "the RL PID tuner and the RL controller: train, export, controller, play"),
    Command("benchmark", "tuners.benchmark", "tuners.benchmark.command:main",
            "every tuner on every plant, ranked"),
    Command("grasp", "tuners.benchmark.grasp", "tuners.benchmark.grasp:main",
            "grasp and hold: force, time to grasp, overload"),
    Command("leaderboard", "tuners.benchmark.leaderboard", "tuners.benchmark.leaderboard:main",
            "print the benchmark's headline, or copy it into the README", script=False),
    Command("results", "tuners.results", "tuners.results:main",
            "list, check or regenerate the committed results/", script=False),
    Command("sysid", "tuners.sysid", "tuners.sysid:main",
            "identification from logs; the paper's Table-1 experiments"),
    Command("reproduce", "tuners.paper", "tuners.paper.command:main",
            "reproduce the paper's tables and figures"),
    Command("calibrate", "tuners.rig.calibrate", "tuners.rig.calibrate:main",
            "two-point potentiometer calibration of the board"),
    Command("record", "tuners.rig.record", "tuners.rig.record:main",
            "an open-loop identification record on the board"),
    Command("deploy", "tuners.rig.deploy", "tuners.rig.deploy:main",
            "tuned gains on the board, behind the stability gate"),
    Command("virtual-device", "tuners.rig.virtual", "tuners.rig.virtual:main",
            "a board on a pseudo-terminal (the firmware's twin, or --emulated)"),
    Command("bus-virtual", "tuners.bus.virtual", "tuners.bus.virtual:main",
            "a virtual STS3215 / XL330 / XL430 on a pseudo-terminal"),
    Command("bus-calibrate", "tuners.bus.calibrate", "tuners.bus.calibrate:main",
            "the gripper's jaw in the servo's ticks: by hand, given, or LeRobot's file"),
    Command("bus-record", "tuners.bus.record", "tuners.bus.record:main",
            "a bus servo's steps and creep at several P/I/D settings"),
    Command("bus-identify", "tuners.bus.identify", "tuners.bus.identify:main",
            "the bus servo's loop from its records"),
    Command("bus-tune", "tuners.bus.tune", "tuners.bus.tune:main",
            "integer registers under the margins and the hold"),
    Command("bus-deploy", "tuners.bus.deploy", "tuners.bus.deploy:main",
            "tuned registers on the servo behind the gate, read back, verified"),
    Command("bus-joint", "tuners.bus.joint", "tuners.bus.joint:main",
            "an arm's loaded joint: virtual arm, safe record, the load, registers against it"),
    Command("bus-export", "tuners.bus.export", "tuners.bus.export:main",
            "an identified servo as MuJoCo classes (native, exact) and their verification"),
)  # fmt: skip

#: ``gripper list KIND``: the configuration folder each kind lists (``profiles``: built in).
LISTS = {"plants": "plants", "presets": "disturbances", "profiles": None, "servos": "bus_servos"}


def _by_name() -> dict[str, Command]:
    return {c.name: c for c in COMMANDS}


def _usage() -> str:
    width = max(len(c.name) for c in COMMANDS)
    lines = [
        "usage: gripper COMMAND [ARGS...]     (gripper COMMAND --help for its options)",
        "       gripper list plants|presets|profiles|servos",
        "",
        "commands:",
    ]
    lines += [f"  {c.name:<{width}}  {c.summary}" for c in COMMANDS]
    lines.append(f"  {'list':<{width}}  the plants, presets, profiles or servos found")
    return "\n".join(lines)


def list_configs(kind: str) -> list[tuple[str, str]]:
    """``[(name, description)]`` of the plants, presets (``disturbances``), profiles or
    servos that names resolve to (the user's own folder first: :mod:`gripper_env.io.config`).

    Raises
    ------
    ValueError
        An unknown kind.
    """
    if kind not in LISTS:
        raise ValueError(f"gripper list: unknown kind {kind!r}; choose from {', '.join(LISTS)}")
    folder = LISTS[kind]
    if folder is None:
        from gripper_env.model.references import PROFILES, describe_profile

        return [(name, describe_profile(name)) for name in PROFILES]
    from gripper_env.io.config import ConfigError, available, find_config, load_yaml

    rows = []
    for name in available(folder):
        try:
            data = load_yaml(find_config(folder, name))
            about = str(data.get("description") or data.get("model") or "").strip()
        except ConfigError as exc:
            about = f"(does not load: {exc})"
        rows.append((name, " ".join(about.split())))
    return rows


def _list(argv: Sequence[str]) -> int:
    parser = command_parser("tuners list", "List the plants, presets, profiles or servos.")
    parser.prog = "gripper list"
    parser.add_argument("kind", choices=tuple(LISTS), help="what to list")
    args = parser.parse_args(list(argv))
    rows = list_configs(args.kind)
    width = max((len(n) for n, _ in rows), default=0)
    for name, about in rows:
        print(f"{name:<{width}}  {about}".rstrip())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``gripper`` (and ``python -m tuners``)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if args[0] == "--version":
        parser = command_parser("tuners", "")
        parser.prog = "gripper"
        add_version(parser)
        parser.parse_args(["--version"])
    name, rest = args[0], args[1:]
    if name == "list":
        return _list(rest)
    command = _by_name().get(name)
    if command is None:
        print(f"gripper: error: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module, _, function = command.entry.partition(":")
    entry = getattr(importlib.import_module(module), function)
    with invoked_as(f"gripper {name}"):
        return int(entry(rest) or 0)


if __name__ == "__main__":
    sys.exit(main())
