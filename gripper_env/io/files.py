"""Writing files so that a reader never sees half of one: the project's one atomic writer.

Every command that leaves a result behind (gains files, logs, reports, plant files, presets,
figures) writes through :func:`write_atomic`: a temporary file in the same folder, then
:func:`os.replace`, which is atomic on the same file system. An interrupted write leaves the old
file (or none), never a truncated one. On top of it, one of each flavour: :func:`write_json`
(indented, numpy values made plain, non-finite numbers as ``null``), :func:`write_csv` (numeric
columns under a header line, 6 decimals) and :func:`save_figure` (a matplotlib figure).

Logs that grow while a run goes (the rig's telemetry) are the exception: they are written under
a ``.partial`` name and renamed when complete
(:class:`gripper_env.hardware.host.experiment.CsvLog`).
"""

from __future__ import annotations

import contextlib
import contextvars
import io
import json
import math
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.config import MAX_DATA_BYTES

__all__ = [
    "VOLATILE_KEYS",
    "collect_provenance",
    "json_ready",
    "provenance_path",
    "read_format_json",
    "record_provenance",
    "save_figure",
    "split_volatile",
    "write_atomic",
    "write_csv",
    "write_json",
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


def write_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write ``obj`` (made :func:`json_ready`) as indented JSON, atomically.

    Raises
    ------
    ValueError
        ``obj`` holds something JSON cannot represent.
    """
    return write_atomic(path, json.dumps(json_ready(obj), indent=2, allow_nan=False) + "\n")


#: Keys whose values change from run to run when the results do not (who ran it, when, how
#: long): :func:`write_result_json` moves them to a provenance sidecar.
VOLATILE_KEYS = frozenset(
    {"git_commit", "date", "python", "wall_time_s", "train_wall_time_s", "search_wall_time_s"}
)

_SINK: contextvars.ContextVar[dict[str, Any] | None] = contextvars.ContextVar(
    "provenance_sink", default=None
)


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


def provenance_path(path: str | os.PathLike[str]) -> Path:
    """``x.json`` -> ``x.provenance.json``: where a result's volatile provenance goes."""
    p = Path(path)
    return p.with_name(f"{p.stem}.provenance{p.suffix or '.json'}")


def write_result_json(path: str | os.PathLike[str], obj: Any) -> Path:
    """Write a result as :func:`write_json` does, its volatile provenance (commit, date, wall
    times: :data:`VOLATILE_KEYS`) apart: into the sink of an enclosing
    :func:`collect_provenance`, else into :func:`provenance_path`. A rerun with equal numbers
    then leaves the result file byte for byte unchanged."""
    stable, volatile = split_volatile(json_ready(obj))
    record_provenance(path, volatile)
    return write_json(path, stable)


def record_provenance(path: str | os.PathLike[str], volatile: dict[str, Any]) -> None:
    """Put a result's volatile provenance where :func:`write_result_json` puts it: the sink of
    an enclosing :func:`collect_provenance`, else the sidecar :func:`provenance_path`."""
    sink = _SINK.get()
    if sink is not None:
        sink[str(path)] = volatile
    elif volatile:
        write_json(provenance_path(path), volatile)


@contextlib.contextmanager
def collect_provenance(path: str | os.PathLike[str], **extra: Any) -> Iterator[dict[str, Any]]:
    """Gather the volatile provenance of every :func:`write_result_json` inside the block into
    one sidecar at ``path`` (one per run), written when the block ends."""
    sink: dict[str, Any] = {}
    token = _SINK.set(sink)
    try:
        yield sink
    finally:
        _SINK.reset(token)
        write_json(path, {**extra, "files": dict(sorted(sink.items()))})


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
    colors: int | None = None,
    **savefig_kwargs: Any,
) -> Path:
    """Render a matplotlib figure to ``path`` atomically, then close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or PathLike
        Destination; its suffix is the format (``.png`` when it has none).
    dpi : float
        Resolution (dots per inch).
    colors : int, optional
        A PNG only: store it with a palette of at most this many colours (2 to 256, chosen
        for the image). A line plot looks the same with 256 and takes about a third of the
        bytes of full colour (figures committed to the repository stay small).
    **savefig_kwargs
        More options of :meth:`~matplotlib.figure.Figure.savefig` (``bbox_inches="tight"``).
    """
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fmt = Path(path).suffix.lstrip(".") or "png"
    try:
        if colors is not None and (fmt != "png" or not 2 <= colors <= 256):
            raise ValueError(f"colors: a PNG's palette of 2 to 256, got {colors} for .{fmt}")
        fig.savefig(buf, dpi=dpi, format=fmt, **savefig_kwargs)
    finally:
        plt.close(fig)
    if colors is None:
        return write_atomic(path, buf.getvalue())
    from PIL import Image  # matplotlib's own dependency

    buf.seek(0)
    with Image.open(buf) as image:
        small = image.convert("RGB").quantize(colors, method=Image.Quantize.MEDIANCUT)
    out = io.BytesIO()
    small.save(out, format="PNG", optimize=True)
    return write_atomic(path, out.getvalue())
