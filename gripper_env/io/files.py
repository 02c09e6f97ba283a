"""Writing files so that a reader never sees half of one: the project's one atomic writer.

Every command that leaves a result behind (gains files, logs, reports, plant files, presets,
figures) writes through :func:`write_atomic`: a temporary file in the same folder, then
:func:`os.replace`, which is atomic on the same file system. An interrupted write leaves the old
file (or none), never a truncated one. On top of it, one of each flavour: :func:`write_json`
(indented, numpy values made plain, non-finite numbers as ``null``), :func:`write_csv` (numeric
columns under a header line, 6 decimals) and :func:`save_figure` (a matplotlib figure, without
version or date, so the same figure gives the same bytes).

Provenance (the commit, date, version, machine, command line and wall time of a run) is kept
apart from the results, in one sidecar per run, ``<name>.provenance.json``
(:func:`write_provenance`): every command that writes results opens
:func:`collect_provenance` around its writes, and :func:`write_result_json` moves the volatile
values of a JSON result (:data:`VOLATILE_KEYS`) into that sidecar. The results then depend on
the numbers only: a rerun that reproduces them leaves every file, the sidecar included, as it
was (the sidecar stays the one of the run that first wrote them).

Logs that grow while a run goes (the rig's telemetry) are the exception: they are written under
a ``.partial`` name and renamed when complete
(:class:`gripper_env.hardware.host.experiment.CsvLog`).
"""

from __future__ import annotations

import contextlib
import contextvars
import datetime as _dt
import io
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.config import MAX_DATA_BYTES, ConfigError, read_bounded

__all__ = [
    "MAX_NAME_CHARS",
    "PROVENANCE_FORMAT",
    "VOLATILE_KEYS",
    "ProvenanceRun",
    "collect_provenance",
    "git_commit",
    "json_ready",
    "path_in",
    "provenance_path",
    "read_format_json",
    "record_provenance",
    "result_json_text",
    "run_facts",
    "safe_name",
    "save_figure",
    "split_volatile",
    "write_atomic",
    "write_csv",
    "write_group",
    "write_json",
    "write_provenance",
    "write_result_json",
    "write_together",
]


def json_ready(obj: Any) -> Any:
    """Plain JSON values: numpy scalars and arrays to Python, non-finite floats to ``None``."""
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


#: The process's file-creation mask, read once at import (``os.umask`` can only be read by
#: setting it, which is not thread-safe later): files are created ``0o666 & ~umask``, as
#: ``open()`` would, not ``0o600`` as :func:`tempfile.mkstemp` makes them.
_UMASK = os.umask(0o022)
os.umask(_UMASK)

#: Characters a name from a file may not hold when it becomes part of a path: separators,
#: NUL and the other control characters.
_UNSAFE = frozenset("/\\" + "".join(map(chr, range(32))) + "\x7f")
#: Longest name accepted as one path component (file systems allow 255 bytes; a suffix is added).
MAX_NAME_CHARS = 100


def safe_name(name: object, what: str = "name") -> str:
    """``name`` if it can be one component of a path, else a :class:`ValueError` naming it.

    The one rule for names read from files or typed by a user (a plant's ``name:``, a gains
    file's ``tuner``, ``--name``) before they become part of a path: a non-empty string of at
    most :data:`MAX_NAME_CHARS` characters, with no ``/``, ``\\``, NUL or other control
    character, not ``.`` or ``..``, not starting with ``-`` (it would read as an option) or
    ``~``. So a name can never climb out of the folder it is joined to, or be absolute.

    Parameters
    ----------
    name : object
        The name.
    what : str
        What it names, for the message (``"plant name"``).

    Raises
    ------
    ValueError
        One line that quotes the name and says what is wrong with it.
    """
    text = name if isinstance(name, str) else None
    why = None
    if text is None:
        why = f"must be a string, got {type(name).__name__}"
    elif not text or not text.strip():
        why = "is empty"
    elif len(text) > MAX_NAME_CHARS:
        why = f"is longer than {MAX_NAME_CHARS} characters"
    elif text in (".", ".."):
        why = "is not a name"
    elif any(c in _UNSAFE for c in text):
        why = "holds a path separator or a control character"
    elif text[0] in "-~":
        why = f"starts with {text[0]!r}"
    if why is not None:
        shown = repr(name)[: MAX_NAME_CHARS + 20]
        raise ValueError(
            f"{what} {shown} {why}: a name becomes a file or folder name, so it must be one "
            "plain path component (letters, digits, '-', '_', '.', '+')"
        )
    assert text is not None
    return text


def path_in(folder: str | os.PathLike[str], *names: str, what: str = "name") -> Path:
    """``folder/names[0]/names[1]/...``, every name checked by :func:`safe_name` first."""
    return Path(folder).joinpath(*(safe_name(n, what) for n in names))


def _mode_for(p: Path) -> int:
    """Permission bits of a new file at ``p``: those of the file it replaces, else the umask's."""
    try:
        return p.stat().st_mode & 0o7777
    except OSError:
        return 0o666 & ~_UMASK


def _stage(p: Path, data: bytes) -> str:
    """Write ``data`` to a temporary file beside ``p``; its path."""
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), _mode_for(p))
            f.write(data)
    except OSError as exc:  # a full disk: named by the file it was for, not the temporary one
        Path(tmp).unlink(missing_ok=True)
        raise OSError(exc.errno, exc.strerror or str(exc), str(p)) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return tmp


def _bytes(data: str | bytes) -> bytes:
    return data if isinstance(data, bytes) else data.encode("utf-8")


def write_atomic(path: str | os.PathLike[str], data: str | bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and ``os.replace``.

    The file is written whole or not at all: on a full disk (or any error) the old file, or
    none, stays, and no temporary file is left. A new file gets the permissions ``open()`` would
    give it (``0o666`` less the umask); a replaced one keeps its own.

    Parameters
    ----------
    path : str or PathLike
        Destination; missing parent folders are created.
    data : str or bytes
        Text (written as UTF-8, newlines untranslated) or bytes.

    Returns
    -------
    Path
        ``path``.
    """
    return write_together({path: data})[0]


def write_together(files: Mapping[str | os.PathLike[str], str | bytes]) -> list[Path]:
    """Write several files all or none: each to a temporary file first, then all renamed.

    A renaming needs no space, so a full disk (or a folder that cannot be written) fails while
    the temporary files are written, before any destination changes: a gains file is never left
    without its plot, nor a plot without its gains file. Text is written as UTF-8.

    Parameters
    ----------
    files : mapping
        ``{path: str or bytes}``, written in this order.

    Returns
    -------
    list of Path
        The paths, in order.
    """
    items = [(Path(path), _bytes(data)) for path, data in dict(files).items()]
    group = _GROUP.get()
    staged: list[tuple[str, Path, bytes]] = []
    try:
        for p, data in items:
            staged.append((_stage(p, data), p, data))
    except BaseException:
        _discard(staged)
        raise
    run = _RUN.get()
    if run is not None:  # compared with what the destinations hold before they change
        for _, p, data in staged:
            run.wrote(p, data)
    if group is not None:  # renamed when the group's block ends
        group.extend(staged)
    else:
        _commit(staged)
    return [p for p, _ in items]


def _discard(staged: list[tuple[str, Path, bytes]]) -> None:
    for tmp, _, _ in staged:
        Path(tmp).unlink(missing_ok=True)


def _commit(staged: list[tuple[str, Path, bytes]]) -> None:
    for i, (tmp, p, _data) in enumerate(staged):
        try:
            os.replace(tmp, p)
        except BaseException:
            _discard(staged[i:])
            raise


_GROUP: contextvars.ContextVar[list[tuple[str, Path, bytes]] | None] = contextvars.ContextVar(
    "write_group", default=None
)


@contextlib.contextmanager
def write_group() -> Iterator[None]:
    """Every file written in the block (:func:`write_atomic` and what calls it) appears when the
    block ends, all together, or none does: a result and its plot, a report and its figures.

    Inside the block the files are written beside their destinations under temporary names;
    when the block ends without an exception they are renamed (renaming needs no space), and
    on an exception (a full disk, Ctrl-C) they are deleted and every destination keeps what it
    held. A file written in the block is therefore not readable at its path until the block
    ends. Groups nest: an inner group's files wait for the outer one.
    """
    if _GROUP.get() is not None:
        yield
        return
    staged: list[tuple[str, Path, bytes]] = []
    token = _GROUP.set(staged)
    try:
        yield
    except BaseException:
        _discard(staged)
        raise
    finally:
        _GROUP.reset(token)
    _commit(staged)


def write_json(path: str | os.PathLike[str], obj: Any, indent: int = 2) -> Path:
    """Write ``obj`` (made :func:`json_ready`) as indented JSON, atomically.

    The same content gives the same bytes: keys in the order the content was built (the
    writers build it in a fixed order), floats as Python's shortest round-trip ``repr``,
    non-finite numbers as ``null``, a newline at the end.

    Raises
    ------
    ValueError
        ``obj`` holds something JSON cannot represent.
    """
    text = json.dumps(json_ready(obj), indent=indent, allow_nan=False)
    return write_atomic(path, text + "\n")


#: Keys whose values change from run to run when the results do not (who ran it, when, how
#: long): :func:`write_result_json` moves them, at any depth, to the run's provenance sidecar.
VOLATILE_KEYS = frozenset(
    {
        "git_commit",
        "date",
        "python",
        "wall_time_s",
        "train_wall_time_s",
        "search_wall_time_s",
        "elapsed_s",
    }
)

#: The ``format`` of a provenance sidecar.
PROVENANCE_FORMAT = "gripper-provenance"

#: Libraries whose versions a sidecar records when the run loaded them.
_LIBRARIES = (
    "numpy", "scipy", "numba", "matplotlib", "gymnasium", "stable_baselines3", "torch",
    "optuna", "control", "pydantic", "rl_zoo3", "mujoco",
)  # fmt: skip


def split_volatile(obj: Any, where: str = "") -> tuple[Any, dict[str, Any]]:
    """``obj`` without any :data:`VOLATILE_KEYS` entry (at any depth), and what was taken out
    as ``{JSON pointer: value}``."""
    taken: dict[str, Any] = {}
    if isinstance(obj, dict):
        out = {}
        for key, value in obj.items():
            pointer = f"{where}/{key}"
            if key in VOLATILE_KEYS:
                taken[pointer] = value
                continue
            out[key], more = split_volatile(value, pointer)
            taken.update(more)
        return out, taken
    if isinstance(obj, list):
        items = []
        for i, value in enumerate(obj):
            item, more = split_volatile(value, f"{where}/{i}")
            items.append(item)
            taken.update(more)
        return items, taken
    return obj, taken


def _run_name(path: Path) -> str:
    """The name of a result's own run: ``x.json`` (or ``x.md``, ``x``) -> ``x``."""
    return path.stem if path.suffix else path.name


def _sidecar(out_dir: str | os.PathLike[str], name: str) -> Path:
    return Path(out_dir) / f"{name}.provenance.json"


def provenance_path(path: str | os.PathLike[str]) -> Path:
    """``x.json`` (or ``x.md``, ``x``) -> ``x.provenance.json``: a result's sidecar."""
    p = Path(path)
    return _sidecar(p.parent, _run_name(p))


def git_commit() -> str | None:
    """The commit of the project's checkout this code runs from (``None`` outside git)."""
    out = _git("rev-parse", "HEAD")
    return out.strip() or None if out is not None else None


def _git(*args: str) -> str | None:
    try:
        return subprocess.run(
            ["git", *args], cwd=Path(__file__).resolve().parent, capture_output=True, text=True,
            timeout=10, check=True,
        ).stdout  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return None


def run_facts() -> dict[str, Any]:
    """Who ran, where and when: the project's version and commit (``git_dirty``: with changes
    not committed, to tracked files), Python, the machine, the versions of the libraries the run
    loaded, the date (UTC) and the process's ``argv``."""
    from gripper_env._version import __version__

    status = _git("status", "--porcelain", "--untracked-files=no")
    libraries = {}
    for name in _LIBRARIES:
        module = sys.modules.get(name)
        if module is not None and isinstance(getattr(module, "__version__", None), str):
            libraries[name] = module.__version__
    return {
        "version": __version__,
        "git_commit": git_commit(),
        "git_dirty": None if status is None else bool(status.strip()),
        "python": platform.python_version(),
        "machine": {
            "system": platform.system(),
            "release": platform.release(),
            "arch": platform.machine(),
            "cpus": os.cpu_count(),
        },
        "libraries": libraries,
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "argv": list(sys.argv),
    }


def write_provenance(
    out_dir: str | os.PathLike[str],
    name: str,
    *,
    command: str | None = None,
    wall_time_s: float | None = None,
    files: dict[str, dict[str, Any]] | None = None,
    **extra: Any,
) -> Path:
    """Write a run's provenance sidecar, ``<out_dir>/<name>.provenance.json``: the command,
    :func:`run_facts`, the wall time, ``extra`` facts of the command (load averages, thread
    counts, ...) and ``files``: the volatile values taken out of each result file
    (``{path relative to out_dir: {JSON pointer: value}}``, :func:`write_result_json`).

    The one place where a result's commit, date, version, machine and wall time are written:
    the result files themselves hold none of them, so that a rerun with the same numbers leaves
    them byte for byte unchanged.
    """
    record = {
        "format": PROVENANCE_FORMAT,
        "command": command,
        **run_facts(),
        "wall_time_s": wall_time_s,
        **extra,
        "files": dict(sorted((files or {}).items())),
    }
    return write_json(_sidecar(out_dir, name), record)


@dataclass
class ProvenanceRun:
    """What :func:`collect_provenance` gathers while its block runs."""

    root: Path
    #: volatile values per result file (path relative to ``root``)
    files: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: facts of the command for the sidecar (:func:`write_provenance`'s ``extra``)
    extra: dict[str, Any] = field(default_factory=dict)
    written: int = 0
    changed: bool = False

    def key(self, path: str | os.PathLike[str]) -> str:
        p = Path(path).resolve()
        try:
            return p.relative_to(self.root.resolve()).as_posix()
        except ValueError:
            return str(p)

    def wrote(self, path: Path, data: bytes) -> None:
        """Note a file written in the block and whether its bytes differ from the old file."""
        self.written += 1
        if not self.changed:
            try:
                same = path.stat().st_size == len(data) and path.read_bytes() == data
            except OSError:
                same = False
            self.changed = not same


_RUN: contextvars.ContextVar[ProvenanceRun | None] = contextvars.ContextVar(
    "provenance_run", default=None
)


@contextlib.contextmanager
def collect_provenance(
    out_dir: str | os.PathLike[str],
    name: str,
    *,
    command: str | None = None,
    started: float | None = None,
    own: bool = False,
    **extra: Any,
) -> Iterator[ProvenanceRun]:
    """One provenance sidecar for everything written inside the block (one per run):
    ``<out_dir>/<name>.provenance.json`` (:func:`write_provenance`), written when the block
    ends without an exception. ``started`` (:func:`time.perf_counter`) is when the run began
    (default: when the block does); ``extra`` and the yielded run's ``extra`` are the command's
    own facts.

    Inside another run's block the block adds to that run (one sidecar, the outer one's),
    unless ``own`` (a task's scratch folder whose files are sent back to the run that started
    it: :func:`tuners.engine.write_files`).

    A rerun whose files are byte for byte those on disk keeps the sidecar that is there (those
    files are the earlier run's results, reproduced; the sidecar is only touched), so that
    rerunning a command that reproduces its numbers leaves ``git diff`` empty.

    Inside a :func:`write_group` (``with write_group(), collect_provenance(...)``) the sidecar
    is one of the group's files: the results and their provenance appear together or not at
    all (a full disk left a result and its plot without their sidecar).
    """
    outer = _RUN.get()
    if outer is not None and not own:
        outer.extra.update(extra)
        yield outer
        return
    start = time.perf_counter() if started is None else started
    run = ProvenanceRun(Path(out_dir), extra=dict(extra))
    token = _RUN.set(run)
    try:
        yield run
    finally:
        _RUN.reset(token)
    sidecar = _sidecar(out_dir, name)
    token = _RUN.set(None)  # the sidecar is no file of an enclosing run
    try:
        if run.written and not run.changed and sidecar.is_file():
            os.utime(sidecar)
        else:
            write_provenance(out_dir, name, command=command,
                             wall_time_s=time.perf_counter() - start, files=run.files,
                             **run.extra)  # fmt: skip
    finally:
        _RUN.reset(token)


def record_provenance(path: str | os.PathLike[str], volatile: dict[str, Any]) -> None:
    """Put the volatile values taken out of the result at ``path`` into the run's sidecar
    (:func:`collect_provenance`); outside a run, into a sidecar of its own
    (:func:`provenance_path`)."""
    if not volatile:
        return
    run = _RUN.get()
    if run is not None:
        run.files.setdefault(run.key(path), {}).update(volatile)
        return
    p = Path(path)
    write_provenance(p.parent, _run_name(p), files={p.name: volatile})


def write_result_json(path: str | os.PathLike[str], obj: Any, indent: int = 2) -> Path:
    """Write a result as :func:`write_json` does, its volatile values (commit, date, wall
    times: :data:`VOLATILE_KEYS`) apart, in the run's provenance sidecar
    (:func:`collect_provenance`; outside a run, in a sidecar of its own,
    :func:`provenance_path`). A rerun with equal numbers then leaves the file byte for byte
    unchanged."""
    p = Path(path)
    stable, volatile = split_volatile(json_ready(obj))
    # inside a run, its sidecar; outside, a run of this one file
    own = _RUN.get() is None
    with collect_provenance(p.parent, _run_name(p)) if own else contextlib.nullcontext():
        record_provenance(p, volatile)
        return write_json(p, stable, indent)


def result_json_text(obj: Any, indent: int = 2) -> str:
    """The text :func:`write_result_json` writes for ``obj`` (its volatile values apart): what a
    command prints for its own result, not the file read back, which a concurrent run of the same
    command may have replaced meanwhile."""
    stable, _volatile = split_volatile(json_ready(obj))
    return json.dumps(json_ready(stable), indent=indent, allow_nan=False) + "\n"


def read_format_json(
    path: str | os.PathLike[str],
    fmt: str,
    what: str,
    error: type[Exception] = ValueError,
    option: str | None = None,
) -> dict[str, Any]:
    """Read a JSON object that declares ``"format": fmt`` (a gains file, a calibration).

    Parameters
    ----------
    path : str or PathLike
        The file.
    fmt : str
        The value its ``format`` key must have (``"gripper-gains"``).
    what : str
        What the file is, for the messages (``"gains file"``).
    error : exception class
        Raised, with a one-line message that names the file, when the file cannot be read, is
        larger than :data:`gripper_env.io.config.MAX_DATA_BYTES`, is not JSON, or is not of that
        format.
    option : str, optional
        The command-line option that named the file, first in a refusal of its kind or size.
    """
    p = Path(path)
    try:
        if p.is_dir():
            raise error(f"{p}: is a folder; give a {what}")
        if not p.exists():
            raise error(f"cannot read {what} {p}: No such file or directory")
        try:  # a pipe or a device refused unopened, a large file before a byte is read
            raw = read_bounded(p, MAX_DATA_BYTES, what, option)
        except ConfigError as exc:
            raise error(str(exc)) from None
        content = json.loads(raw.decode("utf-8"))
    except OSError as exc:
        raise error(f"cannot read {what} {p}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise error(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError:
        raise error(f"{p}: not a text (UTF-8) file") from None
    except RecursionError:
        raise error(f"{p}: not a {what} (nested too deeply)") from None
    if not isinstance(content, dict) or content.get("format") != fmt:
        raise error(f'{p}: not a {what} (expected "format": "{fmt}")')
    return content


def write_csv(
    path: str | os.PathLike[str],
    columns: Sequence[str],
    data: np.ndarray,
    fmt: str = "%.6f",
) -> Path:
    """Write numeric columns as CSV under a header line, atomically.

    Parameters
    ----------
    path : str or PathLike
        Destination.
    columns : sequence of str
        Header (column names, with their units: ``t_s``, ``position_deg``).
    data : ndarray (n, len(columns))
        Rows; NaN is written as ``nan``.
    fmt : str
        ``printf`` format of every value (default 6 decimals: 1 us, 1e-6 deg).
    """
    data = np.asarray(data, dtype=float)
    if data.ndim != 2 or data.shape[1] != len(columns):
        raise ValueError(f"{path}: {len(columns)} columns named, data of shape {data.shape}")
    buf = io.StringIO()
    np.savetxt(buf, data, delimiter=",", header=",".join(columns), comments="", fmt=fmt)
    return write_atomic(path, buf.getvalue())


def save_figure(
    fig: Any,
    path: str | os.PathLike[str],
    dpi: float = 110,
    palette: bool = True,
    **savefig_kwargs: Any,
) -> Path:
    """Render a matplotlib figure to ``path`` atomically, then close it.

    The same figure gives the same bytes: no software version or date in the file (PNG text
    chunks, PDF and SVG dates).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or PathLike
        Destination; its suffix is the format (``.png`` when it has none).
    dpi : float
        Resolution (dots per inch).
    palette : bool
        PNG: an opaque figure is stored with at most 256 colours (median cut, no dithering,
        maximum compression): line plots look the same at about a third of the size. False
        keeps every colour.
    **savefig_kwargs
        More options of :meth:`~matplotlib.figure.Figure.savefig` (``bbox_inches="tight"``).
    """
    import matplotlib
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    metadata = {"png": {"Software": None}, "pdf": {"CreationDate": None, "Producer": None},
                "svg": {"Date": None}}.get(fmt)  # fmt: skip
    if metadata is not None:
        savefig_kwargs.setdefault("metadata", metadata)
    try:  # an SVG's element ids from a fixed salt, not from the process
        with matplotlib.rc_context({"svg.hashsalt": "gripper-env"}):
            fig.savefig(buf, dpi=dpi, format=fmt, **savefig_kwargs)
    finally:
        plt.close(fig)
    data = buf.getvalue()
    if fmt == "png":
        data = _compact_png(data, dpi, palette)
    return write_atomic(path, data)


def _compact_png(data: bytes, dpi: float, palette: bool) -> bytes:
    """The PNG again, with no text chunks, maximum compression and, with ``palette`` and no
    transparency, at most 256 colours."""
    from PIL import Image

    with Image.open(io.BytesIO(data)) as image:
        image.load()
        im = image
        if palette and im.mode == "RGBA" and im.getextrema()[3][0] == 255:
            im = im.convert("RGB")
        if palette and im.mode == "RGB":
            im = im.quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                             dither=Image.Dither.NONE)  # fmt: skip
        out = io.BytesIO()
        im.save(out, format="png", optimize=True, dpi=(dpi, dpi))
    return out.getvalue()
