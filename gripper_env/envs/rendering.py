"""Rendering of an episode: reference, jaw position and servo command against time (matplotlib).

``rgb_array`` draws on an off-screen Agg canvas and returns an (H, W, 3) uint8 image; ``human``
draws in a pyplot window (only if the backend is interactive; with a non-interactive backend
such as Agg the figure is drawn but not shown, without a warning).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["RENDER_MODES", "EpisodeViewer", "render_rgb"]

#: The render modes every simulated environment offers.
RENDER_MODES = ("human", "rgb_array")
_FIGSIZE_IN = (6.4, 4.0)
_DPI = 80


def _matplotlib() -> Any:
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - matplotlib is a dependency
        raise ImportError(
            "rendering needs matplotlib: pip install matplotlib (or gripper-env[all])"
        ) from exc
    return matplotlib


def _draw(fig: Any, t_s: np.ndarray, series: dict[str, np.ndarray], title: str) -> None:
    fig.clear()
    ax = fig.add_subplot(1, 1, 1)
    styles = {"reference": ("k--", 1.2), "position": ("C0-", 1.5), "command": ("C1-", 0.8)}
    for name, values in series.items():
        style, width = styles.get(name, ("-", 1.0))
        ax.plot(t_s[: len(values)], values, style, lw=width, label=f"{name} (deg)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("jaw angle (deg)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()


def render_rgb(t_s: np.ndarray, series: dict[str, np.ndarray], title: str) -> np.ndarray:
    """Plot ``series`` (name -> deg) against ``t_s`` (s) off screen; an (H, W, 3) uint8 image."""
    _matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=_FIGSIZE_IN, dpi=_DPI)
    canvas = FigureCanvasAgg(fig)
    _draw(fig, t_s, series, title)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


class EpisodeViewer:
    """A pyplot window that redraws the episode (``render_mode="human"``)."""

    def __init__(self) -> None:
        matplotlib = _matplotlib()
        import matplotlib.pyplot as plt

        self._plt = plt
        backend = matplotlib.get_backend().lower()
        self.interactive = not any(
            backend.endswith(name) for name in ("agg", "pdf", "ps", "svg", "cairo", "template")
        )
        self.fig = plt.figure(figsize=_FIGSIZE_IN, dpi=_DPI)

    def show(self, t_s: np.ndarray, series: dict[str, np.ndarray], title: str) -> None:
        _draw(self.fig, t_s, series, title)
        if self.interactive:
            self._plt.show(block=False)
            self._plt.pause(0.001)
        else:
            self.fig.canvas.draw()

    def close(self) -> None:
        self._plt.close(self.fig)
