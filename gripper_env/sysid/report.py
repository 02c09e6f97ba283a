"""The report of an identification session: ``identification.md`` and its figures.

Table 1 (the identified transfer functions with their delays, fits on the estimation records
and on the validation record), Table 2 (the paper's validation stage 1 beside the paper's
numbers), and the actual gripper identified with the simulation core (friction, sensor, delay;
beside the truth when the gripper was simulated).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gripper_env import paper
from gripper_env.io.files import save_figure
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.plants import Plant
from gripper_env.sysid.experiments import IdentifiedExperiment, step_t63
from gripper_env.sysid.greybox import response_on
from gripper_env.sysid.logfile import read_log
from gripper_env.sysid.orders import Record
from gripper_env.sysid.session import IdentificationRun
from gripper_env.sysid.tfest import format_polynomial

__all__ = ["actual_figure", "experiment_figure", "render_report", "validation_figure"]


def _moves(desired: np.ndarray, gap: int = 1000) -> list[tuple[int, int]]:
    """``(start, end)`` sample indices of each move of the desired angle (changes less than
    ``gap`` samples apart belong to one move, so a staircase ramp is one move)."""
    steps = np.flatnonzero(np.diff(desired) != 0) + 1
    if steps.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(steps) >= gap)
    starts = np.concatenate([[steps[0]], steps[breaks + 1]])
    ends = np.concatenate([steps[breaks], [steps[-1]]])
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _window(move: tuple[int, int], dt: float, n: int) -> slice:
    """Samples to show around a move: a step from just before it, a ramp around its arrival."""
    start, end = move
    if (end - start) * dt < 0.1:
        return slice(max(0, start - round(0.5 / dt)), min(n, start + round(3.5 / dt)))
    return slice(max(0, end - round(3.0 / dt)), min(n, end + round(2.0 / dt)))


def experiment_figure(item: IdentifiedExperiment, path: Path) -> Path:
    """Measured vs model response of one experiment: the grip and the un-grip move (a step
    from just before it, a ramp around its arrival), and the residuals of the whole record."""
    import matplotlib.pyplot as plt

    est = item.estimate
    t, u, y = item.t_s, item.desired_deg, item.actual_deg
    dt = float(t[1] - t[0])
    y_hat = est.simulate(u)
    moves = _moves(u)[:2]
    fig = plt.figure(figsize=(10, 6))
    grid = fig.add_gridspec(2, 2, height_ratios=[3, 1.3])
    for col, move in enumerate(moves):
        w = _window(move, dt, len(t))
        kind = "grip" if u[move[1]] < u[move[0] - 1] else "un-grip"
        ramp = (move[1] - move[0]) * dt >= 0.1
        ax = fig.add_subplot(grid[0, col])
        ax.plot(t[w], u[w], color="0.5", ls="--", lw=1, label="desired")
        ax.plot(t[w], y[w], color="C0", lw=0.8, label="measured (actual)")
        ax.plot(t[w], y_hat[w], color="C1", lw=1.3, label="model")
        ax.set(
            title=f"({'ab'[col]}) {kind}{': end of the ramp' if ramp else ' step'}",
            xlabel="time (s)",
        )
        ax.grid(alpha=0.3)
        if col == 0:
            ax.set_ylabel("jaw angle (deg)")
            ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[1, :])
    ax.plot(t, y - y_hat, color="C3", lw=0.6)
    ax.set(xlabel="time (s)", ylabel="measured - model (deg)", title="whole record")
    ax.grid(alpha=0.3)
    exp = item.experiment
    fig.suptitle(
        f"{exp.name} ({exp.description}): G(s) = {est.paper_form()}, fit {est.fit_pct:.2f} %",
        fontsize=10,
    )
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)


def validation_figure(run: IdentificationRun, path: Path) -> Path:
    """The paper's Figure 9: grip and un-grip responses of the actual gripper and each model."""
    import matplotlib.pyplot as plt

    val = run.validation
    t, u = val.t_s, val.desired_deg
    dt = float(t[1] - t[0])
    (grip, _), (ungrip, _) = _moves(u)[:2]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for ax, start, title in ((axes[0], grip, "(a) grip"), (axes[1], ungrip, "(b) un-grip")):
        w = slice(max(0, start - round(0.5 / dt)), start + round(5.0 / dt))
        ax.plot(t[w], u[w], color="0.5", ls="--", lw=1, label="desired")
        ax.plot(t[w], val.actual_deg[w], color="C0", lw=1.4, label="actual (measured)")
        for i, (name, y_model) in enumerate(val.responses.items()):
            ax.plot(t[w], y_model[w], color=f"C{i + 1}", lw=1, label=f"model {name}")
        ax.set(title=title, xlabel="time (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("jaw angle (deg)")
    axes[1].legend(fontsize=8)
    fig.suptitle("Validation stage 1: direct response (the paper's Figure 9)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)


# ----------------------------------------------------------------------------------------------
# Report


def _poles(poles: np.ndarray) -> str:
    return ", ".join(
        f"{p.real:.4g}{p.imag:+.3g}j" if abs(p.imag) > 0 else f"{p.real:.4g}"
        for p in sorted(poles, key=lambda p: p.real)
    )


def _paper_tf(name: str) -> str:
    num, den, _fit = paper.PLANTS[name]
    return f"({format_polynomial(num)}) / ({format_polynomial(den)})"


def actual_figure(run: IdentificationRun, path: Path) -> Path:
    """The identified actual gripper on the validation record: measured, the grey-box model, and
    the best linear model, around the grip and the un-grip step."""
    import matplotlib.pyplot as plt

    assert run.actual is not None
    val = run.validation
    t, u, y = read_log(val.log_path)
    y_meas, y_grey = response_on(run.actual, Record(t, u, y))
    same = run.actual_from.split("_")[0]  # the linear model of the same record
    y_lin = val.responses[same]
    fit_lin = next(r.fit_pct for r in val.rows if r.name == same)
    dt = float(val.t_s[1] - val.t_s[0])
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for ax, (start, _), title in zip(axes, _moves(val.desired_deg)[:2], ("(a) grip", "(b) un-grip"),
                                     strict=False):  # fmt: skip
        w = slice(max(0, start - round(0.3 / dt)), start + round(2.0 / dt))
        tt = val.t_s[w]
        ax.plot(tt, val.desired_deg[w], color="0.5", ls="--", lw=1, label="desired")
        ax.plot(tt, y_meas[w], color="C0", lw=0.8, label="measured")
        ax.plot(tt, y_grey[w], color="C3", lw=1.4, label="identified actual gripper (core)")
        ax.plot(tt, y_lin[w], color="C1", lw=1,
                label=f"linear TF of the same record ({same}), fit {fit_lin:.2f} %")  # fmt: skip
        ax.set(title=title, xlabel="time (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("jaw angle (deg)")
    axes[1].legend(fontsize=8)
    a = run.actual
    fig.suptitle(
        f"Actual gripper identified from {run.actual_from}: fit on the validation record "
        f"{a.validation['fit_pct']:.2f} %"
        if a.validation
        else "",
        fontsize=10,
    )
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)


def _num(x: float, digits: int = 3) -> str:
    return "0" if abs(x) < 1e-6 else f"{x:.{digits}g}"


def _actual_section(run: IdentificationRun, truth: Disturbance | None, true_plant: Plant | None,
                    figure: str | None) -> list[str]:  # fmt: skip
    a = run.actual
    assert a is not None
    f, s = a.friction, a.sensor
    val = a.validation or {}
    t = truth
    ident = a.identified()
    rows = [
        ("friction S (deg)", f.S_deg, f"{_num(f.S_range_deg[0])}..{_num(f.S_range_deg[1])}"
         + ("" if ident["S_deg"] else " (not pinned down)"),
         None if t is None else t.friction.S_deg),
        ("friction J (deg)", f.J_deg, f"{_num(f.J_range_deg[0])}..{_num(f.J_range_deg[1])}"
         + ("" if ident["J_deg"] else " (not pinned down)"),
         None if t is None else t.friction.J_deg),
        ("sensor noise (deg)", s.noise_std_deg, "", None if t is None else t.sensor.noise_std_deg),
        ("ADC step (deg)", s.lsb_deg, "", None if t is None else t.sensor.lsb_deg),
        ("ADC offset: angle at count 0 (deg)", s.adc_lo_deg, "modulo one count",
         None if t is None else t.sensor.adc_range_deg[0]),
        ("sensor delay (ms)", 1e3 * a.delay_s,
         f"{1e3 * a.delay_range_s[0]:.3g}..{1e3 * a.delay_range_s[1]:.3g}"
         + ("" if ident["delay_s"] else " (not pinned down)"),
         None if t is None else 1e3 * t.sensor.delay_s),
        ("sensor offset, measured - model (deg)", a.offset_deg, "not in the core",
         None if t is None else 0.0),
    ]  # fmt: skip
    lines = [
        "## 3. The actual gripper, identified with the simulation core",
        "",
        f"From the {run.actual_from} record, `gripper_env.sysid.greybox` fits the project's whole",
        "actual-gripper model (servo command path and stops kept from the `actual` preset;",
        "transfer function, friction, sensor noise, ADC grid and delay identified) by running",
        "the simulation core on batches of candidates: each (S, J) candidate's friction output",
        "from the core and the transfer function refitted to it, at every refresh phase of the",
        "servo with its own delay; the friction's 95 % intervals are the projections of its",
        "likelihood-ratio region (threshold calibrated by a parametric bootstrap), the delay's",
        "and the servo coefficients' hold every friction in that region (`python -m",
        "gripper_env.sysid coverage` checks that they cover the truth: "
        "`identification_coverage.md`).",
        "",
        "| parameter | identified | 95 % interval | truth (simulated gripper) | error |",
        "|---|---|---|---|---|",
    ]
    for name, value, rng, true in rows:
        err = ""
        if true is not None and abs(true) > 1e-9:
            err = f"{100 * (value - true) / true:+.1f} %"
        elif true is not None:
            err = f"{value - true:+.3g}" if abs(value - true) >= 1e-6 else "0"
        shown = "" if true is None else _num(true, 4)
        lines.append(f"| {name} | {_num(value, 4)} | {rng} | {shown} | {err} |")
    dyn = a.dynamics
    from gripper_env.sysid.greybox import coefficients_text

    coef = coefficients_text(dyn.param_names, dyn.params, a.dynamics_intervals)
    lines += [
        "",
        f"Servo dynamics: {dyn.paper_form()} (poles {_poles(dyn.poles)} rad/s; coefficients "
        f"with 95 % intervals: {coef})"
        + (
            f"; the simulated gripper's: ({format_polynomial(true_plant.num)}) / "
            f"({format_polynomial(true_plant.den)}), poles {_poles(true_plant.poles)} rad/s."
            if true_plant is not None
            else "."
        ),
        f"The model simulated by the core fits its own record at {a.fit_pct:.2f} % (residual "
        f"{a.residual_rms_deg:.3g} deg RMS against the sensor's "
        f"{np.sqrt(s.noise_std_deg**2 + s.lsb_deg**2 / 12):.3g} deg of noise and quantisation)"
        + (
            f" and the validation record at **{val['fit_pct']:.2f} %** (residual "
            f"{val['residual_rms_deg']:.3g} deg RMS)."
            if val
            else "."
        ),
        "With whole-degree servo commands the jaw breaks free after a whole number of degrees",
        "of travel, so S and J are known only to the degree bracket their thresholds fall in,",
        "while S - J (the offset while moving) is known continuously: the estimate is the middle",
        "of the interval.",
    ]
    lines += [f"Note: {w}" for w in a.warnings]
    if figure:
        lines += ["", f"![actual gripper on the validation record]({figure})"]
    return [*lines, ""]


def render_report(
    run: IdentificationRun,
    *,
    command: str,
    validation_text: str,
    figures: dict[str, str],
    true_plant: Plant | None = None,
    truth: Disturbance | None = None,
    plant_files: Sequence[Path] = (),
) -> str:
    """The markdown report: Table 1, Table 2 and the identified actual gripper.

    Parameters
    ----------
    run : IdentificationRun
        The session.
    command : str
        The command line that produced it.
    validation_text : str
        One sentence describing the validation profile.
    figures : dict
        ``"validation"``, ``"actual"`` (with a grey-box fit) and each test name -> figure path
        relative to the report.
    true_plant, truth : Plant and Disturbance, optional
        The simulated gripper, when simulated.
    plant_files : sequence of Path
        Plant (and preset) files written.
    """
    lines = _header(run, command)
    lines += _table1_section(run, true_plant, figures)
    lines += _table2_section(run, validation_text, figures)
    if run.actual is not None:
        lines += _actual_section(run, truth, true_plant, figures.get("actual"))
    lines += _plant_files_section(plant_files)
    return "\n".join(lines)


def _header(run: IdentificationRun, command: str) -> list[str]:
    """Title, the command, the headline fits and the record's source."""
    val = run.validation
    best = max(val.rows, key=lambda r: r.fit_pct)
    where = "simulated gripper" if run.source.startswith("simulated") else "board"
    headline = (
        f"**Fit on validation data** ({where}; the direct-response record, which no model was "
        f"estimated from): best transfer function {best.name} **{best.fit_pct:.2f} %**"
    )
    if run.actual is not None and run.actual.validation:
        headline += (
            f"; the actual gripper identified with the core **"
            f"{run.actual.validation['fit_pct']:.2f} %**"
        )
    return [
        "# System identification: the paper's Table 1 and Table 2, rerun",
        "",
        f"Written by `{command}`; its commit, date, version, machine and run times: "
        "`identification.provenance.json`.",
        f"Paper: {paper.CITATION}. Pipeline: `gripper_env.sysid.session`.",
        "",
        headline + ".",
        "",
        "The actual gripper:",
        "",
        "```",
        run.source,
        "```",
        "",
    ]


def _table1_section(
    run: IdentificationRun, true_plant: Plant | None, figures: dict[str, str]
) -> list[str]:
    """Section 1: the experiments and their transfer functions (Table 1, Figure 7): ours and the
    paper's in separate tables, with where each was measured."""
    fits = {row.name: row.fit_pct for row in run.validation.rows}
    simulated = true_plant is not None
    where = (
        "the project's simulated gripper (the simulation core, not hardware)"
        if simulated
        else "the board's gripper (hardware)"
    )
    lines = [
        "## 1. Experiments and identified transfer functions (Table 1, Figure 7)",
        "",
        "Each experiment runs open loop (the desired angle is the servo command), starting at",
        "rest at 92 deg; profiles as in `gripper_env.model.references` (the paper does not",
        "publish its timing): `step` = 1 s at 92, grip step to 21, 9 s, un-grip step to 92,",
        "10 s; `slopeN` =",
        "1 s at 92, ramp to 21 over N s, 5 s hold, ramp back over N s, 5 s hold. Identification:",
        "`tfest` with 2 poles and 1 zero and no delay (the paper's structure; on the slopes the",
        "friction's lag would pose as dead time: section 3 identifies the delay with the",
        "friction), the model mapping deviations from the initial rest point.",
        "*fit % (estimation)* is MATLAB's",
        "`compare` on the record the model was estimated from, initial state estimated (the",
        "paper's *best fit*); *fit % (validation)* is on the direct-response record of section 2.",
        "t63: time for the model's step response to cover 63.2 % of the commanded move.",
        "",
        f"### Ours: identified on {where}",
        "",
        "| test | input (desired) | samples | identified TF | fit % (estimation) | fit % (validation) | poles (rad/s) | DC gain | t63 (s) |",  # noqa: E501
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for item in run.experiments:
        est, exp = item.estimate, item.experiment
        flag = "" if est.stable else " **unstable**"
        lines.append(
            f"| {exp.name} | {exp.description} | {item.t_s.size} | {est.paper_form()}{flag} | "
            f"{est.fit_pct:.2f} | {fits[exp.name]:.2f} | "
            f"{_poles(est.poles)} | {item.dc_gain:.3f} | {item.t63_s:.3f} |"
        )
    lines += [
        "",
        "### The paper's: identified on its hardware (its Table 1)",
        "",
        "| test | paper TF | paper fit % (estimation) |",
        "|---|---|---|",
    ]
    for item in run.experiments:
        name = item.experiment.name
        lines.append(f"| {name} | {_paper_tf(name)} | {paper.PLANTS[name][2]} |")
    lines += ["", *_comparability(simulated)]
    lines.append("")
    if true_plant is not None:
        t63 = step_t63(true_plant.num, true_plant.den, true_plant.dt_s)
        lines += [
            f"The simulated gripper's own transfer function ({true_plant.name}) is "
            f"({format_polynomial(true_plant.num)}) / ({format_polynomial(true_plant.den)}): "
            f"poles {_poles(true_plant.poles)} rad/s, t63 = {t63:.3f} s.",
        ]
        slopes = [i for i in run.experiments if i.experiment.profile.startswith("slope")]
        if slopes and all(i.t63_s > 2 * t63 for i in slopes):
            lines += [
                "Every slope model is more than twice as slow as the true plant: friction and",
                "whole-degree servo commands make the jaw lag a slow ramp, and a linear model",
                "absorbs that lag into its dynamics (on `--disturbance ideal` the same experiments",
                "recover the plant's poles; `tests/sysid/test_identify.py`). Section 3 models the",
                "friction instead.",
            ]
        lines.append("")
    lines += [
        "Each fit is reproducible from its log: `python -m tuners.sysid "
        "results/identification/<test>_<profile>.csv` (logs are written by this command, not "
        "committed).",
        "",
    ]
    for item in run.experiments:
        name = item.experiment.name
        lines.append(f"![{name}: measured vs model]({figures[name]})")
    return [*lines, ""]


def _comparability(simulated: bool) -> list[str]:
    """Why the two tables' fit % do not compare (when ours are on the simulated gripper)."""
    if not simulated:
        return [
            "Both tables are fits to hardware, but to different grippers, profiles and",
            "loggers: compare the models, not the fit %.",
        ]
    return [
        "**The two tables are not comparable.** Ours are fits to records of the project's",
        "simulation of the gripper: the paper's own test2 transfer function behind the `actual`",
        "preset's friction, quantised servo commands and sensor noise (see the top of this",
        "page). A linear model fitted to a simulation whose core is itself linear plus a few",
        "known nonlinearities fits it very well (99 % here); the paper's 95-96 % are fits to its",
        "physical gripper, whose dynamics no model in this project reproduces exactly. A",
        "hardware run of this command (`--port`) gives figures that compare with the paper's.",
    ]


def _table2_section(
    run: IdentificationRun, validation_text: str, figures: dict[str, str]
) -> list[str]:
    """Section 2: validation stage 1, the direct response (Table 2, Figure 9)."""
    val = run.validation
    lines = [
        "## 2. Validation stage 1: direct response (Table 2, Figure 9)",
        "",
        validation_text,
        "Every identified model is driven by the same desired angle as identified (at rest at",
        "its operating point). SD is the sample standard deviation of the angle over the run",
        "(ddof = 1); SD_Actual - SD_Test is the paper's column (signed); fit % is MATLAB's",
        "`compare` fit of the model's response to the actual measured one; *fit % as plant file*",
        "is the same model used the way plant files are (absolute angles from rest at 92 deg).",
        "",
        "| Data | Standard Deviation (SD) | SD_Actual - SD_Test | \\|SD gap\\| | fit % to actual | fit % as plant file | paper SD | paper SD_Actual - SD_Test |",  # noqa: E501
        "|---|---|---|---|---|---|---|---|",
        f"| Actual | {val.sd_actual_deg:.3f} | | | | | {paper.TABLE2_SD['actual']} | |",
    ]
    for row in val.rows:
        paper_sd = paper.TABLE2_SD[row.name]
        lines.append(
            f"| Test {row.name.removeprefix('test')} | {row.sd_deg:.3f} | {row.sd_gap_deg:.3f} | "
            f"{row.abs_sd_gap_deg:.3f} | {row.fit_pct:.2f} | {row.fit_pct_plant:.2f} | "
            f"{paper_sd:.3f} | {paper.TABLE2_SD['actual'] - paper_sd:.3f} |"
        )
    agree = "agree" if val.criteria_agree else "**disagree**"
    by_gap = " < ".join(r.name for r in sorted(val.rows, key=lambda r: r.abs_sd_gap_deg))
    by_fit = " > ".join(r.name for r in sorted(val.rows, key=lambda r: -r.fit_pct))
    lines += [
        "",
        f"Best model by the paper's criterion (smallest |SD gap|): **{val.best_by_sd_gap}**; by "
        f"fit %: **{val.best_by_fit}**. The two criteria {agree} on the best model (the paper "
        f"chose test2 by SD gap). Full rankings: |SD gap| {by_gap}; fit % {by_fit}.",
        "An SD compares only the spread of two responses, not their shape in time: it",
        "cannot see a lag or an offset that leaves the spread unchanged, and a gap of a few",
        "hundredths of a degree is within run-to-run noise; fit % compares the responses sample",
        "by sample.",
        "",
        "The paper's four transfer functions on the same validation run (absolute angles, the TF",
        "alone, as `gripper_env.paper` drives them):",
        "",
        "| paper TF | SD | SD_Actual - SD_Test | fit % to actual |",
        "|---|---|---|---|",
    ]
    for row in val.paper_rows:
        lines.append(
            f"| {row.name} | {row.sd_deg:.3f} | {row.sd_gap_deg:.3f} | {row.fit_pct:.2f} |"
        )
    lines += ["", f"![Figure 9: direct response]({figures['validation']})", ""]
    return lines


def _plant_files_section(plant_files: Sequence[Path]) -> list[str]:
    """Section 4: the plant files and presets written (none: no section)."""
    if not plant_files:
        return []
    lines = ["## 4. Plant files and presets", ""]
    lines += [f"- `{p}`" for p in plant_files]
    lines += [
        "",
        "Each plant file loads with `gripper_env.model.plants.load_plant(PATH)` and runs wherever",
        "a plant is accepted (`--plant PATH`); it holds the transfer function only (the",
        "operating point and delay it was identified with are in its description). The",
        "identified actual gripper is a plant file and a disturbance preset: tune on it",
        "with `python -m tuners.optuna --plant PLANT.yaml --disturbance PRESET.yaml`.",
        "",
    ]
    return lines
