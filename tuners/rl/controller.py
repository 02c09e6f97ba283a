"""The RL controller: a residual policy on GripperServo-v0, trained with PPO over several seeds.

The policy adds a bounded correction (``residual_deg`` at action +/-1) to the output of a fixed
PID every 20 ms (``residual: pid``), or to the reference fed straight to the servo
(``residual: reference``); the zero action is that PID, or "command = reference", exactly. It is
trained with stable-baselines3's PPO through :class:`gripper_env.envs.sb3.NativeVecEnv` under
``VecMonitor`` and ``VecNormalize``, on random grip/un-grip profiles with the actual-gripper
parameters randomised every episode; with several plants (``plants``), each episode draws one of
the gripper's identifications and the policy does not observe which.

Measured as an RL researcher would (:func:`controller_study`):

* several **training seeds**, each trained alone;
* three disjoint sets of disturbance seeds: the searches' tuning seeds (untouched here), the
  **validation** seeds (``validation_seeds``: checkpoint selection and the learning curve) and the
  **held-out** seeds (the evaluation's: every figure reported);
* per training seed, a paired test of its held-out costs against the base PID's (Wilcoxon
  signed-rank over the held-out seeds); across seeds, mean, spread and worst seed;
* the learning curve (validation cost against steps: mean and range over the seeds, the base PID
  as a line) and the first step at which the mean beats the base PID;
* **measured margins** (:mod:`tuners.probe`): a policy has no transfer function, so its margins
  are probed: the plant's gain is raised until the frictionless loop with the hold swings on its
  own. That threshold is the **onset of a limit cycle** (for a linear loop, its gain margin; a
  policy's loop is not linear, and its swing can start below where the linearised loop would
  go unstable); a learned controller is admitted only if every seed's policy keeps it at least
  at the gain margin that ``Ms <= ms_max`` guarantees a linear loop (``20 log10(Ms / (Ms -
  1))``: 8.5 dB for 1.6), on every plant, and meets the rest of the admission rule
  (:mod:`gripper_env.evaluation.admission`: settled, no stall, the jaw inside the nearest stops
  the preset can draw) on the held-out runs.

**Robust training.** A residual policy trained on the nominal plants learns corrections that
the nominal loop tolerates and a loop with more gain does not (the first version's onsets were
0.7-4.7 dB on test4). So each training episode draws the plant's gain from the nominal one or
up to ``gain_spread_db`` above it (more than the 8.5 dB floor), and the sensor delay from
``[0, delay_spread_s]``, which the policy does not observe; and a checkpoint is kept only if
the probe loop does not swing at the floor's gain on any plant (the admission rule applied at
selection: :func:`meets_floor`).

Settings: ``configs/tuners/rl_controller.yaml`` (:class:`ControllerSettings`).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from gripper_env.evaluation.scoring import score_trajectory
from gripper_env.io.config import CONFIG_DIR, load_yaml, validate
from gripper_env.io.files import collect_provenance, json_ready, write_result_json
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import load_plant
from gripper_env.sim import Trajectory, simulate
from tuners import cli
from tuners.engine import engine, write_files
from tuners.evaluation import summarize_runs, with_cost
from tuners.rl.agents import Agent, quiet_logger, save_agent
from tuners.rl.envs import progress_callback, require_rl
from tuners.settings import SeedRange

__all__ = [
    "ControllerSettings",
    "controller_study",
    "evaluate_policy",
    "load_controller_settings",
    "measured_gm_floor_db",
    "train_controller",
]

SERVO = "gripper_env/GripperServo-v0"
_ON = {"pid": "the PID's output", "reference": "the reference"}


class ControllerSettings(BaseModel):
    """``configs/tuners/rl_controller.yaml``: the residual controller and its training budget."""

    model_config = ConfigDict(extra="forbid")

    residual: Literal["pid", "reference"] = "pid"
    residual_deg: float = Field(20.0, gt=0.0, le=180.0)
    timesteps: int = Field(1_000_000, ge=1)
    quick_timesteps: int = Field(8192, ge=1)
    checkpoints: int = Field(16, ge=1, le=200)
    n_envs: int = Field(32, ge=1)
    n_steps: int = Field(256, ge=1)
    batch_size: int = Field(1024, ge=2)
    n_epochs: int = Field(10, ge=1)
    learning_rate: float = Field(3e-4, gt=0.0)
    gamma: float = Field(0.98, gt=0.0, le=1.0)
    gae_lambda: float = Field(0.95, ge=0.0, le=1.0)
    net_arch: list[int] = [64, 64]
    log_std_init: float = -1.5
    training_reference: str = "random"
    episode_s: float = Field(20.0, gt=0.0)
    randomize: bool = True
    seed: int = 0
    validation_seeds: SeedRange = SeedRange(start=200000, count=8)
    gain_spread_db: float = Field(0.0, ge=0.0, le=20.0)
    gain_levels: int = Field(5, ge=1, le=50)
    delay_spread_s: float = Field(0.0, ge=0.0, le=0.060)
    select_on_floor: bool = True


def load_controller_settings(path: str | os.PathLike[str] | None = None) -> ControllerSettings:
    """Load and validate the settings (default ``configs/tuners/rl_controller.yaml``)."""
    p = CONFIG_DIR / "tuners" / "rl_controller.yaml" if path is None else path
    return validate(ControllerSettings, load_yaml(p), str(p))


def measured_gm_floor_db(ms_max: float) -> float:
    """The gain margin (dB) that ``Ms <= ms_max`` guarantees a linear loop: a learned
    controller's measured limit-cycle onset must reach it (its ``Ms`` cannot be probed)."""
    return 20.0 * math.log10(ms_max / (ms_max - 1.0))


def training_plants(names: Sequence[str], s: ControllerSettings) -> list[Any]:
    """The plants a training episode draws from: each identification at its nominal gain
    ``gain_levels`` times and with its gain raised by each of ``gain_levels`` steps up to
    ``gain_spread_db`` (half the episodes nominal); the names alone without a spread."""
    from tuners.probe import scaled_plant

    if s.gain_spread_db <= 0.0:
        return list(names)
    levels = np.linspace(0.0, s.gain_spread_db, s.gain_levels + 1)[1:]
    out: list[Any] = []
    for name in names:
        plant = load_plant(name)
        out += [plant] * s.gain_levels
        out += [scaled_plant(plant, 10.0 ** (db / 20.0)) for db in levels]
    return out


def training_randomize(inputs: cli.Inputs, s: ControllerSettings) -> Any:
    """The training episodes' randomisation: the preset's ranges (if ``randomize``) and the
    sensor delay up to ``delay_spread_s``."""
    if s.delay_spread_s <= 0.0:
        return s.randomize
    ranges = {k: list(v) for k, v in inputs.disturbance.randomize.items()} if s.randomize else {}
    ranges["sensor.delay_s"] = [0.0, s.delay_spread_s]
    return ranges


def meets_floor(
    policy: Callable[[np.ndarray], np.ndarray], inputs: cli.Inputs, kwargs: dict[str, Any],
    plants: Sequence[str],
) -> bool:  # fmt: skip
    """Whether the policy's probe loop (:func:`tuners.probe.measure_margins`'s: frictionless,
    with the hold) stays free of a limit cycle at the nominal gain, half the floor and the floor
    (:func:`measured_gm_floor_db`) on every plant: the checkpoint test of the admission rule's
    margin (the judge then measures the onset itself)."""
    from tuners.probe import oscillates, policy_runner

    floor = measured_gm_floor_db(inputs.objective.constraints.ms_max)
    for name in plants:
        runner = policy_runner(policy, dict(kwargs, plant=name), inputs.reference)
        swing = oscillates(runner, load_plant(name), inputs.disturbance, inputs.ideal,
                           [0.0, floor / 2, floor])  # fmt: skip
        if swing.any():
            return False
    return True


def env_kwargs(
    inputs: cli.Inputs, base: PIDGains | None, s: ControllerSettings, plants: Sequence[str] = ()
) -> dict[str, Any]:
    """``GripperServo-v0``'s arguments for the controller (without the reference)."""
    _, actual = inputs.settings.options(1)
    kwargs: dict[str, Any] = {
        "plant": list(plants) if len(plants) > 1 else (plants[0] if plants else inputs.plant.name),
        "disturbance": inputs.disturbance_name,
        "randomize": s.randomize,
        "residual": s.residual,
        "residual_deg": s.residual_deg,
    }
    if s.residual == "pid":
        if base is None:
            raise ValueError("the residual on a PID needs the PID's gains (base)")
        kwargs.update(
            pid_gains=(base.P, base.I, base.D),
            derivative_filter=base.N,
            pid_options={
                "output_limits": actual.output_limits,
                "anti_windup": actual.anti_windup,
                "kb": actual.kb,
                "derivative_on": actual.derivative_on,
                "sign": 1,
            },
        )
    return kwargs


def _score(traj: Trajectory, inputs: cli.Inputs, disturbance: Disturbance) -> list[dict[str, Any]]:
    """Metrics and cost of every run, through the one scoring path every tuner takes."""
    metrics, costs = score_trajectory(traj, inputs.objective, disturbance)
    return with_cost(metrics, costs)


def evaluate_policy(
    policy: Callable[[np.ndarray], np.ndarray],
    inputs: cli.Inputs,
    kwargs: dict[str, Any],
    seeds: np.ndarray,
    plant: str | None = None,
    env_id: str = SERVO,
) -> tuple[dict[str, Any], list[dict[str, Any]], Trajectory, Trajectory]:
    """The policy on the ideal model (one run) and on the actual model (one run per seed), on
    ``plant`` (default the inputs'); the inputs' reference.

    Returns ``(ideal metrics, actual runs' metrics, ideal trajectory, actual trajectory)``.
    """
    from gripper_env.envs.rollout import policy_trajectory

    one = dict(kwargs, plant=plant or inputs.plant.name)
    ideal_kwargs: dict[str, Any] = {**one, "disturbance": "ideal", "randomize": False}
    ideal = policy_trajectory(policy, [0], env_id=env_id, reference=inputs.reference,
                              **ideal_kwargs)  # fmt: skip
    actual = policy_trajectory(policy, seeds, env_id=env_id, reference=inputs.reference, **one)
    return (
        _score(ideal, inputs, inputs.ideal)[0],
        _score(actual, inputs, inputs.disturbance),
        ideal,
        actual,
    )


def _validation_cost(
    policy: Callable[[np.ndarray], np.ndarray],
    inputs: cli.Inputs,
    kwargs: dict[str, Any],
    seeds: np.ndarray,
    plants: Sequence[str],
) -> float:
    """Mean cost on the validation seeds (and over the plants), the inputs' reference."""
    from gripper_env.envs.rollout import policy_trajectory

    costs = []
    for name in plants:
        traj = policy_trajectory(policy, seeds, reference=inputs.reference,
                                 **dict(kwargs, plant=name))  # fmt: skip
        costs += [r["cost"] for r in _score(traj, inputs, inputs.disturbance)]
    return float(np.mean(costs))


def train_controller(
    inputs: cli.Inputs,
    base: PIDGains | None,
    s: ControllerSettings,
    run_dir: str | os.PathLike[str],
    *,
    seed: int,
    plants: Sequence[str] = (),
    timesteps: int | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> tuple[Agent, dict[str, Any]]:
    """Train the residual policy with one seed; keep the checkpoint with the lowest mean cost on
    the validation seeds (never the tuning or the held-out seeds).

    Returns the kept agent and the training's facts: budget, wall time, the validation curve
    (``history``: ``(steps, validation cost)``, step 0 being the base itself) and the base's
    validation cost.
    """
    require_rl()
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from gripper_env.envs.sb3 import NativeVecEnv

    names = list(plants) or [inputs.plant.name]
    total = s.timesteps if timesteps is None else int(timesteps)
    kwargs = env_kwargs(inputs, base, s, names)
    train_kwargs = dict(
        kwargs,
        reference=s.training_reference,
        plant=training_plants(names, s),
        randomize=training_randomize(inputs, s),
    )
    if len(train_kwargs["plant"]) == 1:
        train_kwargs["plant"] = train_kwargs["plant"][0]  # fmt: skip
    if s.training_reference == "random":
        train_kwargs["episode_s"] = s.episode_s
    torch.set_num_threads(1)  # small networks: threads cost more than they give on 2 cores
    venv = VecNormalize(
        VecMonitor(NativeVecEnv(SERVO, num_envs=s.n_envs, **train_kwargs)), gamma=s.gamma
    )
    venv.seed(seed)
    model = PPO(
        "MlpPolicy", venv, n_steps=s.n_steps, batch_size=s.batch_size, n_epochs=s.n_epochs,
        learning_rate=s.learning_rate, gamma=s.gamma, gae_lambda=s.gae_lambda, seed=seed,
        device="cpu", policy_kwargs={"net_arch": list(s.net_arch), "log_std_init": s.log_std_init},
    )  # fmt: skip
    quiet_logger(model)
    agent = Agent(model, venv, SERVO, kwargs, base)
    validation = s.validation_seeds.seeds()
    run_dir = Path(run_dir)

    def validate_now() -> float:
        venv.training = False
        cost = _validation_cost(agent, inputs, kwargs, validation, names)
        venv.training = True
        return cost

    base_cost = _validation_cost(lambda obs: np.zeros((len(obs), 1)), inputs, kwargs, validation,
                                 names)  # fmt: skip
    history = [(0, base_cost)]
    best = (math.inf, 0)
    refused: list[int] = []  # checkpoints better on validation whose probe loop swung
    met_floor = False
    chunk = max(total // s.checkpoints, s.n_envs * s.n_steps)
    bar = progress_callback(total, f"rl-controller {'+'.join(names)} seed {seed}",
                            disable=not progress)  # fmt: skip
    start = time.perf_counter()
    while model.num_timesteps < total:
        model.learn(total_timesteps=min(chunk, total - model.num_timesteps),
                    reset_num_timesteps=False, callback=bar)  # fmt: skip
        cost = validate_now()
        history.append((int(model.num_timesteps), cost))
        if cost < best[0]:
            venv.training = False
            ok = not s.select_on_floor or meets_floor(agent, inputs, kwargs, names)
            venv.training = True
            if ok:
                best, met_floor = (cost, int(model.num_timesteps)), True
                save_agent(agent, run_dir / "best", _facts(s, seed, names, model.num_timesteps))
            if not ok:
                refused.append(int(model.num_timesteps))
    if not met_floor:  # no better checkpoint kept the probe loop calm: the last one, flagged
        best = (history[-1][1], int(model.num_timesteps))
        save_agent(agent, run_dir / "best", _facts(s, seed, names, model.num_timesteps))
    wall = time.perf_counter() - start
    venv.close()
    facts = {
        "algo": "ppo",
        "seed": seed,
        "plants": names,
        "residual": s.residual,
        "residual_deg": s.residual_deg,
        "base_gains": None if base is None else [base.P, base.I, base.D, base.N],
        "timesteps": int(model.num_timesteps),
        "kept_checkpoint_timesteps": best[1],
        "validation_seeds": [int(x) for x in validation],
        "base_validation_cost": base_cost,
        "best_validation_cost": best[0],
        "history": history,
        "refused_checkpoints": refused,
        "kept_checkpoint_meets_floor": met_floor or not s.select_on_floor,
        "train_wall_time_s": wall,
        "settings": s.model_dump(),
    }
    write_result_json(run_dir / "history.json", facts)
    log(
        f"  rl-controller {'+'.join(names)} seed {seed}: {model.num_timesteps} steps in "
        f"{wall:.0f} s; validation cost {best[0]:.4g} at {best[1]} steps (base {base_cost:.4g})"
    )
    from tuners.rl.agents import load_agent

    return load_agent(run_dir / "best"), facts


def _facts(s: ControllerSettings, seed: int, plants: list[str], steps: int) -> dict[str, Any]:
    return {
        "algo": "ppo",
        "seed": seed,
        "trained_on": plants,
        "timesteps": int(steps),
        "training_reference": s.training_reference,
        "randomize": s.randomize,
    }


def _paired(a: Sequence[float], b: Sequence[float]) -> dict[str, Any]:
    """Mean and relative difference of per-seed costs ``a - b`` and the two-sided Wilcoxon
    signed-rank p-value (the leaderboard's test)."""
    from tuners.statistics import paired_test

    diff, p = paired_test(list(a), list(b))
    return {
        "cost_difference": diff,
        "cost_relative": diff / float(np.mean(b)),
        "p_value": p,
        "better_on_seeds": int(np.sum(np.asarray(a) < np.asarray(b))),
    }


def reference_runs(inputs: cli.Inputs, plant: str | None = None) -> dict[str, Any]:
    """ "command = reference" (the servo commanded the reference, no controller) on ``plant``:
    its metrics on both models and its held-out runs."""
    s = inputs.settings
    seeds = s.seeds.seeds()
    p = load_plant(plant or inputs.plant)
    ideal = simulate(p, inputs.reference, None, "ideal")
    actual = simulate(p, inputs.reference, None, inputs.disturbance, seeds=seeds,
                      randomize=s.randomize)  # fmt: skip
    runs = _score(actual, inputs, inputs.disturbance)
    return {
        "metrics": {"ideal": _score(ideal, inputs, inputs.ideal)[0],
                    "actual": summarize_runs(runs)},
        "runs": runs,
    }  # fmt: skip


def controller_study(
    inputs: cli.Inputs,
    base: PIDGains | None,
    *,
    seeds: Sequence[int],
    settings: ControllerSettings | None = None,
    plants: Sequence[str] = (),
    out: str | os.PathLike[str] = "runs",
    timesteps: int | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
    engine_spec: str | None = None,
) -> dict[str, Any]:
    """Train the RL controller with every seed and evaluate it as an RL researcher would.

    Parameters
    ----------
    inputs : tuners.cli.Inputs
        Plant, preset, profile and evaluation settings (held-out seeds).
    base : PIDGains or None
        The PID the policy corrects (``residual: pid``).
    seeds : sequence of int
        Training seeds.
    settings : ControllerSettings, optional
        Default ``configs/tuners/rl_controller.yaml``.
    plants : sequence of str
        Train across these identifications (one policy for all); default the inputs' plant.
    out : path
        The runs go to ``<out>/rl/controller-<plants>/seed-<k>/``.
    timesteps : int, optional
        Training budget per seed (default the settings').
    engine_spec : str, optional
        Where the seeds train (:func:`tuners.engine.engine`: serial, local worker processes,
        a Dask cluster); the results are the same.

    Returns
    -------
    dict
        ``seeds`` (per training seed: its facts, held-out costs on every plant, paired test
        against the base, measured margins), ``per_plant`` (per evaluation plant: the pooled
        metrics, ``per_seed_cost`` averaged over the training seeds, the base's and command =
        reference's), ``curve`` (the learning curve's mean and range) and ``summary``.
    """
    from tuners.probe import measure_margins, pid_runner

    s = settings or load_controller_settings()
    names = list(plants) or [inputs.plant.name]
    folder = Path(out) / "rl" / f"controller-{'+'.join(names)}"
    held_out = inputs.settings.seeds.seeds()
    eval_plants = names
    plant_models = {p: load_plant(p) for p in eval_plants}  # loaded once for the study
    kwargs = env_kwargs(inputs, base, s, names)
    zero = lambda obs: np.zeros((len(obs), 1))  # noqa: E731 - the base itself
    t0 = time.perf_counter()
    base_eval = {p: evaluate_policy(zero, inputs, kwargs, held_out, p) for p in eval_plants}
    _, actual_opts = inputs.settings.options(1)
    base_margins = (
        {p: measure_margins(pid_runner(base, actual_opts, inputs.reference), plant_models[p],
                            inputs.disturbance, inputs.ideal).as_dict() for p in eval_plants}
        if base is not None else {}
    )  # fmt: skip
    tasks = [
        _SeedTask(inputs, base, s, names, int(k), timesteps, kwargs, progress and engine_spec
                  in (None, "serial"))
        for k in seeds
    ]  # fmt: skip
    per_seed: list[dict[str, Any]] = []
    with engine(engine_spec) as eng:
        for task, result in zip(tasks, eng.map(_run_seed, tasks), strict=True):
            write_files(folder / f"seed-{task.seed}", result["files"])
            entry = result["entry"]
            for p in eval_plants:
                base_runs = base_eval[p][1]
                runs = entry["plants"][p]["runs"]
                entry["plants"][p]["vs_base"] = _paired(
                    [r["cost"] for r in runs], [r["cost"] for r in base_runs]
                )
            per_seed.append(entry)
            log(result["message"])
    wall = time.perf_counter() - t0
    study = _summarise(inputs, s, base, names, per_seed, base_eval, base_margins, wall)
    study["requested_timesteps"] = s.timesteps if timesteps is None else int(timesteps)
    if inputs.objective.constraints.grasp:
        add_grasp(study, inputs, folder)
    return study


@dataclass(frozen=True)
class _SeedTask:
    """One training seed of a study: what a worker needs (picklable)."""

    inputs: cli.Inputs
    base: PIDGains | None
    settings: ControllerSettings
    plants: list[str]
    seed: int
    timesteps: int | None
    kwargs: dict[str, Any]
    progress: bool


def _run_seed(task: _SeedTask) -> dict[str, Any]:
    """Train one seed in a scratch folder and evaluate its kept agent on the held-out seeds of
    every plant, with its measured margins; return the figures and the agent's files."""
    import tempfile

    from tuners.engine import gather_files
    from tuners.probe import measure_margins, policy_runner

    inputs = task.inputs
    held_out = inputs.settings.seeds.seeds()
    with tempfile.TemporaryDirectory() as tmp:
        # the task's own sidecar, sent back with its files (tuners.engine.write_files)
        with collect_provenance(tmp, "task", own=True):
            agent, facts = train_controller(
                inputs, task.base, task.settings, tmp, seed=task.seed, plants=task.plants,
                timesteps=task.timesteps, progress=task.progress, log=lambda m: None,
            )  # fmt: skip
        entry: dict[str, Any] = {"seed": task.seed, "training": facts, "plants": {}}
        for p in task.plants:
            ideal, runs, _, _ = evaluate_policy(agent, inputs, task.kwargs, held_out, p)
            margins = measure_margins(
                policy_runner(agent, dict(task.kwargs, plant=p), inputs.reference),
                load_plant(p), inputs.disturbance, inputs.ideal,
            )  # fmt: skip
            entry["plants"][p] = {
                "ideal": ideal,
                "runs": runs,
                "mean_cost": float(np.mean([r["cost"] for r in runs])),
                "stable_fraction": float(np.mean([r["stable"] for r in runs])),
                "measured_margins": margins.as_dict(),
            }
        files = gather_files(tmp)
    message = (
        f"  rl-controller {'+'.join(task.plants)} seed {task.seed}: {facts['timesteps']} steps; "
        f"validation cost {facts['best_validation_cost']:.4g} at "
        f"{facts['kept_checkpoint_timesteps']} steps (base {facts['base_validation_cost']:.4g})"
    )
    return {"entry": entry, "files": files, "message": message}


def _summarise(
    inputs: cli.Inputs,
    s: ControllerSettings,
    base: PIDGains | None,
    names: list[str],
    per_seed: list[dict[str, Any]],
    base_eval: dict[str, Any],
    base_margins: dict[str, Any],
    wall: float,
) -> dict[str, Any]:
    """The study's figures: per plant and over the seeds; the learning curve."""
    floor = inputs.objective.constraints.measured_gm_min_db
    per_plant: dict[str, Any] = {}
    for p in names:
        costs = np.array([[r["cost"] for r in e["plants"][p]["runs"]] for e in per_seed])
        pooled = [r for e in per_seed for r in e["plants"][p]["runs"]]
        seed_means = costs.mean(axis=1)
        margins = [e["plants"][p]["measured_margins"] for e in per_seed]
        gms = [m["gain_margin_db"] for m in margins]
        reference = reference_runs(inputs, p)
        per_plant[p] = {
            "metrics": {"ideal": per_seed[0]["plants"][p]["ideal"],
                        "actual": summarize_runs(pooled)},
            "per_seed_cost": costs.mean(axis=0).tolist(),  # per held-out seed, over training seeds
            "training_seed_cost": {"mean": float(seed_means.mean()),
                                   "std": float(seed_means.std(ddof=1)) if len(seed_means) > 1
                                   else 0.0,
                                   "min": float(seed_means.min()), "max": float(seed_means.max()),
                                   "worst_seed": int(per_seed[int(np.argmax(seed_means))]["seed"]),
                                   "per_seed": dict(zip([str(e["seed"]) for e in per_seed],
                                                        seed_means.tolist(), strict=True))},
            "base": {"ideal": base_eval[p][0], "actual": summarize_runs(base_eval[p][1]),
                     "per_seed_cost": [r["cost"] for r in base_eval[p][1]],
                     "measured_margins": base_margins.get(p)},
            "command_equals_reference": reference["metrics"],
            "vs_base_per_training_seed": {str(e["seed"]): e["plants"][p]["vs_base"]
                                          for e in per_seed},
            "measured_margins": {
                "per_seed": {str(e["seed"]): m for e, m in zip(per_seed, margins, strict=True)},
                "worst_gain_margin_db": min((math.inf if g is None else g) for g in gms),
                "worst_delay_margin_s": min(
                    (math.inf if m["delay_margin_s"] is None else m["delay_margin_s"])
                    for m in margins
                ),
                "required_gain_margin_db": floor,
            },
        }  # fmt: skip
        per_plant[p]["admission"] = policy_admission(inputs, pooled, gms)
        per_plant[p]["deployable"] = per_plant[p]["admission"]["admitted"]
    curve = learning_curve(per_seed)
    return {
        "controller": f"PPO residual on {_ON[s.residual]} ({s.residual_deg:g} deg at |a| = 1)",
        "trained_on": names,
        "base_gains": None if base is None else [base.P, base.I, base.D, base.N],
        "seeds": per_seed,
        "per_plant": per_plant,
        "curve": curve,
        "timesteps_per_seed": per_seed[0]["training"]["timesteps"],
        "wall_time_s": wall,
        "settings": s.model_dump(),
    }


def policy_admission(
    inputs: cli.Inputs, runs: list[dict[str, Any]], onsets_db: Sequence[float | None]
) -> dict[str, Any]:
    """The admission rule (:mod:`gripper_env.evaluation.admission`) for a learned controller on
    one plant: the measured limit-cycle onset of every training seed's policy against the floor
    that ``Ms <= ms_max`` guarantees a linear loop, and on its held-out runs (every seed's,
    pooled) settled, no stall, the jaw inside the nearest stops the preset can draw."""
    from gripper_env.evaluation.admission import Admission, checks_of_runs, nearest_stops_deg

    checks = checks_of_runs(
        grip_settling_s=[r["grip"]["settling_time_s"] for r in runs],
        ungrip_settling_s=[r["ungrip"]["settling_time_s"] for r in runs],
        stable=[bool(r["stable"]) for r in runs],
        jaw_min_deg=[r.get("jaw_min_deg") for r in runs],
        jaw_max_deg=[r.get("jaw_max_deg") for r in runs],
        stall_s=[r.get("stall_s") for r in runs],
        contact_s=[r.get("contact_s") for r in runs],
        k=1,
        stops_deg=nearest_stops_deg(inputs.disturbance, inputs.settings.randomize),
    )
    worst = min(math.inf if g is None else float(g) for g in onsets_db)
    rule = Admission.build(inputs.objective.constraints.limits(), measured_gm_db=np.array([worst]),
                           checks=checks)  # fmt: skip
    return rule.row(0)


def add_grasp(study: dict[str, Any], inputs: cli.Inputs, folder: Path) -> dict[str, Any]:
    """The grasp scenario (:func:`tuners.rl.grasp.policy_grasp`) of every training seed's kept
    policy on every plant's held-out seeds, added to the study's per-plant admission (the rule's
    last constraint: a policy whose correction trips the servo on the object is refused)."""
    from gripper_env.evaluation.admission import with_grasp
    from tuners.rl.agents import load_agent
    from tuners.rl.grasp import policy_grasp

    seeds = inputs.settings.seeds.seeds()
    agents = {e["seed"]: load_agent(folder / f"seed-{e['seed']}" / "best") for e in study["seeds"]}
    for p, entry in study["per_plant"].items():
        plant = load_plant(p)
        per_seed = {}
        for k, agent in agents.items():
            kwargs = dict(agent.env_kwargs)
            per_seed[str(k)] = policy_grasp(agent, kwargs, plant, inputs.disturbance, seeds,
                                            randomize=inputs.settings.randomize)  # fmt: skip
        worst = max(per_seed.values(), key=lambda g: g["lost"])
        reason = f"{worst['reason']} on {p}" if worst["reason"] else ""
        entry["grasp"] = {"per_seed": per_seed, "lost": worst["lost"], "reason": reason}
        entry["admission"] = with_grasp(entry["admission"], worst["lost"], reason)
        entry["deployable"] = entry["admission"]["admitted"]
    return study


def learning_curve(per_seed: list[dict[str, Any]]) -> dict[str, Any]:
    """Validation cost against steps over the training seeds: mean, min and max; the base's;
    the first step at which the mean beats the base."""
    steps = [h[0] for h in per_seed[0]["training"]["history"]]
    table = np.array([[h[1] for h in e["training"]["history"]] for e in per_seed])
    mean = table.mean(axis=0)
    base = float(per_seed[0]["training"]["base_validation_cost"])
    beats = [st for st, m in zip(steps, mean, strict=True) if st > 0 and m < base]
    return {
        "steps": steps,
        "mean": mean.tolist(),
        "min": table.min(axis=0).tolist(),
        "max": table.max(axis=0).tolist(),
        "per_seed": {str(e["seed"]): row.tolist() for e, row in zip(per_seed, table, strict=True)},
        "base": base,
        "first_step_mean_beats_base": beats[0] if beats else None,
    }


def write_study(study: dict[str, Any], out: str | os.PathLike[str], name: str) -> Path:
    """``<out>/rl/<name>/study.json`` (the runs' figures, not their models)."""
    slim = json.loads(json.dumps(json_ready(study)))
    for e in slim["seeds"]:
        for p in e["plants"].values():
            p["runs"] = [{"cost": r["cost"], "iae": r["iae"], "stable": r["stable"]}
                         for r in p["runs"]]  # fmt: skip
    return write_result_json(Path(out) / "rl" / name / "study.json", slim)
