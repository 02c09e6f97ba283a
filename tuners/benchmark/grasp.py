"""``python -m tuners.benchmark.grasp``: the grasp-and-hold scenario on the benchmark's grippers.

The jaw closes on an object and holds it (:mod:`gripper_env.evaluation.grasp`): time to grasp,
holding force, the lowest force over the hold window, whether the overload criterion trips, the
servo's peak heat, and whether the object is held. The Arduino (hobby-servo) gripper runs with
the paper's tuned and untuned gains, the committed gains files of the benchmark
(``<gains-from>/<plant>/<row>.json``: the paper's hardware gains, Optuna, the best textbook
rules) and the servo alone (no host loop, commanded the close angle), on the actual-gripper
preset over the held-out seeds. Each PID runs twice, side by side: the plain PID (the grasp
mode off) and with the PID's grasp mode (:class:`gripper_env.model.pid.GraspOptions`; a gains
file's own setting, else the default).

Writes ``<out>/grasp.md`` (the table), ``<out>/grasp.json`` (the scenario, the servo, the
overload criterion and every row), ``<out>/figures/grasp.png`` (jaw angle and force against
time per controller) and the run's provenance sidecar ``<out>/grasp.provenance.json``.

The bus servos (``--bus``, default STS3215 and XL330) add their rows on their shipped models
(:func:`bus_rows`): the tuned registers of ``<gains-from>/bus/<servo>_registers.json``, the
factory's and the community's, held against the servo's own overload and thermal protection.
Other grippers add their rows through ``extra`` (:func:`grasp_rows`, :func:`main`): callables
that return lists of :class:`~gripper_env.evaluation.grasp.GraspResult`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.evaluation.bus_servo import GRASP_MAX_S, HOLD_S
from gripper_env.evaluation.grasp import (
    CONTINUOUS_CURRENT_FRACTION,
    FULL_STALL_LIMIT_S,
    GRASP_FRACTION,
    SERVO_NAME,
    STALL_TORQUE_NM,
    THERMAL_TIME_CONSTANT_S,
    GraspResult,
    GraspRun,
    GraspScenario,
    describe_gains,
    simulate_grasp,
    stall_force_n,
)
from gripper_env.io.files import collect_provenance, write_atomic, write_result_json
from gripper_env.model.disturbances import Disturbance, load_disturbance
from gripper_env.model.gains_file import load_gains_file
from gripper_env.model.pid import GraspOptions, PIDGains, PIDOptions
from gripper_env.model.plants import Plant, load_plant
from tuners import cli
from tuners.settings import EvaluationSettings, load_settings

__all__ = [
    "BUS_FAMILIES",
    "COMMITTED_ROWS",
    "WITH_MODE",
    "GainSet",
    "RowProvider",
    "arduino_runs",
    "benchmark_grasp",
    "benchmark_section",
    "both_ways",
    "build_parser",
    "bus_context",
    "bus_rows",
    "gain_sets",
    "grasp_rows",
    "main",
    "render_markdown",
    "result_json",
    "table_lines",
]

#: A source of more rows (another gripper): called once, returns its results.
RowProvider = Callable[[], list[GraspResult]]

#: The committed gains files read from ``<gains-from>/<plant>/`` (table order; a missing one is
#: left out and said): the paper's hardware gains (admitted to the headline), Optuna, the
#: headline's best textbook design (tuned on test2-test4) and the textbook rules best tuned
#: for one identification.
COMMITTED_ROWS = (
    "manual-paper-hw-tuned",
    "optuna",
    "classical-amigo-pi-robust",
    "classical-simc",
    "classical-pidtune",
)
#: The paper's Table-3 presets of :mod:`tuners.manual`, run from their gains (no file needed).
PAPER_PRESETS = ("paper-tuned", "paper-untuned")
#: The row without a host loop: the servo commanded the close angle directly.
SERVO_ALONE = "servo alone"
#: What a PID row with the grasp mode adds to its label.
WITH_MODE = " + grasp mode"


@dataclass(frozen=True)
class GainSet:
    """A controller of the Arduino gripper: its label, gains (``None``: no host loop) and PID
    options (limits, anti-windup, sign, grasp mode)."""

    label: str
    gains: PIDGains | None
    options: PIDOptions


def both_ways(label: str, gains: PIDGains, options: PIDOptions) -> list[GainSet]:
    """A PID as two controllers: plain (the grasp mode off), then with the grasp mode
    (``options``' own, else the default), labelled ``label`` and ``label + grasp mode``."""
    mode = options.grasp if options.grasp is not None else GraspOptions()
    return [
        GainSet(label, gains, dataclasses.replace(options, grasp=None)),
        GainSet(label + WITH_MODE, gains, dataclasses.replace(options, grasp=mode)),
    ]


def gain_sets(
    plant: str, gains_from: Path | None, settings: EvaluationSettings
) -> tuple[list[GainSet], list[str]]:
    """The servo alone, the paper's presets and the committed gains files of ``plant`` found
    under ``gains_from``, each PID plain and with the grasp mode (:func:`both_ways`); and the
    files not found (``gains_from`` ``None``: none looked for)."""
    from tuners.manual import PAPER_GAINS

    _, actual = settings.options(1)
    sets = [GainSet(SERVO_ALONE, None, actual)]
    for name in PAPER_PRESETS:
        preset = PAPER_GAINS[name]
        sets += both_ways(name, preset.gains, settings.options(preset.sign)[1])
    missing: list[str] = []
    if gains_from is None:
        return sets, missing
    for name in COMMITTED_ROWS:
        path = Path(gains_from) / plant / f"{name}.json"
        if not path.is_file():
            missing.append(str(path))
            continue
        f = load_gains_file(path)
        label = name.removeprefix("manual-")
        if f.options.sign != 1:
            label += " (e = y - r)"
        sets += both_ways(label, f.gains, f.options)
    return sets, missing


def arduino_runs(
    plant: str,
    *,
    scenario: GraspScenario,
    seeds: Sequence[int] | np.ndarray,
    gains_from: Path | None = Path("results"),
    disturbance: str | Disturbance = "actual",
    settings: EvaluationSettings | None = None,
    log: Callable[..., None] = print,
) -> list[tuple[GainSet, GraspRun]]:
    """Every :func:`gain_sets` controller through ``scenario`` on the Arduino gripper."""
    s = settings or load_settings(EvaluationSettings)
    p = load_plant(plant)
    dist = load_disturbance(disturbance)
    sets, missing = gain_sets(p.name, gains_from, s)
    for path in missing:
        log(f"  {path}: not found, its row left out")
    runs = []
    for g in sets:
        run = simulate_grasp(p, dist, g.gains, scenario, options=g.options, seeds=seeds,
                             randomize=s.randomize)  # fmt: skip
        runs.append((g, run))
    return runs


def _gripper(plant: str, disturbance: str) -> str:
    return f"arduino {plant} ({disturbance})"


def _rows(runs: Sequence[tuple[GainSet, GraspRun]], gripper: str) -> list[GraspResult]:
    return [run.result(gripper, describe_gains(g.gains, g.label)) for g, run in runs]


def grasp_rows(
    plant_name: str,
    *,
    extra: Sequence[RowProvider] = (),
    scenario: GraspScenario | None = None,
    seeds: Sequence[int] | np.ndarray | None = None,
    gains_from: Path | None = Path("results"),
    disturbance: str = "actual",
    settings: EvaluationSettings | None = None,
) -> list[GraspResult]:
    """The table's rows: the Arduino gripper on ``plant_name`` with every controller of
    :func:`gain_sets` (held-out seeds of the evaluation settings unless ``seeds``), then the rows
    of each ``extra`` provider in turn (another gripper: the bus servo)."""
    s = settings or load_settings(EvaluationSettings)
    runs = arduino_runs(plant_name, scenario=scenario or GraspScenario(),
                        seeds=s.seeds.seeds() if seeds is None else seeds,
                        gains_from=gains_from, disturbance=disturbance, settings=s,
                        log=lambda *a: None)  # fmt: skip
    rows = _rows(runs, _gripper(plant_name, disturbance))
    for provider in extra:
        rows += provider()
    return rows


#: The bus servos whose rows the command adds by default (``--bus``).
BUS_FAMILIES = ("sts3215", "xl330")


def bus_rows(family: str, gains_from: Path | None = Path("results")) -> list[GraspResult]:
    """The bus servo ``family``'s grasp-and-hold rows on its shipped model: the tuned registers
    of ``<gains_from>/bus/<family>_registers.json`` when that file exists, then the factory and
    community registers, through :func:`gripper_env.evaluation.bus_servo.hold_goal` (the goal
    jumps to the closed stop with an object in the jaws; held 10 s; the servo's own overload
    and thermal protection)."""
    from gripper_env.evaluation.bus_servo import hold_goal, hold_metrics
    from gripper_env.model.bus_servo import load_bus_servo, load_registers_file
    from gripper_env.sim.bus_servo import simulate_bus

    model = load_bus_servo(family)
    sets = dict(model.baselines())
    if gains_from is not None:
        path = Path(gains_from) / "bus" / f"{family}_registers.json"
        if path.is_file():
            tuned_model, regs, _doc = load_registers_file(path)
            if tuned_model.family != family:
                raise ValueError(f"{path}: registers of a {tuned_model.family}, not a {family}")
            sets = {"tuned": regs, **sets}
    goal = hold_goal(model)
    run = simulate_bus(model, list(sets.values()), goal, with_object=True)
    stall = model.stall_force_n()
    gripper = f"{family} bus servo (model {model.name})"
    rows = []
    for i, (name, regs) in enumerate(sets.items()):
        h = hold_metrics(model, run, i)
        rows.append(
            GraspResult(
                gripper=gripper,
                controller=f"{name} {regs.label()}",
                time_to_grasp_s=h.time_to_grasp_s,
                holding_force_n=h.holding_force_n,
                holding_force_pct=100.0 * h.holding_force_n / stall,
                min_force_n=h.min_force_n,
                overload=h.overload,
                overload_at_s=h.trip_at_s,
                held=h.held,
                hold_s=HOLD_S - GRASP_MAX_S,
            )
        )
    return rows


def bus_context(families: Sequence[str]) -> str:
    """The report's paragraph on the bus servos' scenario (their models' own numbers)."""
    from gripper_env.evaluation.bus_servo import HOLD_FORCE_FRAC
    from gripper_env.model.bus_servo import load_bus_servo

    parts = []
    for family in families:
        m = load_bus_servo(family)
        pr = m.protection
        parts.append(
            f"{family}: object at {m.jaw.object_deg:g} deg, goal the closed stop "
            f"{m.jaw.limits_deg[0]:g} deg, stall force {m.stall_force_n():.1f} N, overload after "
            f"{pr.overload_time_s:g} s at or above {100 * pr.overload_duty:g} % duty, overheat at "
            f"{pr.max_temp_c:g} C"
        )
    return (
        "**Bus servos** (`tuners.bus`): the servo's own register PID at 1 kHz on its "
        f"model; the goal jumps to the closed stop and is held {HOLD_S:g} s; held means at "
        f"least {100 * HOLD_FORCE_FRAC:g} % of the servo's stall force from {GRASP_MAX_S:g} s "
        "to the end, grasped within it, and no trip of the servo's own protection (the overload "
        "timer, the thermal cut-out). One run each (the model is deterministic). "
        + "; ".join(parts)
        + ". The tuned rows are `results/bus/<servo>_registers.json` "
        "(`python -m tuners.bus.tune --model <servo> --out results/bus`)."
    )


def _trip_s(fraction: float) -> float:
    """When a constant push at ``fraction`` of stall trips the thermal criterion, from cold (s)."""
    trip = CONTINUOUS_CURRENT_FRACTION**2
    return -THERMAL_TIME_CONSTANT_S * math.log(1.0 - trip / fraction**2)


def _num(x: float, fmt: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)


def table_lines(rows: Sequence[GraspResult]) -> list[str]:
    """The Markdown table of ``rows``."""
    lines = [
        "| gripper | controller | time to grasp s | holding force N (% of stall) | "
        "min force N | peak heat (% of trip) | overload (at s) | held |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        overload = f"yes ({r.overload_at_s:.2f})" if r.overload_at_s is not None else "no"
        if r.overload and r.overload_at_s is None:
            overload = "yes"
        grasp = _num(r.time_to_grasp_s, ".3f") if math.isfinite(r.time_to_grasp_s) else "never"
        lines.append(
            f"| {r.gripper} | {r.controller} | {grasp} | {_num(r.holding_force_n, '.2f')} "
            f"({_num(r.holding_force_pct, '.0f')} %) | {_num(r.min_force_n, '.2f')} | "
            f"{_num(100 * r.peak_heat, '.0f')} | {overload} | {'yes' if r.held else '**no**'} |"
        )
    return lines


def render_markdown(
    rows: Sequence[GraspResult],
    *,
    scenario: GraspScenario | None = None,
    context: str = "",
    command: str = "python -m tuners.benchmark.grasp",
) -> str:
    """The report: the scenario and its criteria (``scenario``, default
    :class:`GraspScenario`'s), ``context`` (the plant, preset and seeds), the table, what it
    says."""
    sc = scenario or GraspScenario()
    lo, hi = sc.hold_window_s
    stall = stall_force_n(sc)
    obj = "no object" if sc.object_deg is None else f"an object at {sc.object_deg:g} deg"
    lines = [
        "# Grasp and hold",
        "",
        f"Generated by `{command}`. Provenance (commit, date, version, machine, wall time): "
        "`grasp.provenance.json`.",
        "",
        f"**The scenario.** The jaw rests open at {sc.open_deg:g} deg; at t = 0 it is commanded "
        f"to {sc.close_command_deg:g} deg, past {obj}, and must hold it from {lo:g} s to "
        f"{hi:g} s (the hold window, {sc.hold_s:g} s) with at least {sc.required_force_n:g} N "
        "at the fingertip (a 50 g object between two pads with friction coefficient 0.5 needs "
        "0.49 N; twice that). " + context,
        "",
        "**Force.** A position servo held against an object pushes with a torque that grows with "
        "how far its command lies beyond the jaw, `min(push / stall band, 1)` of its stall torque "
        "(the simulation core's mechanics block, stall band 5 deg on the preset), at the "
        f"fingertip `* {STALL_TORQUE_NM:.4f} N m / {sc.finger_lever_m:g} m` = {stall:.2f} N at "
        f"stall: the {SERVO_NAME}, 3.8 kg cm at 6 V (the paper names no servo; its Figure 1a "
        "shows this class).",
        "",
        "**Overload.** A hobby servo has no overload protection; its current is proportional "
        "to its torque, and what gives out is its winding. The criterion is the I^2 t thermal "
        f"model of motor protection: x' = (i^2 - x) / tau (i: the current as a fraction of "
        f"stall), tripping at x >= {CONTINUOUS_CURRENT_FRACTION:g}^2 (a brushed DC motor "
        f"carries {100 * CONTINUOUS_CURRENT_FRACTION:g} % of its stall current indefinitely: "
        f"Pololu's guidance), tau = {THERMAL_TIME_CONSTANT_S:.1f} s so that a full stall from "
        "cold trips after "
        f"{FULL_STALL_LIMIT_S:g} s (stall damage within seconds; hobby servo datasheets warn "
        f"against continuous stall). A push at 60 % of stall trips after {_trip_s(0.6):.1f} s, "
        f"one at 40 % after {_trip_s(0.4):.1f} s, one at "
        f"{100 * CONTINUOUS_CURRENT_FRACTION:g} % or less never. The peak heat is that state "
        "over the trip level, the highest of any run (100 % trips; a steady push at 20 % of "
        "stall settles at 64 %).",
        "",
        _mode_paragraph(),
        "",
        f"**Read it as the worst case over the runs**: time to grasp (from the close command "
        f"until the jaw touches the object and the force reaches {100 * GRASP_FRACTION:g} % of "
        "its hold value) of the slowest run, the lowest force of any run, the highest heat, the "
        "earliest trip; held only if every run held. The holding force is the mean over the runs "
        "and the window.",
        "",
        *table_lines(rows),
        "",
    ]
    held = [r.controller for r in rows if r.held]
    tripped = [r for r in rows if r.overload]
    lines += [
        "## What it says",
        "",
        f"* Held: {len(held)} of {len(rows)} ({', '.join(held) if held else 'none'}).",
    ]
    if tripped:
        first = min(tripped, key=lambda r: r.overload_at_s or math.inf)
        lines.append(
            f"* Overloaded: {len(tripped)} (the first, {first.controller}, at "
            f"{_num(first.overload_at_s or math.nan, '.2f')} s)."
        )
    plain = [r for r in rows if r.gripper.startswith("arduino") and not r.controller.startswith(
        SERVO_ALONE) and WITH_MODE not in r.controller]  # fmt: skip
    mode = [r for r in rows if WITH_MODE in r.controller]
    if plain:
        lines.append(
            f"* The plain PID: {sum(r.held for r in plain)} of {len(plain)} held, "
            f"{sum(r.overload for r in plain)} tripped the thermal limit. The object keeps the "
            "jaw short of the reference, so the error never vanishes and the integrator charges "
            "until the PID's output limit (the servo's command range), far past the object: "
            "full stall current until something gives. The servo's own position loop (no host "
            "loop) squeezes with a force set by how far its command lies past the object."
        )
    if mode:
        held_mode = [r for r in mode if r.held]
        lost = [r for r in mode if not r.held]
        text = (
            f"* With the grasp mode: {len(held_mode)} of {len(mode)} held, "
            f"{sum(r.overload for r in mode)} tripped; peak heat "
            f"{_span([100 * r.peak_heat for r in mode], '.0f')} % of the trip, holding force "
            f"{_span([r.holding_force_n for r in mode], '.2f')} N, grasped in "
            f"{_span([r.time_to_grasp_s for r in mode], '.2f')} s."
        )
        if lost:
            text += " Not held: " + "; ".join(
                f"{r.controller} (lowest force {_num(r.min_force_n, '.2f')} N"
                + (", grasped after the hold window opened" if not r.time_to_grasp_s < 1.0 else "")
                + ")"
                for r in lost
            ) + "."  # fmt: skip
        lines.append(text)
    lines += [
        "",
        "Figure: `figures/grasp.png` (jaw angle, force and heat against time per controller, the "
        "mean over the runs; dashed the plain PID, solid with the grasp mode).",
        "",
    ]
    return "\n".join(lines)


def _span(values: Sequence[float], fmt: str) -> str:
    """``"lo-hi"`` of the finite values (``"x"`` if they agree, ``"-"`` if none)."""
    ok = [v for v in values if v is not None and math.isfinite(v)]
    if not ok:
        return "-"
    lo, hi = format(min(ok), fmt), format(max(ok), fmt)
    return lo if lo == hi else f"{lo}-{hi}"


def _pct(push_deg: float, stall_band_deg: float = 5.0) -> str:
    """A push (deg) as a percentage of stall on the stall band."""
    return f"{100 * min(max(push_deg, 0.0) / stall_band_deg, 1.0):g}"


def _mode_paragraph(mode: GraspOptions | None = None) -> str:
    """The grasp mode and its settings, for the report."""
    g = mode or GraspOptions()
    return (
        "**The grasp mode** (`gripper_env.model.pid.GraspOptions`, on by default; the same in "
        "the simulation core, the firmware and its Python twin). The PID reads only the "
        "potentiometer, the reference and its own output: once its command has stood at least "
        f"{g.push_deg:g} deg (push) past the jaw, the jaw at least {g.short_deg:g} deg short of "
        f"the reference and still within {g.still_deg:g} deg, for {1000 * g.dwell_s:g} ms "
        "(dwell), it freezes the integrator and holds the command "
        f"{g.squeeze_deg:g} deg (squeeze) past the contact, never past the reference: "
        f"{100 * min(g.squeeze_deg / 5.0, 1.0):g} % of stall on the 5-deg stall band, a force "
        f"and current limit under the {100 * CONTINUOUS_CURRENT_FRACTION:g} % the servo carries "
        "indefinitely (with whole-degree servo commands the push lands within half a degree of "
        f"the squeeze: {_pct(g.squeeze_deg - 0.5)}-{_pct(g.squeeze_deg + 0.5)} % of stall; "
        f"{_pct(g.squeeze_deg + 0.5)} % would trip after "
        f"{_trip_s((g.squeeze_deg + 0.5) / 5.0):.0f} s). It lets go when the reference comes "
        "back to or over the contact (opening) or the jaw moves on past it, and the PID resumes "
        "from the held command. Each PID row below runs plain (the mode off) and with it "
        f"(`{WITH_MODE.strip()}`)."
    )


def result_json(
    rows: Sequence[GraspResult],
    *,
    scenario: GraspScenario,
    plant: str,
    disturbance: str,
    seeds: Sequence[int],
) -> dict[str, Any]:
    """``grasp.json``'s content."""
    return {
        "scenario": scenario.as_dict(),
        "gripper": {
            "plant": plant,
            "disturbance": disturbance,
            "seeds": [int(s) for s in seeds],
            "servo": SERVO_NAME,
            "stall_torque_nm": STALL_TORQUE_NM,
            "stall_force_n": stall_force_n(scenario),
            "stall_torque_source": "3.8 kg cm at 6 V (Pololu item 3441; FEETECH FS5103B)",
        },
        "overload_criterion": {
            "model": "I^2 t: x' = (i^2 - x) / tau, trip at x >= i_c^2",
            "continuous_current_fraction": CONTINUOUS_CURRENT_FRACTION,
            "full_stall_trip_s": FULL_STALL_LIMIT_S,
            "tau_s": THERMAL_TIME_CONSTANT_S,
        },
        "grasp_fraction": GRASP_FRACTION,
        "grasp_mode": GraspOptions().as_dict(),
        "rows": [r.as_dict() for r in rows],
    }


def benchmark_grasp(
    plant: Plant,
    disturbance: Disturbance,
    rows: dict[str, dict[str, Any]],
    settings: EvaluationSettings,
    scenario: GraspScenario | None = None,
) -> list[dict[str, Any]]:
    """The benchmark's grasp rows on one plant (:func:`benchmark_section` renders them): the
    servo alone and every PID row of ``rows`` (the benchmark's rows of that plant: ``P``, ``I``,
    ``D``, ``N``, ``sign``; learned controllers are left out), plain and with the grasp mode
    (:func:`both_ways`), over the held-out seeds, as :meth:`GraspResult.as_dict`."""
    sc = scenario or GraspScenario()
    seeds = settings.seeds.seeds()
    sets = [GainSet(SERVO_ALONE, None, settings.options(1)[1])]
    for name, row in rows.items():
        if row.get("controller") != "pid":
            continue
        gains = PIDGains(row["P"], row["I"], row["D"], row["N"])
        sets += both_ways(name, gains, settings.options(int(row["sign"]))[1])
    gripper = _gripper(plant.name, disturbance.name)
    out = []
    for g in sets:
        run = simulate_grasp(plant, disturbance, g.gains, sc, options=g.options, seeds=seeds,
                             randomize=settings.randomize)  # fmt: skip
        out.append(run.result(gripper, describe_gains(g.gains, g.label)).as_dict())
    return out


def benchmark_section(grasp: dict[str, Any]) -> list[str]:
    """The benchmark report's section (Markdown lines) from its stored grasp data
    (``{"scenario": ..., "plants": {plant: [row dicts]}}``)."""
    sc = GraspScenario(**grasp["scenario"])
    lo, hi = sc.hold_window_s
    lines = [
        "",
        "## Grasp and hold",
        "",
        f"Each PID row and the servo alone (no host loop) closing on an object at "
        f"{sc.object_deg:g} deg, commanded {sc.close_command_deg:g} deg, held from {lo:g} to "
        f"{hi:g} s after the close command with at least {sc.required_force_n:g} N at the "
        f"fingertip; the hobby servo's force from the mechanics block "
        f"({stall_force_n(sc):.2f} N at stall on a {sc.finger_lever_m * 100:g} cm finger), "
        f"overload when its I^2 t estimate trips (a full stall: after {FULL_STALL_LIMIT_S:g} s). "
        f"Each PID plain and with the PID's grasp mode (`{WITH_MODE.strip()}`: the command held "
        f"{GraspOptions().squeeze_deg:g} deg past a blocked jaw). Worst case over the held-out "
        "seeds; the scenario, its criteria and a figure: `grasp.md` "
        "(`python -m tuners.benchmark.grasp`).",
    ]
    for plant, rows in grasp["plants"].items():
        results = [GraspResult.from_dict(r) for r in rows]
        held = sum(r.held for r in results)
        lines += ["", f"### {plant}: {held} of {len(results)} held", "", *table_lines(results)]
    return lines


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.benchmark.grasp",
        description="The grasp-and-hold scenario: time to grasp, holding force, overload.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--plant", default="test2", help="the Arduino gripper's plant")
    parser.add_argument("--disturbance", default="actual", help="actual-gripper preset")
    parser.add_argument("--out", type=Path, default=cli.DEFAULT_OUT,
                        help="output folder (the committed results/ are regenerated by "
                             "python -m tuners.results)")  # fmt: skip
    parser.add_argument(
        "--gains-from",
        type=Path,
        default=Path("results"),
        help="folder of the committed gains files (<folder>/<plant>/<row>.json)",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="the first N held-out seeds (default: all of the evaluation settings')",
    )
    parser.add_argument(
        "--bus",
        nargs="*",
        default=list(BUS_FAMILIES),
        metavar="SERVO",
        help="bus servos whose rows to add (sts3215, xl330, xl430; none: --bus with no names)",
    )
    parser.add_argument(
        "--eval-config",
        type=Path,
        default=None,
        help="evaluation settings; default configs/tuners/evaluation.yaml",
    )
    return parser


def main(argv: list[str] | None = None, *, extra: Sequence[RowProvider] = ()) -> int:
    """Entry point of ``python -m tuners.benchmark.grasp`` (``extra``: more rows, another
    gripper's)."""
    return cli.run(lambda a: _main(a, extra), argv)


def _main(argv: list[str] | None, extra: Sequence[RowProvider]) -> int:
    from tuners.plotting import grasp_plot

    args = cli.parse(build_parser(), argv)
    start = time.perf_counter()
    settings = load_settings(EvaluationSettings, args.eval_config)
    seeds = settings.seeds.seeds()
    if args.seeds is not None:
        if not 1 <= args.seeds <= len(seeds):
            raise ValueError(f"--seeds must be 1 to {len(seeds)}, got {args.seeds}")
        seeds = seeds[: args.seeds]
    plant = load_plant(args.plant)
    dist = load_disturbance(args.disturbance)
    scenario = GraspScenario()
    runs = arduino_runs(args.plant, scenario=scenario, seeds=seeds, gains_from=args.gains_from,
                        disturbance=dist, settings=settings)  # fmt: skip
    gripper = _gripper(plant.name, dist.name)
    rows = _rows(runs, gripper)
    for family in args.bus:
        rows += bus_rows(family, args.gains_from)
    for provider in extra:
        rows += provider()
    context = (
        f"Arduino gripper: plant {plant.name}, actual-gripper preset `{dist.name}` (the servo's "
        f"20 ms command hold and whole degrees, stiction, stops, ADC), {len(seeds)} held-out "
        f"seed{'s' if len(seeds) > 1 else ''} (friction, noise and stops drawn per seed); the "
        f"PID at 1 kHz, its output limited to the servo's 0-180 deg with clamping anti-windup, "
        "plain and with the grasp mode (below)."
    )
    if args.bus:
        context += "\n\n" + bus_context(args.bus)
    with collect_provenance(args.out, "grasp", command=args.command, started=start):
        content = result_json(rows, scenario=scenario, plant=plant.name, disturbance=dist.name,
                              seeds=[int(s) for s in seeds])  # fmt: skip
        write_result_json(args.out / "grasp.json", content)
        write_atomic(args.out / "grasp.md",
                     render_markdown(rows, scenario=scenario, context=context,
                                     command=args.command))  # fmt: skip
        grasp_plot([(g.label, run) for g, run in runs], args.out / "figures" / "grasp.png",
                   f"Grasp and hold: {gripper}, close command {scenario.close_command_deg:g} "
                   f"deg on an object at {scenario.object_deg:g} deg",
                   mode_suffix=WITH_MODE)  # fmt: skip
    print("\n".join(table_lines(rows)))
    print(f"wrote {args.out / 'grasp.md'}, grasp.json and figures/grasp.png in "
          f"{time.perf_counter() - start:.1f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
