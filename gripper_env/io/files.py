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
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.config import MAX_DATA_BYTES

__all__ = [
    "PROVENANCE_FORMAT",
    "VOLATILE_KEYS",
    "ProvenanceRun",
    "collect_provenance",
    "git_commit",
    "json_ready",
    "provenance_path",
    "read_format_json",
    "record_provenance",
    "run_facts",
    "save_figure",
    "split_volatile",
    "write_atomic",
    "write_csv",
    "write_json",
    "write_provenance",
    "write_result_json",
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


def write_atomic(path: str | os.PathLike[str], data: str | bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and ``os.replace``.

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
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    run = _RUN.get()
    if run is not None:
        run.wrote(p, data if isinstance(data, bytes) else data.encode("utf-8"))
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        if isinstance(data, bytes):
            with os.fdopen(fd, "wb") as f:
                f.write(data)
        else:
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
                f.write(data)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


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
    "optuna", "control", "pydantic",
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


def read_format_json(
    path: str | os.PathLike[str], fmt: str, what: str, error: type[Exception] = ValueError
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
    """
    p = Path(path)
    try:
        if p.is_file() and p.stat().st_size > MAX_DATA_BYTES:
            raise error(f"{p}: larger than the {MAX_DATA_BYTES >> 20} MiB a {what} may hold")
        content = json.loads(p.read_text())
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
