"""Measured versus simulated output of an identified model (matplotlib, written to a file)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

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
    y_hat0 = estimate.simulate(u, np.zeros_like(estimate.initial_state))
    fig, (ax0, ax1) = plt.subplots(
        2, 1, sharex=True, figsize=(9, 6), gridspec_kw={"height_ratios": [3, 1]}
    )
    ax0.plot(t, u, color="0.6", lw=1, label="desired (input)")
    ax0.plot(t, y, color="C0", lw=1, label="measured")
    ax0.plot(t, y_hat, color="C1", lw=1.2, label=f"model, fit {estimate.fit_pct:.2f} %")
    ax0.plot(
        t,
        y_hat0,
        color="C2",
        lw=1,
        ls="--",
        label=f"model, zero initial state, fit {estimate.fit_pct_zero_ic:.2f} %",
    )
    ax0.set_ylabel("jaw angle (deg)")
    ax0.set_title(f"G(s) = {estimate.paper_form()}")
    ax0.legend(loc="best", fontsize="small")
    ax1.plot(t, y - y_hat, color="C3", lw=0.8)
    ax1.set_ylabel("residual (deg)")
    ax1.set_xlabel("time (s)")
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=120)
    plt.close(fig)
    return p
