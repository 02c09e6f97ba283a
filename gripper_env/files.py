"""Writing files so that a reader never sees half of one: the project's one atomic writer.

Every command that leaves a result behind (gains files, logs, reports, plant files, presets)
writes through :func:`write_atomic`: a temporary file in the same folder, then
:func:`os.replace`, which is atomic on the same file system. An interrupted write leaves the old
file (or none), never a truncated one. :func:`write_json` is the one JSON flavour: indented,
numpy values made plain, non-finite numbers as ``null``.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["json_ready", "write_atomic", "write_json"]


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
