"""The RL PID tuner: PPO on ``GripperPIDTune-v0``, gains around a textbook design.

``GripperPIDTune-v0`` is a contextual bandit: one step picks P, I and D for a whole 20 s
grip/un-grip episode and the reward is minus the episode's cost. With the preset randomised per
episode (the default here) the context is the friction and noise of that draw; with it fixed, a
per-plant bandit. The recipe, chosen from learning curves over seeds (README, "RL"):

* **Action**: the ``relative`` gain map, log-gains around a textbook design:
  ``P = P0 10**a_P``, ``I = I0 10**a_I`` (one decade each way) and ``D = D0 + a_D d_span``, where
  ``(P0, I0, D0)`` is the first rule of ``center`` whose robustness knob can be set to meet the
  constraints on every tuning plant (:mod:`tuners.classical.constrained`; SIMC cannot on
  test2-test4 together, the PIDTUNE-style design can). The zero action is a deployable design;
  the box spans Optuna's optimum with room on every side.
* **Reward** for training: ``-log(cost + penalty * violation)`` (:func:`admission_reward`), the
  violation being the admission rule's (:mod:`gripper_env.evaluation.admission`) on each
  episode: robustness with the hold on its plant, settled, no stall, and the jaw's envelope
  inside the nearest stops the preset can draw. The constraints as an exact penalty without the
  cliff, in log scale (as :func:`tuners.rl.envs.LogExactPenalty` does for robustness alone). The
  grasp scenario is not in the reward (it would triple an episode's simulation); the
  selection below scores it, with the rest of the rule.
* **Algorithm**: PPO with ``gamma = 0`` (a bandit: no bootstrapping), 16 environments in one
  compiled call, 256 episodes per update, learning rate 1e-3, initial exploration ``std =
  exp(-1.5)`` in action units (a factor 1.4 on the gains).
* **Selection**: every ``eval_every`` episodes the policy's deterministic gains for the nominal
  context are scored on the tuning seeds, exactly as an Optuna trial. The gains file holds the
  best feasible gains so evaluated, with the step and seed they came from; the budget counts
  those scoring episodes too.

Settings: ``configs/tuners/rl_tune.yaml`` (:class:`RLTuneSettings`).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from gripper_env.evaluation.admission import Admission
from gripper_env.evaluation.objective import Objective
from gripper_env.evaluation.scoring import GainScorer
from gripper_env.io.config import CONFIG_DIR, MAX_DATA_BYTES, load_yaml, read_bounded, validate
from gripper_env.io.files import write_result_json
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from tuners import cli
from tuners.rl.agents import quiet_logger, save_model
from tuners.rl.envs import ENV_IDS, make_vec_env, progress_callback, require_rl
from tuners.settings import ClassicalSettings, OptunaSettings, load_settings
from tuners.tasks import make_scorer

__all__ = [
    "RLTuneSettings",
    "TuneRun",
    "admission_reward",
    "episode_admission",
    "load_tune_settings",
    "train_seeds",
    "train_tuner",
]

#: An action this close to +/-1 (in any gain) is on the map's bound.
BOUND_ACTION = 0.98


class RLTuneSettings(BaseModel):
    """``configs/tuners/rl_tune.yaml``: the RL PID tuner's recipe and budget."""

    model_config = ConfigDict(extra="forbid")

    episodes: int = Field(32768, ge=1)
    quick_episodes: int = Field(1024, ge=1)
    n_envs: int = Field(16, ge=1)
    n_steps: int = Field(16, ge=1)
    batch_size: int = Field(64, ge=2)
    n_epochs: int = Field(10, ge=1)
    learning_rate: float = Field(1e-3, gt=0.0)
    log_std_init: float = -1.5
    net_arch: list[int] = [64, 64]
    center: list[str] = ["simc", "pidtune", "amigo-pi"]

    @field_validator("center", mode="before")
    @classmethod
    def _rules(cls, v: Any) -> Any:
        from tuners.classical.constrained import KNOBS

        names = [v] if isinstance(v, str) else v
        if not isinstance(names, list) or not names:
            raise ValueError("center: a rule or a list of rules, tried in order")
        unknown = [n for n in names if n not in KNOBS]
        if unknown:
            raise ValueError(f"center: unknown rule {unknown[0]!r}; choose from {sorted(KNOBS)}")
        return names

    decades: float = Field(1.0, gt=0.0, le=3.0)
    d_span: float = Field(0.5, ge=0.0)
    eval_every: int = Field(512, ge=1)
    randomize: bool = True
    seed: int = 0


def load_tune_settings(path: str | os.PathLike[str] | None = None) -> RLTuneSettings:
    """Load and validate the settings (default ``configs/tuners/rl_tune.yaml``)."""
    p = CONFIG_DIR / "tuners" / "rl_tune.yaml" if path is None else path
    return validate(RLTuneSettings, load_yaml(p), str(p))


class TuneRun(dict):
    """What :func:`train_tuner` returns (a dict, written as the run's ``history.json``):
    ``gains`` (the best feasible evaluated, :class:`PIDGains`), ``best`` (its evaluation: step,
    tuning cost, action), ``evaluations`` (every scoring of the policy's gains), ``center``,
    ``seed``, ``episodes`` (training), ``selection_episodes``, ``train_wall_time_s``."""


def env_kwargs(
    inputs: cli.Inputs, plants: Sequence[str], s: RLTuneSettings, center: PIDGains
) -> dict[str, Any]:
    """``GripperPIDTune-v0``'s arguments: the plant(s), preset, profile, PID structure and the
    relative gain map around ``center``."""
    _, actual = inputs.settings.options(1)
    return {
        "plant": list(plants) if len(plants) > 1 else plants[0],
        "disturbance": inputs.disturbance,
        "reference": inputs.reference,
        "randomize": s.randomize,
        "pid_options": {
            "output_limits": actual.output_limits,
            "anti_windup": actual.anti_windup,
            "kb": actual.kb,
            "derivative_on": actual.derivative_on,
            "sign": 1,
        },
        "gain_scaling": "relative",
        "gain_center": (center.P, center.I, center.D),
        "gain_decades": s.decades,
        "gain_max": (1.0, 1.0, max(s.d_span * abs(center.P) * 0.020, 1e-9)),
        "derivative_filter": center.N,
    }


def design_center(
    inputs: cli.Inputs, s: RLTuneSettings, plants: Sequence[str], scorer: GainScorer
) -> tuple[PIDGains, dict[str, Any]]:
    """The textbook design the gain map is centred on, its knob set under the constraints on
    the tuning task (every plant of a robust task)."""
    from tuners.classical.constrained import constrained_design

    cls = load_settings(ClassicalSettings)
    refusals = []
    for rule in s.center:
        try:
            gains, tuning = constrained_design(
                rule, inputs.plant, inputs.disturbance, cls, scorer, inputs.settings.pid.N
            )
        except ValueError as exc:  # no knob setting meets the constraints: the next rule
            refusals.append(str(exc))
            continue
        return gains, {"rule": rule, "knob": tuning["knob"], "tuned_on": list(plants),
                       "gains": [gains.P, gains.I, gains.D, gains.N],
                       "refused": refusals}  # fmt: skip
    raise ValueError("no centre design for the RL tuner: " + "; ".join(refusals))


def episode_admission(
    infos: Sequence[dict[str, Any]], objective: Objective, disturbance: Disturbance,
    randomize: bool,
) -> Admission:  # fmt: skip
    """The admission rule on ``GripperPIDTune-v0`` episodes (one controller per episode), from
    their ``info``: the loop's margins on the episode's plant, the run's settling, stall and jaw
    envelope against the nearest stops ``disturbance`` can draw."""
    from gripper_env.evaluation.admission import Admission, checks_of_runs, nearest_stops_deg

    rb = [i["robustness"] for i in infos]

    def col(key: str, default: float) -> np.ndarray:
        return np.array([default if r.get(key) is None else r[key] for r in rb], dtype=float)

    checks = checks_of_runs(
        grip_settling_s=[(i.get("grip") or {}).get("settling_time_s") for i in infos],
        ungrip_settling_s=[(i.get("ungrip") or {}).get("settling_time_s") for i in infos],
        stable=[bool(i.get("stable", False)) for i in infos],
        jaw_min_deg=[i.get("jaw_min_deg") for i in infos],
        jaw_max_deg=[i.get("jaw_max_deg") for i in infos],
        stall_s=[i.get("stall_s") for i in infos],
        contact_s=[i.get("contact_s") for i in infos],
        k=len(infos),
        stops_deg=nearest_stops_deg(disturbance, randomize),
    )
    return Admission.build(
        objective.constraints.limits(search=True), ms=col("ms", math.inf),
        gm_db=col("gain_margin_db", math.inf), gm_lower_db=col("lower_gain_margin_db", -math.inf),
        loop_stable=np.array([bool(r.get("stable")) for r in rb]),
        spectral_radius=col("max_pole_magnitude", 1.0), checks=checks,
    )  # fmt: skip


def admission_reward(
    venv: Any, objective: Objective, disturbance: Disturbance, randomize: bool
) -> Any:
    """``GripperPIDTune-v0`` with the PID tuner's training reward,
    ``-log(cost + infeasible_penalty * violation)``, the violation being the admission rule's on
    each episode (:func:`episode_admission`).

    The environment's own reward folds in the robustness constraints with a cliff of
    ``infeasible_penalty`` at their boundary, where the best gains lie; a Gaussian policy that
    maximises the expected reward across a cliff keeps its mean away from it. The exact penalty
    (no jump, growing with the violation, larger than the constraints' multipliers: one deg past
    the stop clearance costs 10) lets the policy sit on the boundary, and the log keeps an
    unstable loop's 10,000 from swamping the advantages of the gains that matter (costs 10-30).
    """
    from stable_baselines3.common.vec_env import VecEnvWrapper

    penalty = float(objective.infeasible_penalty)

    class _AdmissionReward(VecEnvWrapper):
        def reset(self) -> Any:
            return self.venv.reset()

        def step_wait(self) -> Any:
            obs, rewards, dones, infos = self.venv.step_wait()
            rule = episode_admission(infos, objective, disturbance, randomize)
            cost = np.array([i.get("cost", -r) for i, r in zip(infos, rewards, strict=True)])
            shaped = -np.log(np.maximum(cost + penalty * rule.violation, 1e-6))
            return obs, shaped.astype(np.float32), dones, infos

    return _AdmissionReward(venv)


def _context_free(venv: Any) -> Any:
    """The environment with its observation zeroed: one gain set for every plant (robust)."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class _NoContext(VecEnvWrapper):
        def reset(self) -> Any:
            return np.zeros_like(self.venv.reset())

        def step_wait(self) -> Any:
            obs, rewards, dones, infos = self.venv.step_wait()
            return np.zeros_like(obs), rewards, dones, infos

    return _NoContext(venv)


def train_tuner(
    inputs: cli.Inputs,
    s: RLTuneSettings,
    *,
    seed: int,
    run_dir: str | os.PathLike[str],
    plants: Sequence[str] = (),
    episodes: int | None = None,
    optuna_settings: OptunaSettings | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
    designed: tuple[PIDGains, dict[str, Any]] | None = None,
) -> TuneRun:
    """Train the PID tuner with one seed; return its run (see :class:`TuneRun`).

    Parameters
    ----------
    inputs : tuners.cli.Inputs
        Plant, preset, profile and evaluation settings.
    s : RLTuneSettings
        The recipe.
    seed : int
        Training seed (PPO, the environments' episodes).
    run_dir : path
        Where the model and ``history.json`` go.
    plants : sequence of str
        Robust mode: several identifications, one gain set for all (a context-free policy,
        scored on every plant's tuning seeds); default the inputs' plant.
    episodes : int, optional
        Training budget (default ``s.episodes``).
    optuna_settings : OptunaSettings, optional
        Where the tuning seeds come from (default ``configs/tuners/optuna.yaml``).
    progress : bool
        Show a progress bar on stderr.
    designed : (PIDGains, dict), optional
        The centre design and its record, as :func:`design_center` gives them for these inputs
        (computed here when not given; :func:`train_seeds` computes it once for every seed).
    """
    require_rl()
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList

    from gripper_env.envs.spaces import action_to_gains

    names = list(plants) or [inputs.plant.name]
    robust = len(names) > 1
    total = s.episodes if episodes is None else int(episodes)
    scorer = make_scorer(inputs, optuna_settings, names if robust else ())
    center, center_record = designed or design_center(inputs, s, names, scorer)
    kwargs = env_kwargs(inputs, names, s, center)
    torch.set_num_threads(1)  # small networks: threads cost more than they give on 2 cores
    venv = admission_reward(
        make_vec_env("pid-tune", kwargs, s.n_envs, seed), scorer.task.objective,
        inputs.disturbance, s.randomize,
    )  # fmt: skip
    if robust:
        venv = _context_free(venv)
    model = PPO(
        "MlpPolicy", venv, n_steps=s.n_steps, batch_size=s.batch_size, n_epochs=s.n_epochs,
        learning_rate=s.learning_rate, gamma=0.0, gae_lambda=0.0, ent_coef=0.0, seed=seed,
        device="cpu", verbose=0,
        policy_kwargs={"net_arch": list(s.net_arch), "log_std_init": s.log_std_init},
    )  # fmt: skip
    quiet_logger(model)
    nominal = gym.make(ENV_IDS["pid-tune"], **dict(kwargs, randomize=False))
    obs0, _ = nominal.reset(seed=0)
    nominal.close()
    if robust:
        obs0 = np.zeros_like(obs0)
    gain_max = kwargs["gain_max"]
    evaluations: list[dict[str, Any]] = []
    run_dir = Path(run_dir)

    def evaluate_policy() -> None:
        action, _ = model.predict(obs0, deterministic=True)
        a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        g = action_to_gains(a[None, :], gain_max, "relative", kwargs["gain_center"], s.decades)[0]
        gains = PIDGains(float(g[0]), float(g[1]), float(g[2]), center.N)
        scores = scorer.score(gains.as_array()[None, :])
        evaluations.append({
            "episodes": int(model.num_timesteps),
            "tuning_cost": float(scores.cost[0]),
            "feasible": bool(scores.feasible[0]),
            "ms": float(scores.ms[0]),
            "gain_margin_db": float(scores.gm_db[0]),
            "gains": [gains.P, gains.I, gains.D, gains.N],
            "action": a.round(6).tolist(),
            "on_bound": bool(np.any(np.abs(a) >= BOUND_ACTION)),
        })  # fmt: skip

    class Evaluate(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next_at = s.eval_every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_at:
                self.next_at += s.eval_every
                evaluate_policy()
            return True

    start = time.perf_counter()
    evaluate_policy()  # the untrained policy: the centre design, nudged by the initial weights
    label = f"rl-tune {'+'.join(names)} seed {seed}"
    model.learn(
        total_timesteps=total,
        callback=CallbackList([Evaluate(), progress_callback(total, label, disable=not progress)]),
    )
    if evaluations[-1]["episodes"] != model.num_timesteps:
        evaluate_policy()
    wall = time.perf_counter() - start
    venv.close()
    good = [e for e in evaluations if e["feasible"] and not e["on_bound"]]
    best = min(good, key=lambda e: e["tuning_cost"]) if good else None
    run_dir.mkdir(parents=True, exist_ok=True)
    save_model(model, run_dir / "model.zip")
    run = TuneRun(
        env_id=ENV_IDS["pid-tune"],
        env_kwargs=_plain(kwargs),
        plants=names,
        seed=seed,
        episodes=int(model.num_timesteps),
        selection_episodes=len(evaluations) * scorer.task.runs_per_gain_set,
        train_wall_time_s=wall,
        center=center_record,
        evaluations=evaluations,
        best=best,
        settings=s.model_dump(),
        context_free=robust,
        rule=rule_record(scorer.task.objective),
    )
    write_result_json(run_dir / "history.json", run)
    run["gains"] = None if best is None else PIDGains(*best["gains"])
    if best is None:
        log(f"  {label}: no feasible gains off the map's bounds were evaluated")
    else:
        log(f"  {label}: best tuning cost {best['tuning_cost']:.4g} at {best['episodes']} "
            f"episodes; {total} episodes in {wall:.0f} s")  # fmt: skip
    return run


@dataclass(frozen=True)
class _TuneTask:
    """One training seed of the tuner: what a worker needs (picklable)."""

    inputs: cli.Inputs
    settings: RLTuneSettings
    seed: int
    plants: tuple[str, ...]
    episodes: int | None
    optuna_settings: OptunaSettings | None
    progress: bool
    designed: tuple[PIDGains, dict[str, Any]] | None = None


def _tune_seed(task: _TuneTask) -> tuple[TuneRun, dict[str, bytes]]:
    """Train one seed in a scratch folder; return the run and its files."""
    import tempfile

    from gripper_env.io.files import collect_provenance
    from tuners.engine import gather_files

    with tempfile.TemporaryDirectory() as tmp:
        # the task's own sidecar, sent back with its files (tuners.engine.write_files)
        with collect_provenance(tmp, "task", own=True):
            run = train_tuner(
                task.inputs, task.settings, seed=task.seed, run_dir=tmp, plants=task.plants,
                episodes=task.episodes, optuna_settings=task.optuna_settings,
                progress=task.progress, log=lambda m: None, designed=task.designed,
            )  # fmt: skip
        return run, gather_files(tmp)


def train_seeds(
    inputs: cli.Inputs,
    s: RLTuneSettings,
    seeds: Sequence[int],
    folder: str | os.PathLike[str],
    *,
    plants: Sequence[str] = (),
    episodes: int | None = None,
    optuna_settings: OptunaSettings | None = None,
    progress: bool = True,
    engine_spec: str | None = None,
    reuse: bool = False,
) -> list[TuneRun]:
    """:func:`train_tuner` for every seed, through an engine (:mod:`tuners.engine`); each run
    in ``<folder>/seed-<k>``. The same seeds give the same runs on every engine. With
    ``reuse``, a seed whose ``history.json`` was made with the same settings, budget,
    environment (centre design included) and tuning seeds is read, not trained again."""
    from tuners.engine import engine, write_files

    folder = Path(folder)
    serial = engine_spec in (None, "serial")
    done: dict[int, TuneRun] = {}
    names = list(plants) or [inputs.plant.name]
    scorer = make_scorer(inputs, optuna_settings, names if len(names) > 1 else ())
    designed = design_center(inputs, s, names, scorer)  # once for every seed
    center = designed[0]
    if reuse:
        wanted = json.loads(json.dumps(_plain(env_kwargs(inputs, names, s, center))))
        for k in seeds:
            run = _reusable_run(folder / f"seed-{k}" / "history.json", s, episodes, wanted,
                                rule_record(scorer.task.objective))  # fmt: skip
            if run is not None:
                done[int(k)] = run
    tasks = [_TuneTask(inputs, s, int(k), tuple(plants), episodes, optuna_settings,
                       progress and serial, designed) for k in seeds
             if int(k) not in done]  # fmt: skip
    with engine(engine_spec) as eng:
        for task, (run, files) in zip(tasks, eng.map(_tune_seed, tasks), strict=True):
            write_files(folder / f"seed-{task.seed}", files)
            done[task.seed] = run
    return [done[int(k)] for k in seeds]


def rule_record(objective: Objective) -> dict[str, Any]:
    """What the run's reward and selection judged by: the admission rule's limits (a run made
    under another rule, or before the rule, is not reused)."""
    return {"reward": "admission", **objective.constraints.model_dump()}


def _reusable_run(
    path: Path, s: RLTuneSettings, episodes: int | None, kwargs: dict[str, Any],
    rule: dict[str, Any],
) -> TuneRun | None:  # fmt: skip
    """The run at ``path`` if it was made with these settings, budget, environment and rule."""
    try:
        old = json.loads(read_bounded(path, MAX_DATA_BYTES, "result file"))
    except (OSError, ValueError):
        return None
    budget = s.episodes if episodes is None else int(episodes)
    # the rule list is not compared: the centre design it gave is (gain_center in the kwargs)
    mine = json.loads(json.dumps(s.model_dump(exclude={"center"})))
    same = (
        {k: v for k, v in (old.get("settings") or {}).items() if k != "center"} == mine
        and old.get("env_kwargs") == kwargs
        and old.get("rule") == json.loads(json.dumps(rule))
        and old.get("episodes", -1) >= budget > old.get("episodes", 0) - s.n_envs * s.n_steps
    )
    if not same:
        return None
    run = TuneRun(old)
    run["gains"] = None if run["best"] is None else PIDGains(*run["best"]["gains"])
    return run


def _plain(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The environment's arguments as JSON (objects by name)."""
    out = dict(kwargs)
    for key in ("disturbance", "reference"):
        value = out[key]
        out[key] = getattr(value, "name", value)
    return out


def learning_curve(run: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """``(episodes, tuning cost of the policy's gains)`` of a run (infeasible: NaN)."""
    ev = run["evaluations"]
    x = np.array([e["episodes"] for e in ev], dtype=float)
    y = np.array([e["tuning_cost"] if e["feasible"] else math.nan for e in ev])
    return x, y
