"""The response figure (``tuners.plotting``): what it shows, checked through its axes and against
the evaluation's own metrics, not its pixels."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from PIL import Image

from gripper_env.evaluation.objective import load_objective
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from tuners.evaluation import evaluate
from tuners.plotting import (
    SERVO_RANGE_DEG,
    ZOOM_MAX_S,
    ZOOM_SETTLING_FACTOR,
    _ms,
    _pct,
    median_seed,
    metrics_table,
    response_figure,
    response_plot,
    step_zooms,
)

SEEDS = (100000, 100001, 100002)
TEST2, ACTUAL, IDEAL = load_plant("test2"), load_disturbance("actual"), load_disturbance("ideal")
OBJECTIVE = load_objective()
#: The actual model's settling-band floor with the shipped objective (its friction band, deg).
BAND = OBJECTIVE.settling_band_deg(ACTUAL)


def _evaluate(gains: tuple[float, float, float], profile: str = "step", seeds=SEEDS):
    return evaluate(
        TEST2, PIDGains(*gains, 100.0),
        PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping"),
        profile=load_reference(profile, TEST2.dt_s), disturbance=ACTUAL, ideal=IDEAL,
        objective=OBJECTIVE, seeds=seeds, ideal_options=PIDOptions(),
    )  # fmt: skip


@pytest.fixture(scope="module")
def untuned():
    """The paper's untuned gains: they overshoot, and the model's command spikes beyond the
    servo's range (its PID has no limits) while the actual model's saturates."""
    return _evaluate((-0.4, 7.0, -0.045))


@pytest.fixture
def figure(untuned):
    fig = response_figure(untuned, "untuned", BAND)
    yield fig
    plt.close(fig)


def _axes(fig, label):
    (ax,) = [a for a in fig.axes if a.get_label() == label]
    return ax


def test_a_zoom_and_a_command_zoom_on_each_step(untuned, figure):
    labels = sorted(a.get_label() for a in figure.axes)
    assert labels == ["command", "command zoom 0", "command zoom 1", "overview", "zoom 0",
                      "zoom 1"]  # fmt: skip
    zooms = step_zooms(untuned, BAND)
    segments = untuned.ideal_trajectory.reference.segments
    assert [z.segment for z in zooms] == list(segments)  # the step profile: grip, then un-grip
    t = untuned.ideal_trajectory.t
    for i, z in enumerate(zooms):
        ax, axu = _axes(figure, f"zoom {i}"), _axes(figure, f"command zoom {i}")
        assert ax.get_xlim() == pytest.approx(z.window_s)
        assert axu.get_xlim() == pytest.approx(z.window_s)  # the command under it, same time
        assert z.window_s[0] < 0 < z.window_s[1] <= t[z.segment.stop - 1] - t[z.segment.start]
        # at most a tenth of the run: the transient fills the panel
        assert z.window_s[1] <= ZOOM_MAX_S < 0.11 * (t[-1] - t[0])
        box = next(x.get_text() for x in ax.texts if x.get_text().startswith(metrics_table(z)))
        for who, marks in (("model", z.model_marks), ("median seed", z.median_marks)):
            if marks["settled_s"] < z.window_s[1]:  # the zoom ends after it settled...
                end = min(ZOOM_MAX_S, ZOOM_SETTLING_FACTOR * marks["settled_s"])
                assert end <= z.window_s[1] + 1e-9
            else:  # ...or says when it settles, long after the transient (a late wobble)
                assert z.window_s[1] == ZOOM_MAX_S
                assert f"{who} settles for good at {marks['settled_s']:.3g} s" in box
        assert f"{z.segment.kind} {z.segment.initial_deg:g} → {z.segment.final_deg:g}" in (
            ax.get_title()
        )
    assert zooms[1].median_marks["settled_s"] > ZOOM_MAX_S  # these seeds have such a wobble


def test_the_numbers_are_the_evaluations(untuned, figure):
    """Each zoom annotates the evaluation's overshoot, rise and settling: the model's and the
    actual model's mean over the seeds (one grip and one un-grip: the kind's numbers)."""
    for i, z in enumerate(step_zooms(untuned, BAND)):
        kind = z.segment.kind
        mean = untuned.actual["mean"][kind]
        for key in ("overshoot_pct", "rise_time_s", "settling_time_s"):
            assert z.model[key] == pytest.approx(untuned.ideal[kind][key], rel=1e-12)
            assert z.actual_mean[key] == pytest.approx(mean[key], rel=1e-12)
            per_seed = [run[kind][key] for run in untuned.actual_runs]
            np.testing.assert_allclose(z.actual[key], per_seed, rtol=1e-12)
        texts = [t.get_text() for t in _axes(figure, f"zoom {i}").texts]
        box = next(t for t in texts if t.startswith(metrics_table(z)))
        assert f"{_pct(untuned.ideal[kind]['overshoot_pct'])}  {_pct(mean['overshoot_pct'])}" in box
        assert f"{_ms(untuned.ideal[kind]['rise_time_s'])}  {_ms(mean['rise_time_s'])}" in box
        assert (f"{_ms(untuned.ideal[kind]['settling_time_s'])}  "
                f"{_ms(mean['settling_time_s'])}") in box  # fmt: skip
        assert mean["overshoot_pct"] > 5  # the untuned gains do overshoot: a real number shown


def test_rise_and_peak_marks_are_where_the_metrics_measure(untuned):
    t = untuned.ideal_trajectory.t
    for z in step_zooms(untuned, BAND):
        med = z.median_seed
        assert med == median_seed(untuned)
        median = {k: v[med] for k, v in z.actual.items()}
        for marks, metrics in ((z.model_marks, z.model), (z.median_marks, median)):
            assert marks["t90_s"] - marks["t10_s"] == pytest.approx(metrics["rise_time_s"])
            assert marks["peak_s"] == pytest.approx(metrics["peak_time_s"])
            assert marks["settled_s"] == pytest.approx(metrics["settling_time_s"])
            assert marks["t10_s"] in t - t[z.segment.start]  # samples, as the metrics take them


def test_the_settling_bands_are_the_metrics(untuned, figure):
    """Shaded: the actual model's band, max(2 % of the move, the objective's friction band);
    dashed: the model's, 2 % (the ideal preset has no friction)."""
    for i, z in enumerate(step_zooms(untuned, BAND)):
        move = abs(z.segment.final_deg - z.segment.initial_deg)
        assert z.band_deg == max(0.02 * move, BAND) == BAND
        assert z.model_band_deg == pytest.approx(0.02 * move)
        ax = _axes(figure, f"zoom {i}")
        (band,) = [p for p in ax.patches if p.get_label() == "settling band"]
        ys = band.get_patch_transform().transform(band.get_path().vertices)[:, 1]  # data y
        f = z.segment.final_deg
        assert (ys.min(), ys.max()) == pytest.approx((f - BAND, f + BAND))
        dashed = sorted(line.get_ydata()[0] for line in ax.lines if line.get_linestyle() == "--"
                        and line.get_color() == "tab:blue")  # fmt: skip
        assert dashed == pytest.approx([f - z.model_band_deg, f + z.model_band_deg])
    # a run is settled exactly when it stays in that band: the metric's definition
    z = step_zooms(untuned, BAND)[0]
    y = untuned.actual_trajectory.y_true[z.median_seed]
    t = untuned.ideal_trajectory.t
    k = z.segment.start + round(z.median_marks["settled_s"] / (t[1] - t[0]))
    assert np.all(np.abs(y[k : z.segment.stop] - z.segment.final_deg) <= z.band_deg)
    assert abs(y[k - 1] - z.segment.final_deg) > z.band_deg


def test_the_command_axes_hold_every_command_and_the_servo_range(untuned, figure):
    t = untuned.ideal_trajectory.t
    u_model = untuned.ideal_trajectory.u[0]
    u = untuned.actual_trajectory.u
    assert u_model.max() > SERVO_RANGE_DEG[1] and u_model.min() < SERVO_RANGE_DEG[0]  # spikes
    windows = [(_axes(figure, "command"), np.ones(len(t), bool))]
    for i, z in enumerate(step_zooms(untuned, BAND)):
        rel = t - t[z.segment.start]
        windows.append((_axes(figure, f"command zoom {i}"),
                        (rel >= z.window_s[0]) & (rel <= z.window_s[1])))  # fmt: skip
    for ax, inside in windows:
        lo, hi = ax.get_ylim()
        drawn = np.concatenate([u_model[inside], u[:, inside].ravel()])
        assert lo < drawn.min() and hi > drawn.max()  # nothing clipped
        assert lo < SERVO_RANGE_DEG[0] and hi > SERVO_RANGE_DEG[1]
        levels = {line.get_ydata()[0] for line in ax.lines if line.get_linestyle() == ":"}
        assert set(SERVO_RANGE_DEG) <= levels
    texts = [t.get_text() for t in _axes(figure, "command zoom 0").texts]
    assert f"the model's command peaks at {u_model.max():.0f} deg" in texts


def test_the_seeds_are_a_band_with_the_median_drawn(untuned, figure):
    ax = _axes(figure, "overview")
    y = untuned.actual_trajectory.y_true
    (band,) = [c for c in ax.collections if isinstance(c, PolyCollection)]
    edges = band.get_paths()[0].vertices[:, 1]
    assert edges.min() == pytest.approx(y.min()) and edges.max() == pytest.approx(y.max())
    iae = [run["iae"] for run in untuned.actual_runs]
    med = median_seed(untuned)
    assert iae[med] == sorted(iae)[len(iae) // 2]
    assert any(np.array_equal(line.get_ydata(), y[med]) for line in ax.lines)
    labels = [t.get_text() for t in figure.legends[0].get_texts()]
    assert f"actual model, median seed by IAE ({SEEDS[med]})" in labels
    assert f"actual model, min-max of {len(SEEDS)} seeds" in labels


def test_unstable_seeds_are_named_and_their_metrics_are_inf():
    ev = _evaluate((12.0, 600.0, 0.0))  # swings from stop to stop on the actual model
    assert ev.actual["stable_fraction"] == 0.0
    for z in step_zooms(ev, BAND):
        assert math.isinf(z.actual_mean["settling_time_s"]) and not z.median_marks
        assert metrics_table(z).endswith(f"{len(SEEDS)} of {len(SEEDS)} seeds unstable: inf")
    fig = response_figure(ev, "unstable", BAND)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    plt.close(fig)
    assert any(f"{len(SEEDS)} of {len(SEEDS)} unstable" in label for label in labels)


def test_response_plot_writes_a_small_png(untuned, tmp_path):
    path = response_plot(untuned, "untuned", tmp_path / "r.png", BAND)
    with Image.open(path) as image:
        assert image.format == "PNG" and image.mode == "P"  # a palette: a third of the bytes
        assert image.size[0] >= 1000
    assert 20_000 < path.stat().st_size < 150_000


def test_a_ramps_zoom_is_on_its_end():
    """On a ramp the overshoot and the settling come where the reference arrives: the zoom is
    there, not on the ramp's start."""
    ev = evaluate(TEST2, PIDGains(1.0, 9.0, -0.001, 100.0), PIDOptions(),
                  profile=load_reference("ramp3", TEST2.dt_s), disturbance=ACTUAL, ideal=IDEAL,
                  objective=OBJECTIVE, seeds=SEEDS[:1])  # fmt: skip
    (z,) = step_zooms(ev, BAND)
    assert z.arrive_s == pytest.approx(3.0, abs=2e-3)  # ramp3: 92 -> 21 deg over 3 s
    assert z.window_s[0] < z.arrive_s < z.window_s[1] <= z.arrive_s + ZOOM_MAX_S
    fig = response_figure(ev, "ramp", BAND)
    assert "ramp from t = 1 s to 4 s" in fig.axes[1].get_title()
    plt.close(fig)


def test_clustered_labels_are_placed_apart_and_joined_to_their_points():
    """The Pareto figure's labels (tuners.plotting.spread_labels): twelve points within a few
    pixels of each other get labels whose boxes do not overlap, each moved one joined to its
    point by a line."""
    from matplotlib.text import Text

    from tuners.plotting import spread_labels

    fig, ax = plt.subplots(figsize=(5, 4))
    ax.set(xlim=(0, 4), ylim=(0, 30))
    rng = np.random.default_rng(0)
    xs, ys = 1.5 + 0.05 * rng.random(12), 10 + 0.3 * rng.random(12)
    leader = {"arrowstyle": "-", "lw": 0.4}
    labels = [ax.annotate(f"row-{k}", (x, y), fontsize=6, xytext=(3, 2),
                          textcoords="offset points", arrowprops=leader)
              for k, (x, y) in enumerate(zip(xs, ys, strict=True))]  # fmt: skip
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()

    def overlaps():
        boxes = [Text.get_window_extent(t, renderer) for t in labels]
        return sum(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])

    assert overlaps() > 10  # the case: they all sit on each other
    spread_labels(ax, labels)
    fig.canvas.draw()
    assert overlaps() == 0
    moved = [t for t in labels if t.xyann[1] > 2.0]
    assert moved and all(t.arrow_patch.get_visible() for t in moved if t.xyann[1] > 6.0)
    plt.close(fig)
