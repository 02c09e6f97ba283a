"""Measured versus simulated output of an identified model (matplotlib, written to a file)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from gripper_env.io.files import save_figure
from gripper_env.sysid.tfest import TFEstimate

__all__ = ["plot_fit"]


def plot_fit(
    estimate: TFEstimate,
    u: ArrayLike,
    y: ArrayLike,
    path: str | os.PathLike[str],
    t_s: ArrayLike | None = None,
) -> Path:
    """Plot input, measured and simulated output, and residuals; save to ``path``.

    Parameters
    ----------
    estimate : TFEstimate
        The identified model.
    u, y : array_like
        Input and measured output on the estimate's sample grid (deg).
    path : str or PathLike
        Output image; the format follows the suffix (``.png``, ``.pdf``, ``.svg``).
    t_s : array_like, optional
        Time stamps (s); default ``k * estimate.dt_s``.

    Returns
    -------
    Path
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - matplotlib is a dependency
        raise ImportError("plotting needs matplotlib: pip install matplotlib") from exc
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    t = np.arange(u.size) * estimate.dt_s if t_s is None else np.asarray(t_s, dtype=float)
    y_hat = estimate.simulate(u)
    moved = np.flatnonzero(u != u[0])
    y_rest = float(np.mean(y[: max(int(moved[0]) if moved.size else u.size, 1)]))
    y_hat0 = estimate.simulate(u, estimate.rest_state(y_rest, float(u[0])))
    fig, (ax0, ax1) = plt.subplots(
        2, 1, sharex=True, figsize=(9, 6), gridspec_kw={"height_ratios": [3, 1]}
    )
    ax0.plot(t, u, color="0.6", lw=1, label="desired (input)")
    ax0.plot(t, y, color="C0", lw=1, label="measured")
    ax0.plot(t, y_hat, color="C1", lw=1.2, label=f"model (estimation fit {estimate.fit_pct:.2f} %)")
    ax0.plot(
        t,
        y_hat0,
        color="C2",
        lw=1,
        ls="--",
        label=f"model from rest, fit {estimate.fit_pct_rest:.2f} %",
    )
    ax0.set_ylabel("jaw angle (deg)")
    title = f"G(s) = {estimate.paper_form()}  (input delay {1e3 * estimate.input_delay_s:.3g} ms)"
    if estimate.validation is not None:
        title += f"\nfit on validation data: {estimate.validation.fit_pct:.2f} %"
    ax0.set_title(title, fontsize=10)
    ax0.legend(loc="best", fontsize="small")
    ax1.plot(t, y - y_hat, color="C3", lw=0.8)
    ax1.set_ylabel("residual (deg)")
    ax1.set_xlabel("time (s)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)
