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

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gripper_env import paper
from gripper_env.evaluation.metrics import Metrics, compute_metrics, fit_percent, sample_sd
from gripper_env.evaluation.stability import stability_report
from gripper_env.io.files import collect_provenance, save_figure, write_atomic
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
    fig, ax = plt.subplots(figsize=(9, 4.5))
    ax.plot(ref.t_s, ref.values_deg, "k--", lw=1, label="desired")
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
        ax.plot(traj.t, traj.y_true[0], label=f"TF {name}")
    actual = simulate("test2", ref, gains=None, disturbance="actual", seeds=seeds[:1])
    ax.plot(actual.t, actual.y[0], lw=0.8, label="actual (simulated, measured)")
    ax.set(xlabel="time (s)", ylabel="jaw angle (deg)", title="Open-loop step responses")
    ax.legend(loc="center right", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
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
        ax.plot(actual.t[window], actual.y[0, window], lw=1.2, label="actual (simulated)")
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
            ax.plot(traj.t[window], traj.y_true[0, window], lw=1, label=f"TF {name}")
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
    import matplotlib.pyplot as plt

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
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    findings = {}
    for label, gains in PAPER_GAINS.items():
        hardware = "hardware" in label
        for sign in (1, -1) if hardware else (1,):
            row, model, act, mm, at = _table34_row(label, gains, sign, ref, seeds)
            lines.append(row)
            findings[(label, sign)] = (mm, at)
            if not hardware:
                kind = "untuned" if label.startswith("untuned") else "tuned"
                ax = axes[0] if kind == "untuned" else axes[1]
                ax.plot(ref.t_s, ref.values_deg, "k--", lw=1, label="desired")
                ax.plot(model.t, model.y_true[0], lw=1.2, label="model (TF test2)")
                ax.plot(act.t, act.y[0], lw=0.9, label="actual (simulated)")
                ax.set(title=f"({'a' if kind == 'untuned' else 'b'}) {kind} PID",
                       xlabel="time (s)")  # fmt: skip
                ax.grid(alpha=0.3)
    axes[0].set_ylabel("jaw angle (deg)")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, fig_dir / "figure11_pid.png", dpi=110)
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
                     pid_options=PIDOptions(sign=sign))  # fmt: skip
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
    rep = stability_report("test2", PIDGains(*gains), sign)
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
                rep = stability_report(name, PIDGains(*gains), sign)
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.paper",
        description="Reproduce the paper's tables and figures into results/.",
    )
    parser.add_argument(
        "--out", type=Path, default=Path("results"), help="output folder (default: results)"
    )
    parser.add_argument(
        "--seeds", type=int, default=10, help="disturbance seeds of the actual gripper (10)"
    )
    args = parser.parse_args(argv)
    if args.seeds < 2:
        parser.error("--seeds must be at least 2")
    import matplotlib

    matplotlib.use("Agg")
    fig_dir = args.out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    seeds = np.arange(1000, 1000 + args.seeds)
    command = " ".join(["python -m tuners.paper", *(sys.argv[1:] if argv is None else argv)])
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
    with collect_provenance(args.out, "paper_reproduction", command=command):
        _plants_section(lines, fig_dir, seeds)
        _table2_section(lines, fig_dir, seeds)
        _table34_section(lines, fig_dir, seeds)
        _sign_section(lines)
        path = write_atomic(args.out / "paper_reproduction.md", "\n".join(lines))
    print(f"wrote {path} and figures in {fig_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
