"""Reproduce the paper's tables and figures: ``python -m tuners.paper``.

Writes ``results/paper_reproduction.md``, PNG figures under ``results/figures/`` and the run's
provenance, ``results/paper_reproduction.provenance.json`` (``--out`` chooses another folder
than ``results/`` of the working directory; the same code writes the same bytes):

1. the four identified plants (Table 1, Figure 7): poles, DC gain, and their open-loop response to
   the grip/un-grip step, with step metrics;
2. validation stage 1 (Table 2, Figure 9): the SD of each transfer function's response and its SD
   gap to the actual gripper's response, for a documented profile, beside the paper's numbers;
3. validation stage 2 (Tables 3-4, Figure 11): the paper's PID gains on TF test2 (the untuned
   gains overshoot, the tuned do not) with the SDs beside Table 4's, on the model and on the
   actual-gripper model;
4. the hardware gains of Table 3 and the error-sign convention under which they are stable.

The "actual gripper" is simulated: plant test2 (the paper's chosen model) behind the ``actual``
preset (1-deg servo commands at 50 Hz, Choudhury stiction, stops, 10-bit ADC, noise), averaged
over seeds. The paper's exact reference profiles are not published; the ones used are stated.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env import paper
from gripper_env.evaluation.metrics import Metrics, compute_metrics, fit_percent, sample_sd
from gripper_env.evaluation.stability import stability_report
from gripper_env.io.files import collect_provenance, save_figure, write_atomic, write_group
from gripper_env.model.disturbances import describe, load_disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import Reference, load_reference, step_profile
from gripper_env.sim import Trajectory, simulate

PLANTS = ("test1", "test2", "test3", "test4")
PAPER_FIT = {name: fit for name, (_num, _den, fit) in paper.PLANTS.items()}
PAPER_TABLE2 = paper.TABLE2_SD
PAPER_GAINS = {
    "untuned (TF test2)": paper.PID_GAINS["untuned_tf"],
    "tuned (TF test2)": paper.PID_GAINS["tuned_tf"],
    "untuned (hardware)": paper.PID_GAINS["untuned_hw"],
    "tuned (hardware)": paper.PID_GAINS["tuned_hw"],
}
PAPER_TABLE4 = paper.TABLE4_SD


def _fmt(x: float, digits: int = 3) -> str:
    return "inf" if not np.isfinite(x) else f"{x:.{digits}f}"


#: The `step` profile's moves (s): the grip and the un-grip.
STEP_MOVES_S = (1.0, 10.0)


def zoom_insets(
    ax: Any,
    draw: Callable[[Any], None],
    windows_s: Sequence[tuple[float, float]],
    rects: Sequence[tuple[float, float, float, float]],
) -> list[Any]:
    """Zoomed copies of a time plot: ``draw(axes)`` once per window, each in an inset at
    ``rect`` (axes fractions, where the curves never go), linked to its window on ``ax``.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        The whole run.
    draw : callable
        Draws the curves on the axes it is given (the same as on ``ax``).
    windows_s : sequence of (float, float)
        Time spans to zoom on (s).
    rects : sequence of (x, y, width, height)
        Where each inset sits, in fractions of ``ax``.

    Returns
    -------
    list of matplotlib.axes.Axes
        The insets, labelled ``zoom A``, ``zoom B``, ...; the vertical range of each holds
        every curve within its window.
    """
    insets = []
    for i, ((t0, t1), rect) in enumerate(zip(windows_s, rects, strict=True)):
        axin = ax.inset_axes(rect, label=f"zoom {chr(ord('A') + i)}")
        draw(axin)
        ys = [np.asarray(line.get_ydata(), dtype=float)[
                  (np.asarray(line.get_xdata(), dtype=float) >= t0)
                  & (np.asarray(line.get_xdata(), dtype=float) <= t1)]
              for line in axin.lines]  # fmt: skip
        for coll in axin.collections:
            for path in coll.get_paths():
                v = path.vertices
                ys.append(v[(v[:, 0] >= t0) & (v[:, 0] <= t1), 1])
        y = np.concatenate(ys)
        y = y[np.isfinite(y)]
        pad = 0.06 * (y.max() - y.min()) if y.size else 1.0
        axin.set_xlim(t0, t1)
        if y.size:
            axin.set_ylim(y.min() - pad, y.max() + pad)
        axin.set_title(f"{chr(ord('A') + i)}: t = {t0:g} to {t1:g} s", fontsize=7, pad=2)
        axin.tick_params(labelsize=6)
        axin.grid(alpha=0.3)
        ax.indicate_inset_zoom(axin, edgecolor="0.35")
        insets.append(axin)
    return insets


def _plants_section(lines: list[str], fig_dir: Path, seeds: np.ndarray) -> None:
    import matplotlib.pyplot as plt

    ref = load_reference("step")
    lines += [
        "## 1. The identified plants (Table 1, Figure 7)",
        "",
        "Open-loop response of each transfer function (`ideal` preset: the TF alone, starting at",
        "rest at 92 deg) to the `step` profile: 92 deg, grip step to 21 deg at t = 1 s, un-grip",
        "step to 92 deg at t = 10 s, 20 s in all.",
        "",
        "| plant | transfer function | paper fit % | poles (rad/s) | DC gain | grip rise / settling (s) | grip overshoot % | un-grip rise / settling (s) |",  # noqa: E501
        "|---|---|---|---|---|---|---|---|",
    ]
    curves = []
    for name in PLANTS:
        plant = load_plant(name)
        traj = simulate(plant, ref, gains=None, disturbance="ideal")
        m = compute_metrics(traj)
        poles = ", ".join(f"{p.real:.4g}{p.imag:+.3g}j" if p.imag else f"{p.real:.4g}"
                          for p in plant.poles)  # fmt: skip
        tf = f"({_poly(plant.num)}) / ({_poly(plant.den)})"
        lines.append(
            f"| {name} | {tf} | {PAPER_FIT[name]} | {poles} | {plant.dc_gain:.3f} | "
            f"{_fmt(m.grip['rise_time_s'][0])} / {_fmt(m.grip['settling_time_s'][0])} | "
            f"{_fmt(m.grip['overshoot_pct'][0], 2)} | "
            f"{_fmt(m.ungrip['rise_time_s'][0])} / {_fmt(m.ungrip['settling_time_s'][0])} |"
        )
        curves.append((traj.t, traj.y_true[0], f"TF {name}"))
    actual = simulate("test2", ref, gains=None, disturbance="actual", seeds=seeds[:1])
    curves.append((actual.t, actual.y[0], f"actual (simulated, measured; seed {seeds[0]})"))

    def draw(ax: Any) -> None:  # the actual gripper (test2 with friction) beneath TF test2
        ax.plot(ref.t_s, ref.values_deg, "k--", lw=1, label="desired", zorder=3)
        for i, (t, y, label) in enumerate(curves):
            actual = "actual" in label
            ax.plot(t, y, lw=0.8 if actual else 1.3, color=f"C{i}", label=label,
                    zorder=1 if actual else 2)  # fmt: skip

    fig, ax = plt.subplots(figsize=(9, 5))
    draw(ax)
    zoom_insets(ax, draw, [(m - 0.05, m + 0.6) for m in STEP_MOVES_S],
                [(0.14, 0.2, 0.3, 0.45), (0.6, 0.09, 0.36, 0.45)])  # fmt: skip
    ax.set(xlabel="time (s)", ylabel="jaw angle (deg)",
           title="Open-loop step responses (insets: the first 0.6 s of each step)")  # fmt: skip
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", ncol=6, fontsize=8,
               frameon=False, columnspacing=1.2)  # fmt: skip
    ax.grid(alpha=0.3)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    save_figure(fig, fig_dir / "plants_step.png", dpi=110)
    lines += [
        "",
        "test1's slow complex poles (time constant about 20 s) barely move within the 9 s hold:",
        "the reason the paper found it the least accurate in validation despite its best fit.",
        "Tests 2-4 are a fast real pole plus an almost-cancelling slow pole/zero pair.",
        "",
        "![open-loop step responses](figures/plants_step.png)",
        "",
    ]


def _poly(c: tuple[float, ...]) -> str:
    n = len(c) - 1
    terms = []
    for i, a in enumerate(c):
        p = n - i
        s = "" if p == 0 else ("s" if p == 1 else f"s^{p}")
        terms.append(f"{a:g}{' ' + s if s else ''}")
    return " + ".join(terms)


def _table2_section(lines: list[str], fig_dir: Path, seeds: np.ndarray) -> None:
    import matplotlib.pyplot as plt

    ref = step_profile(hold_s=1.0, grip_s=60.0, ungrip_s=60.0)
    actual = simulate("test2", ref, gains=None, disturbance="actual", seeds=seeds,
                      randomize=True)  # fmt: skip
    sd_actual = sample_sd(actual.y, axis=1)
    sd_act = float(sd_actual.mean())
    lines += [
        "## 2. Validation stage 1: direct response (Table 2, Figure 9)",
        "",
        "Profile: 1 s at 92 deg, grip step to 21 deg, 60 s hold, un-grip step to 92 deg, 60 s hold",
        "(121 s). The paper does not publish its validation profile; with 60 s halves, test1's SD",
        "comes out near the paper's 26.891, which suggests holds of about that length. The actual",
        f"gripper: test2 behind the randomised `actual` preset, {len(seeds)} seeds (mean +/- SD).",
        "SD is the sample standard deviation of the angle over the run (ddof = 1); fit % is",
        "MATLAB's `compare` fit of the TF response to the actual one.",
        "",
        "| data | SD (ours) | SD_actual - SD_test (ours) | fit % to actual (ours) | SD (paper) | SD_actual - SD_test (paper) |",  # noqa: E501
        "|---|---|---|---|---|---|",
        f"| actual | {sd_act:.3f} +/- {sd_actual.std(ddof=1):.3f} | | | "
        f"{PAPER_TABLE2['actual']} | |",
    ]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    grip = (ref.t_s > 0.5) & (ref.t_s < 4.0)
    ungrip = (ref.t_s > 60.5) & (ref.t_s < 64.0)
    for ax, window, title in ((axes[0], grip, "(a) grip"), (axes[1], ungrip, "(b) un-grip")):
        ax.plot(ref.t_s[window], ref.values_deg[window], "k--", lw=1, label="desired")
        ax.fill_between(actual.t[window], actual.y[:, window].min(axis=0),
                        actual.y[:, window].max(axis=0), color="C0", alpha=0.3, lw=0,
                        label=f"actual (simulated), min-max of {len(seeds)} seeds")  # fmt: skip
        ax.plot(actual.t[window], actual.y[0, window], lw=0.8, color="C0",
                label=f"actual, seed {seeds[0]}")  # fmt: skip
        ax.set(title=title, xlabel="time (s)", ylabel="jaw angle (deg)")
    gaps = {}
    for name in PLANTS:
        traj = simulate(name, ref, gains=None, disturbance="ideal")
        sd = float(sample_sd(traj.y_true[0]))
        gaps[name] = sd_act - sd
        fit = float(np.mean(fit_percent(actual.y, traj.y_true[0][None, :], axis=1)))
        paper_gap = PAPER_TABLE2["actual"] - PAPER_TABLE2[name]
        lines.append(
            f"| {name} | {sd:.3f} | {sd_act - sd:.3f} | {fit:.1f} | {PAPER_TABLE2[name]} | "
            f"{paper_gap:.3f} |"
        )
        for ax, window in ((axes[0], grip), (axes[1], ungrip)):
            ax.plot(traj.t[window], traj.y_true[0, window], lw=1.2,
                    color=f"C{1 + PLANTS.index(name)}", label=f"TF {name}")  # fmt: skip
    axes[1].legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, fig_dir / "figure9_direct_response.png", dpi=110)
    best = min(gaps, key=lambda k: abs(gaps[k]))
    fast = [gaps[k] for k in PLANTS[1:]]
    lines += [
        "",
        f"Smallest |SD gap| here: **{best}**. As in the paper, test1 is far off (its response is",
        f"too slow for the holds: gap {gaps['test1']:.2f} deg); tests 2-4 are within "
        f"{max(abs(g) for g in fast):.2f} deg. Which of them is closest depends on the profile and",
        "on what stands in for the actual gripper (here test2 with friction and quantisation, so",
        "the comparison is partly circular), and our gaps for tests 2-3 are negative: the",
        "simulated gripper's stiction offset ((S - J)/2 short of each target) lowers its SD below",
        "the linear models', whereas in the paper every TF had a lower SD than the hardware.",
        "Our SDs of tests 2-4 sit 0.9-2.0 deg above the paper's: their responses settle onto the",
        "reference, so their SD is close to the square wave's (35.5); the paper's lower values",
        "point to a different (unpublished) profile or window.",
        "",
        "![Figure 9](figures/figure9_direct_response.png)",
        "",
    ]


def _table34_section(lines: list[str], fig_dir: Path, seeds: np.ndarray) -> None:
    ref = load_reference("step")
    lines += [
        "## 3. Validation stage 2: PID on test2 (Tables 3-4, Figure 11)",
        "",
        "Profile `step` (20 s). Model: TF test2 alone (`ideal`), Simulink-style PID (parallel,",
        "N = 100, Forward Euler, no limits: Simulink's defaults). Actual: test2 behind the",
        f"randomised `actual` preset, {len(seeds)} seeds, with the PID output limited to the",
        "servo's 0-180 deg and clamping anti-windup, as firmware would. The actual gripper's",
        "stops lie beyond 21 and 92 deg (12 and 100 deg, randomised +/- 3 deg: an assumption,",
        "the paper does not give them), so its overshoot shows, as in the paper's Figure 11(a).",
        "SDs are of the measured angle (what the paper's Arduino recorded); overshoot of the true",
        "jaw angle. Margins: gain margin and Ms of the loop as it really runs, with the servo's",
        "20 ms command hold (`gripper_env.evaluation.stability`).",
        "",
        "| gains | P | I | D | error sign | model: grip / un-grip overshoot % | actual: grip / un-grip overshoot % | GM dB / Ms (20 ms hold) | model SD | actual SD | paper SD (model / actual) |",  # noqa: E501
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    panels = {}
    findings = {}
    for label, gains in PAPER_GAINS.items():
        hardware = "hardware" in label
        for sign in (1, -1) if hardware else (1,):
            row, model, act, mm, at = _table34_row(label, gains, sign, ref, seeds)
            lines.append(row)
            findings[(label, sign)] = (mm, at)
            if not hardware:
                panels["untuned" if label.startswith("untuned") else "tuned"] = (model, act, at)
    save_figure(figure11(ref, panels), fig_dir / "figure11_pid.png", dpi=110)
    untuned, untuned_act = findings[("untuned (TF test2)", 1)]
    tuned, tuned_act = findings[("tuned (TF test2)", 1)]
    lines += [
        "",
        f"The paper's qualitative result holds on TF test2: the untuned gains overshoot "
        f"({untuned.grip['overshoot_pct'][0]:.1f} % on the grip), the tuned gains do not "
        f"({tuned.grip['overshoot_pct'][0]:.2g} %), and the SD drops from untuned to tuned as in "
        "Table 4. On the simulated actual gripper the untuned gains overshoot too "
        f"({np.mean(untuned_act.grip['overshoot_pct']):.1f} % on the grip, until the jaw meets "
        "its stop), as the paper saw on hardware (Figure 11a), and the tuned ones barely "
        f"({np.mean(tuned_act.grip['overshoot_pct']):.1f} %). With the servo's 20 ms hold the "
        "untuned gains keep only about 3 dB of gain margin: far from deployable.",
        "",
        "![Figure 11](figures/figure11_pid.png)",
        "",
    ]


def figure11(ref: Reference, panels: dict[str, tuple[Trajectory, Trajectory, Metrics]]) -> Any:
    """The paper's Figure 11: per gain set (``untuned``, ``tuned``: the model's trajectory, the
    actual gripper's over the seeds and their metrics of the true angle), the model's response
    and the actual gripper's measured angle (what the paper's Arduino recorded) over the seeds
    as a band (min to max) with the median seed (by IAE), and a zoom inset on each step."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), sharey=True)
    for ax, (kind, (model, act, at)) in zip(axes, panels.items(), strict=False):
        ok = np.isfinite(act.y).all(axis=1)
        iae = np.where(np.isfinite(at.run["iae"]), at.run["iae"], np.inf)
        med = int(np.argsort(iae, kind="stable")[len(iae) // 2])

        draw = partial(_figure11_curves, ref=ref, model=model, act=act, ok=ok, med=med)
        draw(ax)
        zoom_insets(ax, draw, [(m - 0.1, m + 1.0) for m in STEP_MOVES_S],
                    [(0.18, 0.42, 0.28, 0.5), (0.6, 0.08, 0.37, 0.45)])  # fmt: skip
        ax.set(title=f"({'a' if kind == 'untuned' else 'b'}) {kind} PID", xlabel="time (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("jaw angle (deg)")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=4, fontsize=8,
               frameon=False)  # fmt: skip
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    return fig


def _figure11_curves(
    ax: Any, *, ref: Reference, model: Trajectory, act: Trajectory, ok: np.ndarray, med: int
) -> None:
    """Figure 11's curves on ``ax``: the actual gripper's seeds ``ok`` as a band, its seed
    ``med`` and the model."""
    ax.plot(ref.t_s, ref.values_deg, "k--", lw=1, label="desired")
    if ok.any():
        ax.fill_between(act.t, act.y[ok].min(axis=0), act.y[ok].max(axis=0), color="C1",
                        alpha=0.3, lw=0,
                        label=f"actual (simulated), min-max of {int(ok.sum())} seeds")  # fmt: skip
    ax.plot(act.t, act.y[med], color="C1", lw=0.8, label="actual, median seed")
    ax.plot(model.t, model.y_true[0], color="C0", lw=1.2, label="model (TF test2)")


def _table34_row(
    label: str, gains: Sequence[float], sign: int, ref: Reference, seeds: np.ndarray
) -> tuple[str, Trajectory, Trajectory, Metrics, Metrics]:
    """One row of Tables 3-4: the gains on TF test2 alone and on the actual gripper.

    Returns the table row, the model's and the actual gripper's trajectories, the model's
    metrics and the actual gripper's metrics of the true jaw angle.
    """
    hardware = "hardware" in label
    actual_opts = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping", sign=sign)
    model = simulate("test2", ref, gains=[gains], disturbance="ideal",
                     pid_options=PIDOptions(sign=sign, grasp=None))  # fmt: skip
    mm = compute_metrics(model)
    act = simulate("test2", ref, gains=np.tile(gains, (len(seeds), 1)),
                   disturbance="actual", seeds=seeds, randomize=True,
                   pid_options=actual_opts)  # fmt: skip
    am = compute_metrics(act)
    at = compute_metrics(act, "true")
    kind = "untuned" if label.startswith("untuned") else "tuned"
    paper = PAPER_TABLE4[kind]
    paper_txt = f"{paper[0]} / {paper[1]}" if not hardware else f"- / {paper[1]}"
    if not mm.stable[0]:
        model_txt, model_sd = "unstable (diverges)", "-"
    else:
        model_txt = (f"{mm.grip['overshoot_pct'][0]:.1f} / "
                     f"{mm.ungrip['overshoot_pct'][0]:.1f}")  # fmt: skip
        model_sd = f"{mm.run['sd_deg'][0]:.3f}"
    sd_act = am.run["sd_deg"]
    ok = np.isfinite(sd_act)  # a run that swings stop to stop has no settled SD (metrics: inf)
    if ok.sum() > 1:
        act_txt = f"{np.mean(sd_act[ok]):.3f} +/- {np.std(sd_act[ok], ddof=1):.3f}"
    elif ok.any():
        act_txt = f"{sd_act[ok][0]:.3f}"
    else:
        act_txt = "-"
    if not ok.all():
        act_txt += f" ({int((~ok).sum())} of {len(ok)} runs swing from stop to stop)"
    actual = load_disturbance("actual")
    rep = stability_report(load_plant("test2"), PIDGains(*gains), sign, disturbance=actual)
    if not rep.stable:
        # limits keep the actual loop bounded: it runs into a stop and stays there
        act_txt += " (unstable loop: pinned at a stop)"
        margin_txt = "unstable"
    else:
        gm = "inf" if rep.gain_margin_db is None else f"{rep.gain_margin_db:.1f}"
        margin_txt = f"{gm} / {rep.ms:.2f}"
    os_txt = (f"{np.mean(at.grip['overshoot_pct']):.1f} / "
              f"{np.mean(at.ungrip['overshoot_pct']):.1f}")  # fmt: skip
    sign_txt = "e = r - y" if sign == 1 else "e = y - r"
    row = (
        f"| {label} | {gains[0]} | {gains[1]} | {gains[2]} | {sign_txt} | {model_txt} | "
        f"{os_txt} | {margin_txt} | {model_sd} | {act_txt} | {paper_txt} |"
    )
    return row, model, act, mm, at


def _sign_section(lines: list[str]) -> None:
    lines += [
        "## 4. The hardware gains and the error-sign convention",
        "",
        "Each Table-3 gain set on each plant's nominal model, for both sign conventions: the",
        "largest closed-loop |z| of the 1 ms loop (exact ZOH at 1 ms, Forward Euler PID: the",
        "paper's Simulink model), and the verdict with the servo's 20 ms command hold (the loop",
        "as the hardware runs it, lifted to the refresh period; its gain margin in dB).",
        "",
        "| gains | sign | test1 | test2 | test3 | test4 |",
        "|---|---|---|---|---|---|",
    ]
    for label, gains in PAPER_GAINS.items():
        for sign in (1, -1):
            cells = []
            for name in PLANTS:
                rep = stability_report(
                    load_plant(name), PIDGains(*gains), sign, disturbance=load_disturbance("actual")
                )
                fast = rep.loop_1ms
                verdict = "stable" if fast["stable"] else "**unstable**"
                if rep.stable:
                    gm = rep.gain_margin_db
                    held = f"stable ({'inf' if gm is None else f'{gm:.1f}'} dB)"
                else:
                    held = "**unstable**"
                cells.append(f"{fast['max_pole_magnitude']:.8f} {verdict}; hold: {held}")
            sign_txt = "e = r - y" if sign == 1 else "e = y - r"
            lines.append(f"| {label} | {sign_txt} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "The hardware gains (negative P and I) are unstable on every transfer function with the",
        "error defined as r - y; with e = y - r they are stable on tests 2-4. The paper does not",
        "state its sign convention; the hardware loop evidently fed back the opposite way.",
        "test1 has no stable gain set here: its slow complex poles (0.056 rad/s) with integral",
        "action leave a closed-loop pair at |z| ~ 1.0001 (a growth time constant of about 10 s).",
        "",
    ]


def reproduce(
    out: Path,
    n_seeds: int = 10,
    command: str | None = None,
    log: Callable[[str], None] | None = None,
) -> tuple[Path, Path]:
    """Write ``out/paper_reproduction.md`` and its figures under ``out/figures``; return both
    paths (``command``: the command line, for the provenance sidecar; ``log``: told each
    section as it starts)."""
    say = log or (lambda _line: None)
    import matplotlib

    matplotlib.use("Agg")
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    seeds = np.arange(1000, 1000 + n_seeds)
    lines = [
        "# Reproducing the paper",
        "",
        f"Written by `python -m tuners.paper`. Paper: {paper.CITATION}. Provenance (commit, "
        "date, version, machine): `paper_reproduction.provenance.json`.",
        "",
        "The simulated actual gripper (`actual` preset, nominal values; randomised per seed):",
        "",
        "```",
        describe(load_disturbance("actual")),
        "```",
        "",
    ]
    # the page, its figures and the sidecar all or none (a full disk)
    with write_group(), collect_provenance(out, "paper_reproduction", command=command):
        say("the four plants (Table 1, Figure 7)...")
        _plants_section(lines, fig_dir, seeds)
        say(f"Table 2: the SDs over {n_seeds} seeds of the actual gripper (Figure 9)...")
        _table2_section(lines, fig_dir, seeds)
        say("Tables 3-4: the paper's gains on TF test2 (Figure 11)...")
        _table34_section(lines, fig_dir, seeds)
        say("the hardware gains' sign convention...")
        _sign_section(lines)
        path = write_atomic(out / "paper_reproduction.md", "\n".join(lines))
    return path, fig_dir
