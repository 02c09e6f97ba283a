"""``python -m tuners.bus.tune``: search a bus servo's integer registers with Optuna.

The search space is the registers themselves, integers in the servo's units: P, I, D and the
torque limit (:data:`SEARCH_SPACE`, per family). Every candidate is judged on the model
(:func:`gripper_env.evaluation.bus_servo.judge`): the cost is tracking (IAE, overshoot, settled
error, chatter) plus the time to grasp; the constraints are the loop's margins (``Ms <= 1.6``,
gain margin >= 6 dB, on the model, its uncertainty corners and every delay pair the
identification could not rule out), the D term's kick per encoder tick (at most 30 % of full
drive: a reading flickering between two ticks buzzes) and the hold (grasp within 1 s, hold 20 %
of stall force for 10 s, no trip of the protection the servo's own registers set). The sampler
is Optuna's multivariate TPE with those constraints (``Trial.set_constraint``), started from
the factory and community registers, then an integer pattern search from its best sets
(:func:`tune_registers`). The result - the best feasible registers, the baselines judged on the
same terms, the margins - goes to a JSON file that ``python -m tuners.bus.deploy`` takes, with a
figure of tracking and hold.

Examples
--------
``python -m tuners.bus.tune --model sts3215 --trials 300 --out results/bus``
``python -m tuners.bus.tune --model runs/bus/mine_model.json --out runs/bus``
``python -m tuners.bus.tune --model xl330 --operating-mode current_position`` (the Koch gripper:
P, I, D and the goal current; ``--goal-current 500`` keeps the goal current given)
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import optuna
from tqdm.auto import tqdm

from gripper_env.evaluation.bus_servo import (
    D_KICK_MAX,
    DELAY_TICKS,
    GM_MIN_DB,
    MS_MAX,
    BusScore,
    judge,
)
from gripper_env.io.config import MAX_CONFIG_BYTES, ConfigError, read_bounded
from gripper_env.io.files import collect_provenance, write_atomic
from gripper_env.model.bus_servo import (
    BusServoModel,
    RegisterSet,
    alternative_models,
    load_bus_servo,
    relative_uncertainties,
)
from tuners import cli
from tuners.conventions import conform

__all__ = ["SEARCH_SPACE", "constraint_value", "main", "search_space", "tune_registers"]

#: Integer search ranges per family: (low, high) of P, I, D and the torque limit register. The
#: STS3215's gains are one-byte registers (0-254); the XL's position gains go to 16383, searched
#: here up to where the loop is long unstable. The torque limit's floor is 10 % (below it the
#: jaw does not overcome its friction reliably).
SEARCH_SPACE: dict[str, dict[str, tuple[int, int]]] = {
    "sts3215": {"p": (1, 254), "i": (0, 64), "d": (0, 254), "torque_limit": (100, 1000)},
    "xl330": {"p": (10, 6000), "i": (0, 4000), "d": (0, 12000), "torque_limit": (90, 885)},
    "xl430": {"p": (10, 6000), "i": (0, 4000), "d": (0, 12000), "torque_limit": (90, 885)},
}
#: Current-based position mode (Dynamixel mode 5, the Koch gripper): the goal current (register
#: units, mA on the XL330) takes the torque limit's place, which stays the factory's PWM limit.
#: Without back-EMF damping the loop needs more D. P starts at an eighth of the lowest setting
#: the mode's records take (200): far below it the dead band is wider than the records ever saw
#: and the model extrapolates (a run beside other tests tuned P=13 I=33 D=1298, and the servo
#: then followed the model's prediction to 68.8 %; the feasible sets found lie at P 61-482).
CURRENT_SEARCH_SPACE: dict[str, tuple[int, int]] = {
    "p": (25, 6000), "i": (0, 4000), "d": (0, 16000), "goal_current": (50, 1750),
}  # fmt: skip


def search_space(
    model: BusServoModel, goal_current: int | None = None
) -> dict[str, tuple[int, int]]:
    """The registers searched for ``model`` and their ranges: :data:`SEARCH_SPACE`, or in
    current-based position mode :data:`CURRENT_SEARCH_SPACE` (without the goal current when it
    is ``goal_current``, given). The torque limit is capped at the servo's own maximum torque
    limit when the model carries a real servo's calibration (LeRobot's SO gripper:
    ``Max_Torque_Limit`` 500), and the goal current at an XL330's ``Current_Limit``: a tuned set
    never asks more than the owner allows."""
    if not model.current_mode:
        space = dict(SEARCH_SPACE[model.family])
    else:
        space = dict(CURRENT_SEARCH_SPACE)
        if goal_current is not None:
            del space["goal_current"]
    cal = model.calibration
    if cal is not None and cal.servo is not None and "torque_limit" in space:
        lo, hi = space["torque_limit"]
        top = cal.servo.max_torque_limit
        space["torque_limit"] = (min(lo, top), min(hi, top))
    current_limit = cal.servo.protection.get("current_limit") if cal and cal.servo else None
    if current_limit is not None and "goal_current" in space:  # an XL330's Current_Limit
        lo, hi = space["goal_current"]
        space["goal_current"] = (min(lo, current_limit), min(hi, current_limit))
    return space


def constraint_value(score: BusScore) -> float:
    """How far ``score`` is from feasible (0 when feasible): the sum of the scaled excesses."""
    if score.feasible:
        return 0.0
    m, h = score.robust_margins, score.hold
    v = max(score.d_kick - D_KICK_MAX, 0.0) / D_KICK_MAX
    if not m.stable:
        v += 10.0
    else:
        v += max(m.ms - MS_MAX, 0.0) + max(GM_MIN_DB - m.gm_db, 0.0) / GM_MIN_DB
    if h.overload:
        v += 1.0 + max(10.0 - (h.trip_at_s or 0.0), 0.0) / 10.0
    else:
        v += max(h.required_force_n - h.min_force_n, 0.0) / max(h.required_force_n, 1e-9)
        t = h.time_to_grasp_s if math.isfinite(h.time_to_grasp_s) else 10.0
        v += max(t - 1.0, 0.0)
    return max(v, 1e-6)


def tune_registers(
    model: BusServoModel,
    *,
    trials: int = 300,
    seed: int = 0,
    rel_std: dict[str, float] | None = None,
    alternatives: Sequence[BusServoModel] = (),
    progress: bool = True,
    batch: int = 16,
    polish: int = 600,
    goal_current: int | None = None,
    judge_fn: Callable[..., list[BusScore]] = judge,
) -> tuple[BusScore, optuna.Study]:
    """The best feasible registers for ``model``: ``trials`` TPE trials, then local searches of
    at most ``polish`` judged candidates each.

    Two stages share one Optuna study (every judged set is a trial):

    1. **global**, ``trials`` trials: multivariate TPE under the constraints, started from
       the factory and community registers, asked ``batch`` candidates at a time (constant liar)
       and judged in one batch of the simulation core. Each register is sampled on a log scale
       (the study's parameter ``"p+1"`` is the register plus one, so 0 stays reachable): the
       gains matter by their ratios, and on a linear scale the integrator's useful range near 0
       is a sliver of 0-4000 that the random start almost never draws, which left TPE in the
       hunting high-I basin for some seeds;
    2. **local**, each until it converges or has judged ``polish`` sets: an integer pattern search
       (Hooke-Jeeves) from each of the best
       :data:`POLISH_STARTS` feasible sets that differ by at least 1/8 of a range. Each round
       judges the neighbours of :func:`_pattern_moves` (and the last successful move repeated),
       takes the best feasible improvement, and halves the steps when none improves, down to 1.
       The cost is not smooth (the static friction makes the dead band jump between ticks), and
       TPE alone stops short of the optimum erratically from seed to seed (one seed settled on
       a hunting integrator at I = 53 where the others found I = 0); the local stage makes the
       result a local optimum on the integer grid, and the distinct starts keep one basin from
       deciding.

    In current-based position mode (:attr:`BusServoModel.operating_mode`) the goal current is
    searched in the torque limit's place, or kept at ``goal_current`` when given.

    ``judge_fn`` judges the candidates (default
    :func:`~gripper_env.evaluation.bus_servo.judge`; an arm's loaded joint:
    :func:`~gripper_env.evaluation.bus_load.judge_loaded`), same arguments, same scores.

    Raises
    ------
    RuntimeError
        If no trial is feasible (the constraints cannot be met on this model).
    """
    space = search_space(model, goal_current)
    base = model.baselines()["factory"]
    cal = model.calibration
    if model.current_mode and cal is not None and cal.servo is not None:
        # the PWM limit is not searched in current-based position control: the factory's,
        # within the servo's own PWM_Limit
        top = cal.servo.max_torque_limit
        base = base.model_copy(update={"torque_limit": min(base.torque_limit, top)})
    if goal_current is not None:
        base = base.model_copy(update={"goal_current": int(goal_current)})
    keys = list(space)
    n_global = max(trials, len(model.baselines()))
    sampler = optuna.samplers.TPESampler(
        seed=seed,
        multivariate=True,
        constant_liar=True,
        n_startup_trials=min(20, max(n_global // 5, 1)),
    )
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="minimize", sampler=sampler)
    bar = tqdm(total=n_global, desc=f"tuning {model.name}", unit="trial", disable=not progress)

    def evaluate(fixed: list[dict[str, int]] | None, n: int) -> list[BusScore]:
        """Ask ``n`` trials (the ``fixed`` parameters when given), judge them in one batch."""
        asked = []
        for k in range(n):
            if fixed is not None:
                study.enqueue_trial({_param(key): v + 1 for key, v in fixed[k].items()})
            trial = study.ask()
            values = {
                key: trial.suggest_int(_param(key), lo + 1, hi + 1, log=True) - 1
                for key, (lo, hi) in space.items()
            }
            asked.append((trial, base.model_copy(update=values)))
        scores = judge_fn(model, [r for _t, r in asked], rel_std=rel_std, alternatives=alternatives)
        for (trial, _r), score in zip(asked, scores, strict=True):
            violation = constraint_value(score)
            trial.set_constraint("margins_and_hold", violation)
            trial.set_user_attr("constraint", violation)
            trial.set_user_attr("score", score.as_dict())
            study.tell(trial, score.cost)
        bar.update(n)
        return scores

    try:
        starts = [
            {k: min(max(getattr(r, k), lo), hi) for k, (lo, hi) in space.items()}
            for r in model.baselines().values()
        ]
        evaluate(starts, len(starts))
        done = len(starts)
        while done < n_global:
            n = min(batch, n_global - done)
            evaluate(None, n)
            done += n
        feasible = [t for t in study.trials if t.user_attrs.get("constraint", 1.0) <= 0.0]
        if not feasible:  # a narrow feasible region: walk from the least violation into it
            closest = min(study.trials, key=lambda t: t.user_attrs.get("constraint", math.inf))
            seen_repair = {tuple(_register(t, k) for k in keys) for t in study.trials}
            _repair({k: _register(closest, k) for k in keys}, evaluate, space, seen_repair,
                    polish)  # fmt: skip
            feasible = [t for t in study.trials if t.user_attrs.get("constraint", 1.0) <= 0.0]
        if not feasible:
            late = sorted({round(a.physics.loop_delay_s * 1e3) for a in alternatives})
            advice = "try more --trials, or check the model"
            if model.current_mode or late:
                # a current-driven loop has no back-EMF damping: a late delay costs it most
                delays = sorted({round(model.physics.loop_delay_s * 1e3) + DELAY_TICKS, *late})
                advice = (
                    f"its margins must hold at loop delays up to {max(delays)} ms, which the "
                    "records left open or the fit put late: record again on a quieter host, or "
                    "try more --trials"
                )
            raise RuntimeError(
                f"no feasible registers in {n_global} trials on {model.name}: every candidate "
                f"broke the margins or the hold ({advice})"
            )
        seen: set[tuple[int, ...]] = {tuple(_register(t, k) for k in keys) for t in study.trials}
        results = []
        starts_local = _distinct_starts(feasible, space, POLISH_STARTS)
        bar.total = n_global + polish * len(starts_local)  # shrinks as each search converges
        for start in starts_local:
            x, fx, used, converged = _polish(start, evaluate, space, seen, polish)
            bar.total -= polish - used
            bar.refresh()
            results.append((fx, x, converged))
        _fx, x, converged = min(results, key=lambda c: c[0])
        study.set_user_attr("local_optimum", converged)
    finally:
        bar.close()
    regs = base.model_copy(update=x)
    return judge_fn(model, [regs], rel_std=rel_std, alternatives=alternatives)[0], study


def _param(key: str) -> str:
    """The study's parameter for register ``key``: the register plus one, sampled on a log
    scale (``"i+1"``)."""
    return f"{key}+1"


def _register(trial: optuna.trial.FrozenTrial, key: str) -> int:
    """Register ``key`` of a trial of the study."""
    return int(trial.params[_param(key)]) - 1


#: A local-search move must lower the cost by this fraction: creeping along a flat direction (the
#: torque limit, between where the grasp slows and where the overload trips) gains nothing a
#: servo would show, and cost most of the search.
SUFFICIENT_DECREASE = 1e-3
#: The local stage starts from this many distinct feasible sets of the global stage.
POLISH_STARTS = 3


def _distinct_starts(
    feasible: list[optuna.trial.FrozenTrial], space: dict[str, tuple[int, int]], n: int
) -> list[tuple[dict[str, int], float]]:
    """The best ``n`` feasible trials that differ by at least 1/8 of a register's range from
    every better one picked, as (registers, cost)."""
    picked: list[tuple[dict[str, int], float]] = []
    for t in sorted(feasible, key=lambda t: float(t.value) if t.value is not None else math.inf):
        x = {k: _register(t, k) for k in space}
        far = all(
            max(abs(x[k] - y[k]) / max(hi - lo, 1) for k, (lo, hi) in space.items()) >= 0.125
            for y, _f in picked
        )
        if far and t.value is not None:
            picked.append((x, float(t.value)))
        if len(picked) == n:
            break
    return picked


def _polish(
    start: tuple[dict[str, int], float],
    evaluate: Callable[[list[dict[str, int]] | None, int], list[BusScore]],
    space: dict[str, tuple[int, int]],
    seen: set[tuple[int, ...]],
    budget: int,
) -> tuple[dict[str, int], float, int, bool]:
    """Integer pattern search from ``start`` within ``budget`` judged candidates: the best
    feasible registers found, their cost, the candidates used, and whether it converged (no
    neighbour at step 1 is a feasible set better by :data:`SUFFICIENT_DECREASE`) before the
    budget ran out."""
    keys = list(space)
    x, fx = start
    step = {k: max((hi - lo) // 16, 1) for k, (lo, hi) in space.items()}
    used, last = 0, None
    while used < budget:
        moves = _pattern_moves(x, step, space, seen)
        if last is not None:  # Hooke-Jeeves: repeat the last successful move, further
            ahead = {k: min(max(2 * x[k] - last[k], lo), hi) for k, (lo, hi) in space.items()}
            if tuple(ahead[k] for k in keys) not in seen and ahead not in moves:
                moves.insert(0, ahead)
        moves = moves[: budget - used]
        scores = evaluate(moves, len(moves)) if moves else []
        used += len(moves)
        seen.update(tuple(m[k] for k in keys) for m in moves)
        better = [(s.cost, m) for s, m in zip(scores, moves, strict=True) if s.feasible]
        better = [c for c in better if c[0] < fx - SUFFICIENT_DECREASE * abs(fx)]
        if better:
            last = x
            fx, x = min(better, key=lambda c: c[0])
        elif all(v <= 1 for v in step.values()):
            return x, fx, used, True
        else:
            last = None
            step = {k: max(v // 2, 1) for k, v in step.items()}
    return x, fx, used, False


def _repair(
    x: dict[str, int],
    evaluate: Callable[[list[dict[str, int]] | None, int], list[BusScore]],
    space: dict[str, tuple[int, int]],
    seen: set[tuple[int, ...]],
    budget: int,
) -> bool:
    """Integer pattern search on the constraints' violation (:func:`constraint_value`) from
    ``x``, until a judged set is feasible (True) or ``budget`` sets are judged, or no
    one-register step lowers the violation (False). A feasible region too narrow for the
    global stage to land in (current-based position control on a slow loop: a few registers
    wide in P, I and D) is reached this way; the local stage then starts from it."""
    keys = list(space)
    step = {k: max((hi - lo) // 16, 1) for k, (lo, hi) in space.items()}
    fx, used = math.inf, 0
    while used < budget:
        moves = _pattern_moves(x, step, space, seen)[: budget - used]
        scores = evaluate(moves, len(moves)) if moves else []
        used += len(moves)
        seen.update(tuple(m[k] for k in keys) for m in moves)
        if any(s.feasible for s in scores):
            return True
        judged = [(constraint_value(s), m) for s, m in zip(scores, moves, strict=True)]
        better = [c for c in judged if c[0] < fx]
        if better:
            fx, x = min(better, key=lambda c: c[0])
        elif all(v <= 1 for v in step.values()):
            return False
        else:
            step = {k: max(v // 2, 1) for k, v in step.items()}
    return False


def _pattern_moves(
    x: dict[str, int],
    step: dict[str, int],
    space: dict[str, tuple[int, int]],
    seen: set[tuple[int, ...]],
) -> list[dict[str, int]]:
    """The pattern search's neighbours of ``x``: each register by ``+-step`` and ``+-4 step``
    alone (clipped to its range), and P and D together by ``+-step`` (same and opposite
    directions), not judged before.

    The far polls step over the integrator's ridges: with the static friction, some integral
    gains hunt (a limit cycle, large chatter) between ones that settle, so the cost along ``i``
    has isolated spikes that would trap a search of near neighbours only.
    """
    keys = list(space)
    dirs: list[dict[str, int]] = []
    for k in keys:
        dirs += [{k: 1}, {k: -1}, {k: 4}, {k: -4}]
    if "p" in space and "d" in space:
        dirs += [{"p": sp, "d": sd} for sp in (1, -1) for sd in (1, -1)]
    out, taken = [], set()
    for d in dirs:
        cand = dict(x)
        for k, sign in d.items():
            lo, hi = space[k]
            cand[k] = min(max(x[k] + sign * step[k], lo), hi)
        key = tuple(cand[k] for k in keys)
        if key not in seen and key not in taken:
            taken.add(key)
            out.append(cand)
    return out


def _on_bounds(regs: RegisterSet, space: dict[str, tuple[int, int]]) -> list[str]:
    out = []
    for k, (lo, hi) in space.items():
        v = getattr(regs, k)
        if v in (lo, hi) and not (k == "i" and v == 0):
            out.append(f"{k}={v} on its search bound [{lo}, {hi}]")
    return out


def format_table(rows: dict[str, BusScore]) -> str:
    """A markdown table of judged register sets (tracking, hold, margins)."""
    lines = [
        "| registers | cost | IAE (deg s) | IAE/step (s) | overshoot (deg) | settled error (deg) "
        "| chatter (1/s) "
        "| grasp (s) | hold force (N) | least force (N) | trip | Ms | GM (dB) | PM (deg) "
        "| robust Ms / GM | D kick | feasible |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in rows.items():
        t, h, m, r = s.tracking, s.hold, s.margins, s.robust_margins
        trip = "none" if not h.overload else f"{h.trip} at {h.trip_at_s:.2f} s"
        lines.append(
            f"| {name}: {s.registers.label()} | {s.cost:.2f} | {t.iae:.2f} | {t.iae_per_deg_s:.3f} "
            f"| {t.overshoot_deg:.2f} "
            f"| {t.settled_error_deg:.2f} | {t.chatter:.1f} | {h.time_to_grasp_s:.2f} "
            f"| {h.holding_force_n:.1f} | {h.min_force_n:.1f} | {trip} | {m.ms:.2f} "
            f"| {m.gm_db:.1f} | {m.pm_deg:.0f} | {r.ms:.2f} / {r.gm_db:.1f} | {s.d_kick:.0%} "
            f"| {'yes' if s.feasible else 'no: ' + '; '.join(s.violations)} |"
        )
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.bus.tune",
        description="Search a bus servo's P, I, D and torque-limit registers (integers) with "
        "Optuna on its model, under the loop's margins and a grasp-and-hold constraint.",
    )
    parser.add_argument(
        "--model",
        default="sts3215",
        help="a shipped model (sts3215, xl330, xl430) or an identified model file "
        "(python -m tuners.bus.identify --out); default sts3215",
    )
    parser.add_argument(
        "--trials", type=int, default=300, help="TPE trials, the global search (default 300)"
    )
    parser.add_argument(
        "--polish",
        type=int,
        default=600,
        help="most register sets each local search after TPE judges (default 600; it stops "
        "earlier when no one-step change is better)",
    )
    parser.add_argument(
        "--operating-mode",
        choices=("position", "current_position"),
        default=None,
        help="the loop the servo runs: position control, or current-based position control "
        "(Dynamixel mode 5, the Koch gripper's; XL330 only); default the model's",
    )
    parser.add_argument(
        "--goal-current",
        type=int,
        default=None,
        metavar="UNITS",
        help="current-based position mode: keep this goal current (register units, mA on the "
        "XL330) instead of tuning it",
    )
    parser.add_argument("--seed", type=int, default=0, help="sampler seed (default 0)")
    parser.add_argument(
        "--out", type=Path, default=Path("runs/bus"), help="folder for <name>_registers.json/.md"
    )
    parser.add_argument("--no-plot", action="store_true", help="do not draw the figure")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return conform(parser, "tuners.bus.tune")


def main(argv: Sequence[str] | None = None) -> int:
    started = time.perf_counter()
    try:
        args = cli.parse(build_parser(), None if argv is None else list(argv))
    except ValueError as exc:  # --out names a file
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not 1 <= args.trials <= 100_000:
        print(f"error: --trials must be 1..100000, got {args.trials}", file=sys.stderr)
        return 2
    if not 0 <= args.polish <= 100_000:
        print(f"error: --polish must be 0..100000, got {args.polish}", file=sys.stderr)
        return 2
    try:
        model = load_bus_servo(args.model)
    except ConfigError as exc:
        print(f"error: --model: {exc}", file=sys.stderr)
        return 2
    try:
        rel_std, alternatives = identified_extras(args.model)
    except ConfigError as exc:
        print(f"error: --model: {exc}", file=sys.stderr)
        return 2
    if args.operating_mode is not None and args.operating_mode != model.operating_mode:
        try:
            model = model.with_updates(operating_mode=args.operating_mode)
            alternatives = [
                a.with_updates(operating_mode=args.operating_mode) for a in alternatives
            ]
        except ValueError:
            print(
                f"error: --operating-mode {args.operating_mode}: the {model.family} model has no "
                "current-based position mode (it needs a goal-current register: xl330)",
                file=sys.stderr,
            )
            return 2
    if args.goal_current is not None:
        lo, hi = CURRENT_SEARCH_SPACE["goal_current"]
        if not model.current_mode:
            print(
                "error: --goal-current applies in current-based position mode "
                "(--operating-mode current_position)",
                file=sys.stderr,
            )
            return 2
        if not lo <= args.goal_current <= hi:
            print(
                f"error: --goal-current must be {lo}..{hi}, got {args.goal_current}",
                file=sys.stderr,
            )
            return 2
    space = search_space(model, args.goal_current)
    try:
        best, study = tune_registers(
            model, trials=args.trials, seed=args.seed, rel_std=rel_std, polish=args.polish,
            alternatives=alternatives, progress=not args.no_progress and sys.stderr.isatty(),
            goal_current=args.goal_current,
        )  # fmt: skip
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    baselines = dict(zip(model.baselines(), judge(model, list(model.baselines().values()),
                                                   rel_std=rel_std, alternatives=alternatives),
                         strict=False))  # fmt: skip
    rows = {"tuned": best, **baselines}
    table = format_table(rows)
    bounds = _on_bounds(best.registers, space)
    local = bool(study.user_attrs.get("local_optimum", False))
    if not local:
        bounds.append(
            "the local search stopped at --polish before it converged: a better set may be "
            "one register step away (raise --polish)"
        )
    print(
        f"{model.name} ({model.family}), {args.trials} TPE trials and "
        f"{len(study.trials) - args.trials} of local search, seed {args.seed}"
    )
    print(table)
    for note in [*bounds, *protection_notes(model, best)]:
        print(f"note: {note}")
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"{model.name}_registers"
    doc = {
        "family": model.family,
        "name": model.name,
        "registers": best.registers.model_dump(),
        "score": best.as_dict(),
        "baselines": {k: v.as_dict() for k, v in baselines.items()},
        "search_space": space,
        "trials": args.trials,
        "judged": len(study.trials),
        "seed": args.seed,
        "uncertainty_rel_std": rel_std or {},
        "alternative_models": [m.model_dump() for m in alternatives],
        "on_bounds": bounds,
        "local_optimum": local,
        "model": model.model_dump(),
    }
    with collect_provenance(args.out, stem.name, command=args.command, started=started):
        write_atomic(stem.with_suffix(".json"), json.dumps(doc, indent=2) + "\n")
        write_atomic(stem.with_suffix(".md"), f"# {model.name}: tuned registers\n\n{table}\n")
        if not args.no_plot:
            from tuners.bus.plots import plot_registers

            plot_registers(model, rows, stem.with_suffix(".png"))
    print(f"wrote {stem.with_suffix('.json')}")
    return 0


def protection_notes(model: BusServoModel, best: BusScore) -> list[str]:
    """What the servo's own protection did to the tuned set, in words: the registers it was
    read from, and the overload threshold capping the torque limit when it does."""
    cal = model.calibration
    if cal is None or cal.servo is None or not cal.servo.protection:
        return [
            f"the hold is judged under the {model.family}'s factory protection (overload at "
            f"{model.protection.overload_duty:.0%} of full drive for "
            f"{model.protection.overload_time_s:g} s): a model identified from records of your "
            "servo carries its own"
        ]
    pr = model.protection
    read = ", ".join(f"{k} {v}" for k, v in cal.servo.protection.items())
    notes = [f"the hold is judged under servo {cal.servo_id}'s own protection registers ({read})"]
    if model.current_mode:
        regs = best.registers
        climit = cal.servo.protection.get("current_limit")
        within = "" if climit is None else f", within its Current_Limit {climit}"
        notes.append(
            f"current-based position control (operating mode {cal.servo.operating_mode}): goal "
            f"current {regs.goal_current} ({model.current_fraction(regs):.0%} of the stall "
            f"current{within}) holds {best.hold.holding_force_n:.1f} N"
        )
        return notes
    limit = model.limit_fraction(best.registers)
    top = search_space(model).get("torque_limit", (0, 0))[1] / model.scale.duty_full
    if 0.0 < pr.overload_duty < top and limit <= pr.overload_duty:
        notes.append(
            f"its overload threshold ({pr.overload_duty:.0%} of full drive for "
            f"{pr.overload_time_s:g} s) caps the hold: torque limit {best.registers.torque_limit} "
            f"({limit:.0%}) holds {best.hold.holding_force_n:.1f} N without tripping it, where "
            f"a limit above {pr.overload_duty * model.scale.duty_full:.0f} would trip in a hold"
        )
    return notes


def identified_extras(
    model_arg: str | Path,
) -> tuple[dict[str, float] | None, list[BusServoModel]]:
    """What an identified model file adds to its model: the relative standard errors
    (``"uncertainty"``) and the alternative models (``"alternatives"``: the fits at later loop
    delays, :class:`~gripper_env.sysid.bus_servo.BusEstimate`); neither for a family name.

    Raises
    ------
    gripper_env.io.config.ConfigError
        If an alternative is not a valid model (naming the file, the entry and the field), or
        an uncertainty is not a finite number >= 0 (naming the key).
    """
    if not str(model_arg).endswith(".json"):
        return None, []
    try:
        doc = json.loads(read_bounded(Path(model_arg), MAX_CONFIG_BYTES, "bus servo model"))
    except (OSError, ValueError):
        return None, []
    if not isinstance(doc, dict):
        return None, []
    rel_std = relative_uncertainties(doc, "uncertainty", str(model_arg))
    return rel_std, alternative_models(doc, "alternatives", str(model_arg))


if __name__ == "__main__":
    raise SystemExit(main())
