"""The paper's figures (``tuners.paper.reproduce``): zoom insets on each step, the seeds as a
band, small files."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import PolyCollection

from gripper_env.model.references import load_reference
from tuners.paper import command as paper_command
from tuners.paper import reproduce


def test_zoom_insets_show_every_curve_in_their_window():
    fig, ax = plt.subplots()
    t = np.linspace(0.0, 20.0, 20001)
    y = np.where(t < 1.0, 92.0, 21.0 + 71.0 * np.exp(-(t - 1.0) / 0.1))

    def draw(a):
        a.plot(t, y)
        a.fill_between(t, y - 2.0, y + 150.0 * (np.abs(t - 1.2) < 0.01))  # a spike at 1.2 s

    insets = reproduce.zoom_insets(ax, draw, [(0.9, 2.0), (9.9, 11.0)],
                                   [(0.2, 0.4, 0.3, 0.5), (0.6, 0.1, 0.35, 0.4)])  # fmt: skip
    assert [a.get_label() for a in insets] == ["zoom A", "zoom B"]
    assert insets[0].get_xlim() == (0.9, 2.0) and insets[1].get_xlim() == (9.9, 11.0)
    lo, hi = insets[0].get_ylim()
    inside = (t >= 0.9) & (t <= 2.0)
    assert lo < (y[inside] - 2.0).min() and hi > y[np.abs(t - 1.2) < 0.01].max() + 150.0
    lo, hi = insets[1].get_ylim()
    assert lo < 19.0 and hi < 25.0  # held at 21 deg: a tight range, not the whole run's
    plt.close(fig)


def test_figure11_has_an_inset_on_each_step_and_the_seeds_as_a_band():
    ref = load_reference("step")
    seeds = np.arange(1000, 1003)
    panels = {}
    for kind in ("untuned", "tuned"):
        _, model, act, _, at = reproduce._table34_row(
            f"{kind} (TF test2)", reproduce.PAPER_GAINS[f"{kind} (TF test2)"], 1, ref, seeds
        )
        panels[kind] = (model, act, at)
    fig = reproduce.figure11(ref, panels)
    for kind in panels:
        (ax,) = [a for a in fig.axes if a.get_title().endswith(f") {kind} PID")]
        insets = [a for a in ax.child_axes if a.get_label().startswith("zoom")]
        assert [a.get_xlim() for a in insets] == [
            pytest.approx((m - 0.1, m + 1.0)) for m in reproduce.STEP_MOVES_S
        ]
        (band,) = [c for c in ax.collections if isinstance(c, PolyCollection)]
        edges = band.get_paths()[0].vertices[:, 1]
        y = panels[kind][1].y
        assert edges.min() == pytest.approx(y.min()) and edges.max() == pytest.approx(y.max())
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "actual (simulated), min-max of 3 seeds" in labels and "actual, median seed" in labels
    plt.close(fig)


def test_the_paper_command_writes_small_figures(tmp_path):
    assert paper_command.main(["--out", str(tmp_path), "--seeds", "2"]) == 0
    for name in ("plants_step", "figure9_direct_response", "figure11_pid"):
        assert 10_000 < (tmp_path / "figures" / f"{name}.png").stat().st_size < 150_000
