"""What every command's command line follows, whatever the command: one place to apply it.

* **Its name as typed.** Usage and errors name the program the user ran: ``gripper-optuna``
  when run as that console script, ``gripper optuna`` through the umbrella command
  (:mod:`tuners.commands`), ``python -m tuners.optuna`` otherwise (:func:`program_name`).
* **``--version``** prints the package's version and exits (:func:`add_version`).
* **One-line usage errors.** A bad option is refused in one line naming it, exit status 2
  (:class:`Parser`), like every other refusal of bad input.
* **Defaults said once.** :class:`HelpFormatter` appends ``(default: X)`` only to an option
  whose help does not already give its default, and never ``(default: None)``; a default that
  is a path is shown as given, never made absolute.
* **Light until parsed.** This module imports nothing heavy, so ``--help``, ``--version`` and
  a usage error answer in well under a second: a command builds its parser from it (and from
  :mod:`tuners.cli`'s light parts) and imports the library only after parsing. Names of
  configurations (``--plant``, ``--disturbance``, ``--profile``) are checked against the
  configuration lookup at once (:func:`check_config_names`), before the library loads.

Any command, the bus servos' included, applies them with :func:`command_parser` (a new parser)
or :func:`conform` (a parser built elsewhere, sub-commands included).
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NoReturn

__all__ = [
    "MAX_ARGUMENT_VALUES",
    "MAX_LIST_ITEMS",
    "HelpFormatter",
    "Parser",
    "add_version",
    "check_config_names",
    "command_parser",
    "conform",
    "invoked_as",
    "program_name",
    "split_list",
]

#: The most names a comma-separated list option may hold (``--plants``): every evaluation runs
#: each plant, so a list's length multiplies a run's cost (the robust task takes three).
MAX_LIST_ITEMS = 16


def split_list(value: str, option: str, cap: int = MAX_LIST_ITEMS) -> list[str]:
    """The names of the comma-separated list ``value`` of option ``option``, refused, before
    any is looked at, when it holds more than ``cap``.

    Raises
    ------
    ValueError
        One line naming the option, how many were given and the cap.
    """
    if value.count(",") >= cap:
        raise ValueError(
            f"{option}: {value.count(',') + 1} names, more than the {cap} a list may hold"
        )
    return [v.strip() for v in value.split(",") if v.strip()]


#: The name the umbrella command ran a command under (``gripper optuna``), if it did.
_INVOKED_AS: list[str] = []


class invoked_as:
    """Within the block, commands name themselves ``name`` (the umbrella command sets it)."""

    def __init__(self, name: str) -> None:
        self.name = name

    def __enter__(self) -> None:
        _INVOKED_AS.append(self.name)

    def __exit__(self, *exc: object) -> None:
        _INVOKED_AS.pop()


def program_name(module: str) -> str:
    """The program name a user typed to run ``module``.

    ``gripper optuna`` inside the umbrella command; the console script's own name when
    ``sys.argv[0]`` is one (``gripper-optuna``); else ``python -m <module>``.
    """
    if _INVOKED_AS:
        return _INVOKED_AS[-1]
    script = os.path.basename(sys.argv[0] if sys.argv and sys.argv[0] else "")
    if script.startswith("gripper") and not script.endswith(".py"):
        return script
    return f"python -m {module}"


def _version() -> str:
    from gripper_env._version import __version__

    return f"gripper-env {__version__}"


def add_version(parser: argparse.ArgumentParser) -> None:
    """Add ``--version`` (the package's version, then exit 0), once."""
    if any("--version" in a.option_strings for a in parser._actions):
        return
    parser.add_argument("--version", action="version", version=_version())


#: The most values an option or argument that takes a list (``nargs`` ``+`` or ``*``: record
#: files, register settings, servo IDs) may be given; comma-separated names: :data:`MAX_LIST_ITEMS`.
MAX_ARGUMENT_VALUES = 256


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line: ``prog: error: what (see prog
    --help)`` and exit status 2, like every other refusal of bad input; a list argument with
    more than :data:`MAX_ARGUMENT_VALUES` values is refused before the command uses it."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")

    def parse_known_args(  # type: ignore[override]
        self, args: Any = None, namespace: Any = None
    ) -> tuple[argparse.Namespace, list[str]]:
        parsed, extras = super().parse_known_args(args, namespace)
        for action in self._actions:
            value = getattr(parsed, action.dest, None)
            if action.nargs in ("+", "*") and isinstance(value, list):
                if len(value) > MAX_ARGUMENT_VALUES:
                    name = action.option_strings[0] if action.option_strings else action.dest
                    self.error(
                        f"{name}: {len(value)} values, more than the {MAX_ARGUMENT_VALUES} a "
                        "list may hold"
                    )
        return parsed, extras


class HelpFormatter(argparse.HelpFormatter):
    """Help with each option's default said once: appended as ``(default: X)`` only when the
    help text does not mention a default already and there is one to say (not ``None``, not a
    flag's ``False``)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or "default" in text.lower()
            or default is None
            or default is argparse.SUPPRESS
            or isinstance(default, bool)
            or default == []
            or not action.option_strings
            or action.nargs == 0
        ):
            return text
        return f"{text} (default: %(default)s)"

    def _expand_help(self, action: argparse.Action) -> str:
        if isinstance(action.default, os.PathLike):  # as given: never an absolute path
            action = copy.copy(action)
            action.default = os.fspath(action.default)
        return super()._expand_help(action)


def conform(parser: argparse.ArgumentParser, module: str | None = None) -> argparse.ArgumentParser:
    """Apply the conventions to a parser built elsewhere: its program name (when ``module`` is
    given), :class:`HelpFormatter`, ``--version``; the same for its sub-commands (named
    ``<prog> <sub-command>``)."""
    old_prog = parser.prog
    if module is not None:
        parser.prog = program_name(module)
    if type(parser) is argparse.ArgumentParser:  # one-line usage errors
        parser.__class__ = Parser
    parser.formatter_class = HelpFormatter
    add_version(parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            action._prog_prefix = parser.prog
            for name, sub in action.choices.items():
                if sub.prog.startswith(old_prog):
                    sub.prog = parser.prog + sub.prog[len(old_prog) :]
                else:
                    sub.prog = f"{parser.prog} {name}"
                conform(sub)
    return parser


def command_parser(module: str, description: str, **kwargs: Any) -> argparse.ArgumentParser:
    """A new parser that follows the conventions: named as the user ran ``module``, with
    ``--version`` and :class:`HelpFormatter` (``kwargs`` go to :class:`argparse.ArgumentParser`)."""
    kwargs.setdefault("formatter_class", HelpFormatter)
    parser = Parser(prog=program_name(module), description=description, **kwargs)
    add_version(parser)
    return parser


#: Which kind of configuration each option names (an option absent from a command is skipped).
CONFIG_OPTIONS = {"plant": "plants", "disturbance": "disturbances"}


def check_config_names(args: argparse.Namespace, options: Iterable[str] = ()) -> None:
    """Refuse, before the library is imported, a configuration name that does not exist: the
    options of :data:`CONFIG_OPTIONS` that ``args`` has (and ``options``, ``dest`` names of
    comma-separated lists of plants such as ``plants``), and ``profile`` (a shipped profile's
    name or a CSV file).

    Raises
    ------
    gripper_env.io.config.ConfigError
        One line that names the option, the value and what is available.
    """
    from gripper_env.io.config import ConfigError, find_config

    def check(flag: str, kind: str, value: object) -> None:
        if not isinstance(value, str | os.PathLike):
            return
        try:
            find_config(kind, value)
        except ConfigError as exc:
            raise ConfigError(f"--{flag.replace('_', '-')}: {exc}") from None

    for dest, kind in CONFIG_OPTIONS.items():
        check(dest, kind, getattr(args, dest, None))
    for dest in options:
        value = getattr(args, dest, None)
        if isinstance(value, str):
            for name in split_list(value, f"--{dest.replace('_', '-')}"):
                check(dest, "plants", name)
    profile = getattr(args, "profile", None)
    if isinstance(profile, str | os.PathLike):
        _check_profile(os.fspath(profile))


def _check_profile(text: str) -> None:
    from gripper_env.io.config import ConfigError
    from gripper_env.model.references import PROFILES  # numpy only: already loaded

    if text in PROFILES:
        return
    path = Path(text)
    if path.suffix.lower() == ".csv":
        if path.is_dir():
            raise ConfigError(f"--profile: {text!r} is a folder; give a CSV file")
        if not path.is_file():
            raise ConfigError(f"--profile: reference CSV {text!r} does not exist")
        return
    raise ConfigError(
        f"--profile: unknown reference profile {text!r}; available: {', '.join(PROFILES)}, "
        "or a .csv file"
    )
