"""Rendering of an episode against time (matplotlib): the reference and the jaw position above,
the controller's command below on its own axis with the servo's command range marked.

:class:`EpisodePlot` keeps one figure for its environment's lifetime. Axes, ticks, legend and
title are drawn once per episode (:meth:`EpisodePlot.start`; the time axis spans the whole
episode), and a frame draws only the lines' new segments, those since the previous frame, onto
the canvas (matplotlib's ``draw_artist``), so a frame costs about the same at the end of an
episode as at its start, and far less than a full figure draw. The lines hold at most two points
per control period (:class:`EpisodeRecorder`: the period's lowest and highest sample, at their own
times), so the drawn envelope is the full 1 ms trace's at this resolution.

The command's axis holds the command range and every command drawn so far: a command beyond it
(a PID's output before the servo clips it) widens the axis and the frame is drawn again whole,
so no spike is cut at the edge.

``rgb_array`` draws on an off-screen Agg canvas and returns an (H, W, 3) uint8 image; ``human``
draws in a pyplot window (shown only if the backend is interactive; under a non-interactive
backend such as Agg the figure is drawn but not shown, without a warning).
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

__all__ = [
    "RENDER_MODES",
    "EpisodePlot",
    "EpisodeRecorder",
    "EpisodeRenderer",
    "RowRenderer",
    "command_ylim_deg",
    "envelope",
    "ylim_deg",
]

#: The render modes every simulated environment offers.
RENDER_MODES = ("human", "rgb_array")

_FIGSIZE_IN = (6.4, 4.0)
_DPI = 80
SERIES = ("reference", "position", "command")
_STYLES = {"reference": ("k--", 1.2), "position": ("C0-", 1.5), "command": ("C1-", 0.8)}
#: The servo's command range (deg): the command axis's default, marked by dotted lines.
SERVO_RANGE_DEG = (0.0, 180.0)
_NON_INTERACTIVE = ("agg", "pdf", "ps", "svg", "cairo", "template")


def _matplotlib() -> Any:
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - matplotlib is a dependency
        raise ImportError(
            "rendering needs matplotlib: pip install matplotlib (or gripper-env[all])"
        ) from exc
    return matplotlib


def envelope(values: np.ndarray, n_per_bin: int, dt_s: float, t0_s: float = 0.0):
    """Decimate ``values`` (one sample per ``dt_s``) to the lowest and highest sample of each bin
    of ``n_per_bin`` samples, at their own times, in time order.

    Returns ``(t_s, values)``, two points per bin (one for a bin of one sample); a plot of them
    has the same envelope as the full trace when a bin is narrower than a pixel.
    """
    values = np.asarray(values, dtype=float)
    n = len(values) // n_per_bin * n_per_bin
    bins = values[:n].reshape(-1, n_per_bin)
    lo, hi = bins.argmin(axis=1), bins.argmax(axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    start = np.arange(bins.shape[0]) * n_per_bin
    idx = np.stack([start + first, start + second], axis=1).ravel()
    if n < len(values):  # a partial last bin: its samples as they are
        idx = np.concatenate([idx, np.arange(n, len(values))])
    return t0_s + idx * dt_s, values[idx]


class EpisodeRecorder:
    """The series of one episode for rendering, two points per control period.

    Parameters
    ----------
    dt_s : float
        Physics step (s).
    """

    def __init__(self, dt_s: float) -> None:
        self.dt_s = dt_s
        self.t = np.zeros(0)
        self.values = np.zeros((len(SERIES), 0))
        self.n = 0
        self.steps = 0

    def start(self, n_periods: int, reference_deg: float, position_deg: float,
              command_deg: float) -> None:  # fmt: skip
        """A new episode of at most ``n_periods`` periods, from its first sample (t = 0)."""
        size = 2 * n_periods + 1
        if self.t.shape[0] < size:
            self.t = np.zeros(size)
            self.values = np.zeros((len(SERIES), size))
        self.t[0] = 0.0
        self.values[:, 0] = (reference_deg, position_deg, command_deg)
        self.n = 1
        self.steps = 0

    def record(self, reference: np.ndarray, position: np.ndarray, command: np.ndarray) -> None:
        """Add one period: the samples (deg) of each series at its physics steps."""
        n_sub = len(position)
        t0 = self.steps * self.dt_s  # sample k of the period is taken at physics step k
        for j, x in enumerate((reference, position, command)):
            lo, hi = int(np.argmin(x)), int(np.argmax(x))
            first, second = min(lo, hi), max(lo, hi)
            self.values[j, self.n] = x[first]
            self.values[j, self.n + 1] = x[second]
            if j == 0:
                self.t[self.n] = t0 + first * self.dt_s
                self.t[self.n + 1] = t0 + second * self.dt_s
        self.n += 2
        self.steps += n_sub

    def series(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Times (s) and the series (deg) so far (views, valid until the next call)."""
        n = self.n
        return self.t[:n], {name: self.values[j, :n] for j, name in enumerate(SERIES)}


class EpisodePlot:
    """One figure that plots episodes frame by frame (see the module docstring).

    Parameters
    ----------
    human : bool
        Draw in a pyplot window (``render_mode="human"``) rather than off screen.
    """

    def __init__(self, human: bool = False) -> None:
        matplotlib = _matplotlib()
        self._plt: ModuleType | None  # pyplot, for the window (``human`` only)
        if human:
            import matplotlib.pyplot as plt

            self._plt = plt
            backend = matplotlib.get_backend().lower()
            self.interactive = not any(backend.endswith(name) for name in _NON_INTERACTIVE)
            self.fig = plt.figure(figsize=_FIGSIZE_IN, dpi=_DPI)
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            self._plt = None
            self.interactive = False
            self.fig = Figure(figsize=_FIGSIZE_IN, dpi=_DPI)
            FigureCanvasAgg(self.fig)
        self.human = human
        grid = self.fig.add_gridspec(2, 1, height_ratios=[2.3, 1.0], hspace=0.08)
        ax = self.fig.add_subplot(grid[0])
        cax = self.fig.add_subplot(grid[1], sharex=ax)
        self.lines = {}
        for name in SERIES:
            style, width = _STYLES[name]
            (line,) = (cax if name == "command" else ax).plot(
                [], [], style, lw=width, label=f"{name} (deg)", animated=True
            )
            self.lines[name] = line
        self._range_lines = [
            cax.axhline(v, color="tab:red", ls=":", lw=0.8) for v in SERVO_RANGE_DEG
        ]
        ax.set_ylabel("jaw angle (deg)", fontsize=8)
        ax.tick_params(labelbottom=False, labelsize=7)
        cax.set_xlabel("time (s)", fontsize=8)
        cax.set_ylabel("command (deg)", fontsize=8)
        cax.tick_params(labelsize=7)
        for a in (ax, cax):
            a.grid(True, alpha=0.3)
        # the legend sits outside the axes: the frames' segments are drawn over what is there
        self.fig.legend(
            handles=[*self.lines.values(), self._range_lines[0]],
            labels=[*(line.get_label() for line in self.lines.values()), "command range"],
            loc="lower center", ncol=4, fontsize=7, frameon=False,
        )  # fmt: skip
        self._title = ax.set_title("", fontsize=9)
        self.ax = ax
        self.cax = cax
        self._drawn = 0  # points of the series already on the canvas
        self._started = False
        self._shown = False
        self._laid_out = False

    def start(
        self,
        title: str,
        duration_s: float,
        ylim_deg: tuple[float, float],
        command_range_deg: tuple[float, float] = SERVO_RANGE_DEG,
        command_ylim: tuple[float, float] | None = None,
    ) -> None:
        """A new episode: fixed axes for its whole duration, drawn once without lines.

        Parameters
        ----------
        title : str
            Title of the frames.
        duration_s : float
            The episode's length (s): the time axis.
        ylim_deg : (float, float)
            The angle axis (deg; :func:`ylim_deg`).
        command_range_deg : (float, float)
            The servo's command range (deg), marked on the command axis.
        command_ylim : (float, float), optional
            The command axis (deg); default :func:`command_ylim_deg` of the range alone. It
            widens as commands beyond it are drawn.
        """
        self._title.set_text(title)
        self.ax.set_xlim(0.0, max(duration_s, 1e-3))
        self.ax.set_ylim(*ylim_deg)
        for line, value in zip(self._range_lines, command_range_deg, strict=True):
            line.set_ydata([value, value])
        self._command_range = command_range_deg
        self.cax.set_ylim(*(command_ylim or command_ylim_deg(command_range_deg)))
        if self._plt is not None and self.interactive and not self._shown:
            self._plt.show(block=False)
            self._shown = True
        if not self._laid_out:  # once: the layout does not change between episodes
            self.fig.subplots_adjust(left=0.11, right=0.98, top=0.92, bottom=0.2)
            self._laid_out = True
        self.fig.canvas.draw()  # the lines are animated: not drawn here
        self._drawn = 0
        self._started = True

    def _draw_lines(self, t_s: np.ndarray, series: dict[str, np.ndarray]) -> None:
        if not self._started:
            raise RuntimeError("EpisodePlot: call start() before drawing a frame")
        n = len(t_s)
        if n < self._drawn:
            raise ValueError("EpisodePlot: the series got shorter; call start() for a new episode")
        first = max(self._drawn - 1, 0)  # the new segments start at the last point drawn
        command = series.get("command")
        if command is not None and n > first:
            lo, hi = self.cax.get_ylim()
            new = np.asarray(command[first:n], dtype=float)
            new = new[np.isfinite(new)]
            if new.size and (new.min() < lo or new.max() > hi):  # widen, then draw all again
                self.cax.set_ylim(*command_ylim_deg(self._command_range, command[:n]))
                self.fig.canvas.draw()
                first = 0
        for name, line in self.lines.items():
            values = series.get(name)
            if values is None or n - first < 2:
                continue
            line.set_data(t_s[first:n], values[first:n])
            (self.cax if name == "command" else self.ax).draw_artist(line)
        self._drawn = n

    def rgb(self, t_s: np.ndarray, series: dict[str, np.ndarray]) -> np.ndarray:
        """The frame: ``series`` (name -> deg) against ``t_s`` (s), an (H, W, 3) uint8 image.

        The series extend those of the previous frame of this episode (only the new points are
        drawn).
        """
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        self._draw_lines(t_s, series)
        canvas = self.fig.canvas
        if not isinstance(canvas, FigureCanvasAgg):  # human figures draw to a window instead
            raise RuntimeError(f"rgb frames need an Agg canvas, not {type(canvas).__name__}")
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()

    def show(self, t_s: np.ndarray, series: dict[str, np.ndarray]) -> None:
        """Draw the frame in the window (``human``)."""
        self._draw_lines(t_s, series)
        if self.interactive:
            self.fig.canvas.blit(self.fig.bbox)
            self.fig.canvas.flush_events()

    def close(self) -> None:
        if self._plt is not None:
            self._plt.close(self.fig)


def ylim_deg(jaw_range_deg: tuple[float, float], reference: np.ndarray) -> tuple[float, float]:
    """Vertical range of the angle axis: the jaw range and the reference with a quarter range
    of room."""
    lo = min(jaw_range_deg[0], float(np.min(reference)))
    hi = max(jaw_range_deg[1], float(np.max(reference)))
    pad = 0.25 * (hi - lo)
    return lo - pad, hi + pad


def command_ylim_deg(
    command_range_deg: tuple[float, float], command: np.ndarray | None = None
) -> tuple[float, float]:
    """Vertical range of the command axis: the command range and every (finite) value of
    ``command`` (deg), with a tenth of the span of room."""
    lo, hi = command_range_deg
    if command is not None:
        values = np.asarray(command, dtype=float)
        values = values[np.isfinite(values)]
        if values.size:
            lo, hi = min(lo, float(values.min())), max(hi, float(values.max()))
    pad = 0.1 * (hi - lo)
    return lo - pad, hi + pad


class EpisodeRenderer:
    """An episode recorded period by period and drawn on an :class:`EpisodePlot` made on first
    use: what every environment's renderer shares (subclasses start episodes and record).

    Parameters
    ----------
    name : str
        Environment name, for the titles and errors.
    mode : {"rgb_array", "human"}
        The render mode.
    dt_s : float
        Time step of the recorded series (s).
    """

    def __init__(self, name: str, mode: str, dt_s: float) -> None:
        self.name, self.mode = name, mode
        self.recorder = EpisodeRecorder(dt_s)
        self.plot: EpisodePlot | None = None
        self.started = False

    def _start_plot(
        self, title: str, duration_s: float, ylim: tuple[float, float],
        command_range_deg: tuple[float, float],
    ) -> None:  # fmt: skip
        """A new episode's background (the figure made on first use)."""
        if self.plot is None:
            self.plot = EpisodePlot(human=self.mode == "human")
        self.plot.start(title, duration_s, ylim, command_range_deg)
        self.started = True

    def render(self) -> np.ndarray | None:
        """``rgb_array``: the frame; ``human``: draw it in the window."""
        if not self.started:
            raise RuntimeError(f"{self.name}: call reset() before render()")
        assert self.plot is not None
        t_s, series = self.recorder.series()
        if self.mode == "rgb_array":
            return self.plot.rgb(t_s, series)
        self.plot.show(t_s, series)
        return None

    def close(self) -> None:
        if self.plot is not None:
            self.plot.close()
            self.plot = None
            self.started = False

    def __getstate__(self) -> dict[str, Any]:  # a copy starts without a figure
        state = self.__dict__.copy()
        state["plot"], state["started"] = None, False
        return state


class RowRenderer(EpisodeRenderer):
    """Rendering of one row of a :class:`~gripper_env.envs.control_batch.ControlBatch`: records
    each period of the row's episode and draws it on an :class:`EpisodePlot` made on first use.

    Parameters
    ----------
    batch : ControlBatch
        The batch (its :meth:`episode_start` and :meth:`period_series`).
    row : int
        The row to render.
    name : str
        Environment name, for the title.
    mode : {"rgb_array", "human"}
        The render mode.
    """

    def __init__(self, batch: Any, row: int, name: str, mode: str) -> None:
        super().__init__(name, mode, batch.settings.dt_s)
        self.batch, self.row = batch, row

    def start(self) -> None:
        """The row was reset: a new episode, a new background."""
        n_periods, r0, y0, u0, title, values = self.batch.episode_start(self.row)
        self.recorder.start(n_periods, r0, y0, u0)
        s = self.batch.settings
        duration = n_periods * s.n_sub * s.dt_s
        self._start_plot(f"{self.name}: {title}", duration, ylim_deg(s.jaw_range_deg, values),
                         s.command_range_deg)  # fmt: skip

    def record(self) -> None:
        """The row stepped one period."""
        self.recorder.record(*self.batch.period_series(self.row))
