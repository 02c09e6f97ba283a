"""Reading identification logs: CSV with a header row and columns ``t_s, desired_deg, actual_deg``.

Other columns are ignored, column order is free, blank lines are skipped. Every problem is a
``ValueError`` that names the file, and the line and column where it can be pinned down.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np

__all__ = ["LOG_COLUMNS", "read_log"]

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
    p = Path(path)
    try:
        with p.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
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
        raise ValueError(f"{p}: empty file (expected a header row {', '.join(LOG_COLUMNS)})")
    header_line, header = numbered[0]
    names = [h.strip() for h in header]
    missing = [c for c in LOG_COLUMNS if c not in names]
    if missing:
        raise ValueError(
            f"{p}: line {header_line}: missing column(s) {', '.join(missing)} in the header "
            f"(found: {', '.join(names) or 'nothing'})"
        )
    idx = [names.index(c) for c in LOG_COLUMNS]
    data = np.empty((len(numbered) - 1, 3))
    for k, (line, row) in enumerate(numbered[1:]):
        for j, (col, name) in enumerate(zip(idx, LOG_COLUMNS, strict=True)):
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
    return data[:, 0].copy(), data[:, 1].copy(), data[:, 2].copy()
