"""Reading identification logs: CSV with a header row and columns ``t_s, desired_deg, actual_deg``.

Other columns are ignored (or read by name: a closed loop's ``reference_deg``), column order is
free, blank lines are skipped. Every problem is a ``ValueError`` that names the file, and the
line and column where it can be pinned down.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gripper_env.io.config import MAX_DATA_BYTES, ConfigError, read_bounded

__all__ = ["LOG_COLUMNS", "read_columns", "read_log"]

LOG_COLUMNS = ("t_s", "desired_deg", "actual_deg")


def read_log(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read an identification log.

    Parameters
    ----------
    path : str or PathLike
        CSV file with a header row naming at least ``t_s`` (time, s), ``desired_deg`` (commanded
        jaw angle, deg) and ``actual_deg`` (measured jaw angle, deg).

    Returns
    -------
    t_s, desired_deg, actual_deg : ndarray
        One value per data row.

    Raises
    ------
    ValueError
        Missing file or columns, no data rows, or a cell that is not a finite number.
    """
    cols = read_columns(path, LOG_COLUMNS)
    return cols[LOG_COLUMNS[0]], cols[LOG_COLUMNS[1]], cols[LOG_COLUMNS[2]]


def read_columns(path: str | os.PathLike[str], names: Sequence[str]) -> dict[str, np.ndarray]:
    """Read the named columns of a CSV log with a header row.

    Parameters
    ----------
    path : str or PathLike
        CSV file.
    names : sequence of str
        Column names to read (each must be in the header).

    Returns
    -------
    dict of str to ndarray
        One array per name, one value per data row.

    Raises
    ------
    ValueError
        Missing or too large a file (:data:`gripper_env.io.config.MAX_DATA_BYTES`), missing
        columns, no data rows, or a cell that is not a finite number.
    """
    p = Path(path)
    try:
        try:  # a pipe or a device (/dev/zero) is refused before it is opened, a large file
            raw = read_bounded(p, MAX_DATA_BYTES, "log")  # before a byte is read
        except ConfigError as exc:
            if "more than" in str(exc):
                raise ValueError(
                    f"{exc} (minutes at 1 kHz are enough to identify the gripper: cut the log)"
                ) from None
            raise ValueError(str(exc)) from None
        text = raw.decode("utf-8-sig")
        del raw
        rows = list(csv.reader(io.StringIO(text, newline="")))
    except FileNotFoundError:
        raise ValueError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{p}: is a directory, not a CSV file") from None
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a text (UTF-8) CSV file") from None
    except (OSError, csv.Error) as exc:
        raise ValueError(f"{p}: cannot read: {exc}") from None
    numbered = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    if not numbered:
        raise ValueError(f"{p}: empty file (expected a header row {', '.join(names)})")
    header_line, header = numbered[0]
    found = [h.strip() for h in header]
    missing = [c for c in names if c not in found]
    if missing:
        raise ValueError(
            f"{p}: line {header_line}: missing column(s) {', '.join(missing)} in the header "
            f"(found: {', '.join(found) or 'nothing'})"
        )
    idx = [found.index(c) for c in names]
    data = np.empty((len(numbered) - 1, len(names)))
    for k, (line, row) in enumerate(numbered[1:]):
        for j, (col, name) in enumerate(zip(idx, names, strict=True)):
            if col >= len(row):
                raise ValueError(f"{p}: line {line}: no value for column {name}")
            cell = row[col].strip()
            try:
                val = float(cell)
            except ValueError:
                raise ValueError(
                    f"{p}: line {line}: column {name}: {cell!r} is not a number"
                ) from None
            if not math.isfinite(val):
                raise ValueError(f"{p}: line {line}: column {name}: {cell!r} is not finite")
            data[k, j] = val
    if data.shape[0] == 0:
        raise ValueError(f"{p}: no data rows after the header")
    return {name: data[:, j].copy() for j, name in enumerate(names)}
