"""Loading and validating configuration files (YAML) with errors that name the file and the key.

Configuration is data: plants, disturbance presets, tuner and benchmark settings. The files that
ship with the project live in the top-level ``configs/`` folder of the source tree, installed as
the package ``gripper_env.configs`` and read through :mod:`importlib.resources`, so a wheel
finds them wherever it is installed (:data:`SHIPPED`).

A name (``"test2"``, ``"mine"``) is looked up first in the user's folder: the one the
``GRIPPER_CONFIG_DIR`` environment variable names, if it is set, else ``runs/configs`` of the
working folder (:data:`USER_CONFIG_DIR`, where identification saves a plant file and a preset by
default); same layout: ``plants/``, ``disturbances/``, ``tuners/``, ``objective.yaml``,
``benchmark.yaml``, any of them may be missing. Then in the shipped configurations. A path
(``my/plant.yaml``) is read as it is. Every file is validated
once, on load, by a pydantic model; a problem is reported as a :class:`ConfigError` that names
the file and the offending key. Hostile files are refused before they cost time or memory: a
file larger than :data:`MAX_CONFIG_BYTES` before it is read, one nested deeper than
:data:`MAX_CONFIG_DEPTH` or expanding to more than :data:`MAX_CONFIG_NODES` values before
anything is built from it (data files: :data:`MAX_DATA_BYTES`, :func:`read_bounded`).
"""

from __future__ import annotations

import os
import stat
from importlib.resources import files
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

__all__ = [
    "CONFIG_DIR",
    "MAX_CONFIG_BYTES",
    "MAX_CONFIG_DEPTH",
    "MAX_CONFIG_NODES",
    "MAX_DATA_BYTES",
    "SHIPPED",
    "USER_CONFIG_DIR",
    "ConfigError",
    "available",
    "check_input",
    "config_file",
    "find_config",
    "load_yaml",
    "read_bounded",
    "user_config_dir",
    "validate",
]


def _shipped() -> Traversable:
    try:
        return files("gripper_env.configs")
    except ModuleNotFoundError:
        # a source tree used without installing it (PYTHONPATH=.), or an editable install made
        # before configs/ became a package: the folder beside the package
        return Path(__file__).resolve().parents[2] / "configs"


#: The configurations shipped in the package (``gripper_env.configs``).
SHIPPED: Traversable = _shipped()
#: Where names are looked up first: the folder in ``GRIPPER_CONFIG_DIR``, else :data:`SHIPPED`.
CONFIG_DIR: Traversable = (
    Path(os.environ["GRIPPER_CONFIG_DIR"]) if os.environ.get("GRIPPER_CONFIG_DIR") else SHIPPED
)
#: The user's own configurations when ``GRIPPER_CONFIG_DIR`` is not set: ``runs/configs`` of the
#: working folder, beside the runs (not committed), searched before the shipped files. Where
#: ``python -m tuners.sysid greybox --save-plant`` and ``--save-disturbance`` write by default.
USER_CONFIG_DIR = Path("runs") / "configs"

M = TypeVar("M", bound=BaseModel)


class ConfigError(ValueError):
    """A configuration file or value is missing, malformed or out of range."""


#: Largest configuration file read (bytes). The shipped ones hold a few kB; the size is checked
#: before parsing, which is slow (pure-Python YAML: about 1 s per MB) and memory-hungry.
MAX_CONFIG_BYTES = 1 << 20
#: Deepest nesting of lists and mappings in a configuration file (the shipped ones: 4).
MAX_CONFIG_DEPTH = 32
#: Most values (scalars, lists, mappings) a configuration file may expand to, aliases counted
#: at their expanded size (a "billion laughs" file is a few lines).
MAX_CONFIG_NODES = 100_000
#: Largest data file read whole (bytes): logs and reference profiles (CSV), gains files (JSON).
#: Ten minutes of a 1 kHz log take about 25 MB; parsing one costs about 1 s and 30 MB of memory
#: per MB.
MAX_DATA_BYTES = 32 << 20

_LOADER: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser, if present


def _size(n_bytes: float) -> str:
    return f"{n_bytes / 2**20:.3g} MiB" if n_bytes >= 2**20 else f"{n_bytes / 2**10:.3g} KiB"


#: What a path that is not a regular file is, for the refusals (:func:`check_input`).
_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _kind(mode: int) -> str:
    return next((text for test, text in _KINDS if test(mode)), "not a regular file")


def _file(what: str) -> str:
    return what if what.endswith("file") else f"{what} file"


def _source(path: object, option: str | None) -> str:
    return f"{option} {path}" if option else f"{path}"


def check_input(
    path: str | os.PathLike[str],
    limit_bytes: int,
    what: str,
    option: str | None = None,
    *,
    folder: bool = False,
    missing_ok: bool = False,
) -> os.stat_result | None:
    """Refuse an input before a byte of it is read: the one check every reader of a user's file
    goes through (:func:`read_bounded` for what it reads itself; Optuna's storages, agent
    folders and logs through this).

    A named pipe, a device (``/dev/zero``), a socket or a folder where a file is expected (a
    file where a folder is, with ``folder=True``) is refused from its ``stat`` alone, without
    opening it (opening a FIFO blocks until a writer comes; a device never ends); a file larger
    than ``limit_bytes`` (for a folder: the files in it, one level deep, together) from its size.

    Parameters
    ----------
    path : str or PathLike
    limit_bytes : int
        The most the input may hold (bytes).
    what : str
        What the input is, for the message (``"journal storage"``).
    option : str, optional
        The command-line option that named it (``"--storage"``), first in the message.
    folder : bool
        The input is a folder (an agent's).
    missing_ok : bool
        A path that does not exist yet is accepted (``None``): a storage to create.

    Returns
    -------
    os.stat_result or None
        The input's status; ``None`` for a missing one with ``missing_ok``.

    Raises
    ------
    ConfigError
        One line naming the option, the path and what is wrong (the cap, for a size).
    """
    source = _source(path, option)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if missing_ok:
            return None
        raise ConfigError(f"{source}: no such {'folder' if folder else 'file'}") from None
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    if folder:
        if not stat.S_ISDIR(st.st_mode):
            raise ConfigError(f"{source}: {_kind(st.st_mode)}, not the folder of a {what}")
        total = 0
        try:
            with os.scandir(path) as entries:
                for n, entry in enumerate(entries):
                    if n >= _MAX_FOLDER_ENTRIES:
                        raise ConfigError(
                            f"{source}: more than {_MAX_FOLDER_ENTRIES:,} entries, more than "
                            f"a {what} holds"
                        )
                    if entry.is_file(follow_symlinks=True):
                        total += entry.stat().st_size
        except OSError as exc:
            raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
        if total > limit_bytes:
            raise ConfigError(
                f"{source}: {_size(total)}, more than the {_size(limit_bytes)} a {what} may hold"
            )
        return st
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{source}: {_kind(st.st_mode)}, not a {_file(what)}")
    if st.st_size > limit_bytes:
        raise ConfigError(
            f"{source}: {_size(st.st_size)}, more than the {_size(limit_bytes)} a {what} may hold"
        )
    return st


#: Entries a folder input may list (an agent's folder holds a handful).
_MAX_FOLDER_ENTRIES = 10_000


def read_bounded(
    path: Path | Traversable, limit_bytes: int, what: str, option: str | None = None
) -> bytes:
    """The bytes of ``path``, refused before reading if it is not a regular file or holds more
    than ``limit_bytes`` (:func:`check_input`).

    Raises
    ------
    ConfigError
        The file is larger than ``limit_bytes`` (the message names the option, the file, its
        size and the limit), is a pipe, a device or a folder, or cannot be read.
    """
    if not isinstance(path, Path):  # a packaged file: no stat, read at most the limit
        try:
            with path.open("rb") as f:
                data = f.read(limit_bytes + 1)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
        if len(data) > limit_bytes:
            raise ConfigError(f"{path}: more than the {_size(limit_bytes)} a {what} may hold")
        return data
    check_input(path, limit_bytes, what, option)
    source = _source(path, option)
    try:
        # O_NONBLOCK: a path swapped for a FIFO since the check opens at once instead of
        # waiting for a writer; fstat then refuses it.
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if not stat.S_ISREG(st.st_mode):
                raise ConfigError(f"{source}: {_kind(st.st_mode)}, not a {_file(what)}")
            data = f.read(limit_bytes + 1)
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from None
    if len(data) > limit_bytes:  # a file that grew since
        raise ConfigError(f"{source}: more than the {_size(limit_bytes)} a {what} may hold")
    return data


def _check_structure(text: str, source: object) -> None:
    """Refuse YAML nested deeper than :data:`MAX_CONFIG_DEPTH` or expanding to more than
    :data:`MAX_CONFIG_NODES` values, from its parser events (no recursion, nothing built)."""
    sizes = [0]  # expanded size of each open collection
    anchors: dict[str, int] = {}
    anchored: list[str | None] = []
    total = 0
    for event in yaml.parse(text, Loader=_LOADER):
        grown = 0
        if isinstance(event, yaml.CollectionStartEvent):
            if len(sizes) > MAX_CONFIG_DEPTH:
                line = event.start_mark.line + 1 if event.start_mark else "?"
                raise ConfigError(
                    f"{source}: nested deeper than {MAX_CONFIG_DEPTH} levels (line {line})"
                )
            sizes.append(0)
            anchored.append(event.anchor)
            grown = 1
        elif isinstance(event, yaml.CollectionEndEvent):
            inner = sizes.pop() + 1
            anchor = anchored.pop()
            if anchor is not None:
                anchors[anchor] = inner
            sizes[-1] += inner
        elif isinstance(event, yaml.ScalarEvent):
            if event.anchor is not None:
                anchors[event.anchor] = 1
            sizes[-1] += 1
            grown = 1
        elif isinstance(event, yaml.AliasEvent):
            grown = anchors.get(event.anchor or "", 1)
            sizes[-1] += grown
        total += grown
        if total > MAX_CONFIG_NODES:
            raise ConfigError(f"{source}: more than {MAX_CONFIG_NODES:,} values (aliases expanded)")


def load_yaml(path: str | os.PathLike[str] | Traversable) -> dict[str, Any]:
    """Read a YAML mapping from ``path`` (a file path, or a file of :data:`CONFIG_DIR`).

    The file's size (:data:`MAX_CONFIG_BYTES`) is checked before it is parsed, its depth
    (:data:`MAX_CONFIG_DEPTH`) and expanded size (:data:`MAX_CONFIG_NODES`) before anything is
    built from it.

    Raises
    ------
    ConfigError
        If the file does not exist, is too large or too deep, is not valid YAML, or does not
        hold a mapping.
    """
    p = path if isinstance(path, Traversable) else Path(path)
    if not p.is_file():
        if p.is_dir():
            raise ConfigError(f"{p}: is a folder; give a configuration (YAML) file")
        if isinstance(p, Path) and p.exists():
            raise ConfigError(f"{p}: not a regular file; give a configuration (YAML) file")
        raise ConfigError(f"{p}: no such configuration file")
    raw = read_bounded(p, MAX_CONFIG_BYTES, "configuration file")
    try:
        text = raw.decode("utf-8-sig")
        _check_structure(text, p)
        data = yaml.load(text, Loader=_LOADER)  # a safe loader: plain data only
    except ConfigError:
        raise
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a text (UTF-8) file") from None
    except yaml.YAMLError as exc:
        text = " ".join(str(exc).replace(' in "<unicode string>"', "").split())
        raise ConfigError(f"{p}: not valid YAML ({text})") from None
    except (ValueError, TypeError, OverflowError) as exc:  # a value no constructor takes
        raise ConfigError(f"{p}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping of keys to values, got {type(data).__name__}")
    return data


def validate(model: type[M], data: dict[str, Any], source: str) -> M:
    """Validate ``data`` against ``model``; on failure raise one :class:`ConfigError` per problem.

    Parameters
    ----------
    model : pydantic model class
        The schema.
    data : dict
        The raw mapping (from YAML, JSON or a keyword argument).
    source : str
        Where the data came from (a file path or a description), used in the message.
    """
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        problems = []
        for err in exc.errors():
            key = ".".join(str(part) for part in err["loc"]) or "<top level>"
            msg = err["msg"].removeprefix("Value error, ")
            problems.append(f"key '{key}': {msg}")
        raise ConfigError(f"{source}: " + "; ".join(problems)) from None


def user_config_dir() -> Path:
    """Where a user's own configurations go: ``GRIPPER_CONFIG_DIR`` if set, else
    :data:`USER_CONFIG_DIR` (``runs/configs`` of the working folder); searched for names before
    the shipped files."""
    if CONFIG_DIR != SHIPPED and isinstance(CONFIG_DIR, Path):
        return CONFIG_DIR
    return USER_CONFIG_DIR


def _roots() -> list[Traversable]:
    """Folders searched for a name, in order (read at call time: tests may move CONFIG_DIR):
    ``GRIPPER_CONFIG_DIR`` if set, else ``runs/configs`` if it exists; then the shipped files."""
    if CONFIG_DIR != SHIPPED:
        return [CONFIG_DIR, SHIPPED]
    return [USER_CONFIG_DIR, SHIPPED] if USER_CONFIG_DIR.is_dir() else [SHIPPED]


def config_file(*parts: str) -> Traversable:
    """A file of the configuration tree, e.g. ``config_file("tuners", "optuna.yaml")``: the first
    of :data:`CONFIG_DIR` and :data:`SHIPPED` that has it."""
    for root in _roots():
        if root.joinpath(*parts).is_file():
            return root.joinpath(*parts)
    return CONFIG_DIR.joinpath(*parts)  # missing: the error names where it was expected


def available(kind: str) -> list[str]:
    """Names of the configuration files of one kind (``"plants"``, ``"disturbances"``, ...)."""
    names: set[str] = set()
    for root in _roots():
        folder = root / kind
        if folder.is_dir():
            names.update(
                f.name[: -len(".yaml")] for f in folder.iterdir() if f.name.endswith(".yaml")
            )
    return sorted(names)


def find_config(kind: str, name_or_path: str | os.PathLike[str]) -> Traversable:
    """Resolve a configuration by name (``<kind>/<name>.yaml``, see the module docstring) or by
    path.

    Raises
    ------
    ConfigError
        If neither a file of that path nor a configuration of that name exists; the message lists
        the available names.
    """
    text = os.fspath(name_or_path)
    candidate = Path(text)
    if "\x00" in text:
        raise ConfigError(f"{kind[:-1]} {text!r}: a name or path holds no NUL character")
    if candidate.suffix in (".yaml", ".yml") or os.sep in text or "/" in text:
        if candidate.is_file():
            return candidate
        if candidate.is_dir():
            raise ConfigError(f"{kind[:-1]} file {text!r} is a folder; give a YAML file in it")
        raise ConfigError(f"{kind[:-1]} file {text!r} does not exist")
    for root in _roots():
        named = root / kind / f"{text}.yaml"
        if named.is_file():
            return named
    names = ", ".join(available(kind)) or "(none)"
    raise ConfigError(f"unknown {kind[:-1]} {text!r}; available: {names}")
