"""Reference scores of the RL benchmark: every task's anchors, its best PID, and PPO and SAC over
training seeds, on a scale with headroom.

``python -m tuners.rl.reference_scores [--out results] [--tasks servo,grasp] [--engine local:2]``
writes ``reference_scores.md`` and ``.json``, the performance-profile figure
``figures/rl_performance_profiles.png`` and the run's provenance sidecar (commit, date, library
versions). For every task of ``configs/rl_zoo/tasks.yaml`` (:mod:`tuners.rl.suite`):

* **the scale** (:mod:`tuners.rl.scores`): 0 is the trivial policy (command = reference), 100
  the limit (the exact linear program of the reward, a floor under the objective's cost, or a
  stated oracle: :mod:`tuners.rl.anchors`), both computed per episode of the task's fixed
  evaluation set;
* **the best PID** (:func:`tuners.rl.judge.best_pid`): the committed gains file with the best
  return on selection episodes of the training arguments, among those the task's verdict admits;
* **PPO and SAC**: the task's rl-zoo3 recipes (``configs/rl_zoo/tasks/<task>-<algo>.yml``), one
  run per training seed (the task's ``seeds``: at least 10 where a seed trains in under two
  minutes, at least 5 elsewhere), on the native vector environment where the id has one
  (:class:`gripper_env.envs.sb3.NativeVecEnv`, step for step a ``DummyVecEnv``'s equal) and a
  ``DummyVecEnv`` otherwise. Each seed's agent is judged like any other
  (:func:`tuners.rl.judge.judge_policy`); a cell is the IQM of the seeds' scores with its
  stratified-bootstrap 95 % interval, and the figure the performance profiles over the hard
  tasks (rliable's protocol).

A published score below 0 (worse than command = reference) is printed as "< 0" in the table,
with its unclipped score and raw return in the task's section (:mod:`tuners.rl.scores` says
why); the aggregates and the profiles use the unclipped scores. The anchor shift of a task is
how far the anchors' own standard errors would move its published scores in [0, 100]
(:func:`published_scores`); the evaluation sets of ``tasks.yaml`` are sized to keep it near 1
point or below.

Every row keeps its raw returns, the objective's cost, the constraint cost, the measured margins
and the verdict beside its score. The seeds train where ``--engine`` says (``serial``,
``local:N`` worker processes, a Dask cluster: :mod:`tuners.engine`); each seed's row and agent
are kept under ``--cache`` (default ``runs/rl/reference``) and reused when the recipe, budget and
anchors are unchanged, so an interrupted run resumes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.config import MAX_DATA_BYTES, read_bounded
from gripper_env.io.files import (
    collect_provenance,
    run_facts,
    save_figure,
    write_atomic,
    write_json,
    write_result_json,
)
from tuners import cli
from tuners.engine import ENGINE_HELP, engine
from tuners.rl.agents import one_torch_thread
from tuners.rl.scores import normalise, stratified_bootstrap_ci
from tuners.rl.suite import ALGOS, Task, load_tasks, recipe, task

__all__ = ["main", "reference_scores", "render", "train_agent"]

FIGURE = "figures/rl_performance_profiles.png"


# ---- training ------------------------------------------------------------------------------


def train_agent(t: Task, algo: str, seed: int, timesteps: int | None = None) -> Any:
    """PPO or SAC with the task's rl-zoo3 recipe on its training arguments; the trained
    :class:`tuners.rl.agents.Agent`."""
    import gymnasium as gym
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor, VecNormalize

    from tuners.rl.agents import Agent, quiet_logger
    from tuners.rl.envs import require_rl

    require_rl()
    one_torch_thread()
    params = recipe(t.name, algo)
    env_id = params.pop("env_id")
    kwargs = dict(params.pop("env_kwargs", None) or {})
    n_envs = int(params.pop("n_envs", 1))
    total = int(timesteps or params.pop("n_timesteps"))
    params.pop("n_timesteps", None)
    normalize = params.pop("normalize", False)
    policy_kwargs = params.pop("policy_kwargs", None)
    if isinstance(policy_kwargs, str):  # rl-zoo3's convention: a Python expression
        policy_kwargs = eval(policy_kwargs)
    if gym.spec(env_id).vector_entry_point is not None:
        from gripper_env.envs.sb3 import NativeVecEnv

        base: Any = NativeVecEnv(env_id, num_envs=n_envs, **kwargs)
    else:
        base = DummyVecEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n_envs)])
    venv: Any = VecMonitor(base)
    if normalize:
        norm = eval(normalize) if isinstance(normalize, str) else {}
        venv = VecNormalize(venv, gamma=params.get("gamma", 0.99), **norm)
    venv.seed(seed)
    cls = {"ppo": PPO, "sac": SAC}[algo]
    model = cls(params.pop("policy"), venv, seed=seed, device="cpu", verbose=0,
                policy_kwargs=policy_kwargs, **params)  # fmt: skip
    quiet_logger(model)
    model.learn(total)
    normalizer = venv if normalize else None
    if normalizer is not None:
        normalizer.training = False
    venv.close()
    return Agent(model, normalizer, env_id, kwargs,
                 facts={"algo": algo, "seed": seed, "task": t.name})  # fmt: skip


@dataclass(frozen=True)
class _Job:
    """One training seed of one cell: what a worker needs (picklable)."""

    task: str
    algo: str
    seed: int
    timesteps: int | None
    anchors: dict[str, list[float]] | None  # None: train (and keep) the agent only
    folder: str
    episodes: int | None = None  # the first episodes of the evaluation set only


def _recipe_key(t: Task, algo: str, timesteps: int | None) -> str:
    """What a kept agent depends on: its recipe and budget."""
    text = json.dumps([recipe(t.name, algo), timesteps], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _row_key(agent_key: str, t: Task, anchors: dict[str, Any]) -> str:
    """What a kept row depends on: the agent, the evaluation set, the anchors."""
    text = json.dumps([agent_key, t.eval_seeds, t.eval_kwargs, anchors["trivial"],
                       anchors["limit"]], sort_keys=True, default=str)  # fmt: skip
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _kept_facts(folder: Path, key: str) -> dict[str, Any] | None:
    """The facts of the agent kept in ``folder`` if it was trained with the recipe and budget
    ``key`` (its ``agent.json`` is written last, so a seed still training has none)."""
    meta = folder / "agent.json"
    if not meta.is_file():
        return None
    facts: dict[str, Any] = json.loads(meta.read_text())
    return facts if facts.get("recipe_key") == key else None


def _agent(job: _Job, t: Task) -> tuple[Any, float, str]:
    """The seed's agent: kept in its folder (same recipe and budget), else trained now."""
    from tuners.rl.agents import load_agent

    folder = Path(job.folder) / "agent"
    key = _recipe_key(t, job.algo, job.timesteps)
    facts = _kept_facts(folder, key)
    if facts is not None:
        return load_agent(folder), float(facts.get("train_wall_time_s", math.nan)), key
    start = time.perf_counter()
    agent = train_agent(t, job.algo, job.seed, job.timesteps)
    wall = time.perf_counter() - start
    from tuners.rl.agents import save_agent

    save_agent(agent, folder, {"algo": job.algo, "seed": job.seed, "task": t.name,
                               "timesteps": int(agent.model.num_timesteps), "recipe_key": key,
                               "train_wall_time_s": wall})  # fmt: skip
    return agent, wall, key


def _run_job(job: _Job) -> dict[str, Any] | None:
    """Train (or reuse) one seed's agent and judge it; its row (kept in the job's folder)."""
    from tuners.rl.judge import judge_policy

    one_torch_thread()
    t = task(job.task).first(job.episodes)
    agent, wall, key = _agent(job, t)
    if job.anchors is None:
        return None
    row_key = _row_key(key, t, job.anchors)
    cached = Path(job.folder) / "row.json"
    if cached.is_file():
        row = json.loads(cached.read_text())
        if row.get("key") == row_key:
            row["cached"] = True
            return row
    # the environment arguments the agent brings (its action map: a residual on the reference)
    iface = {k: v for k, v in agent.env_kwargs.items() if k in t.interface}
    row = judge_policy(t, agent, job.anchors, iface)
    row.update(interface={k: list(v) if isinstance(v, tuple) else v for k, v in iface.items()})
    row.update(seed=job.seed, algo=job.algo, train_wall_time_s=wall, key=row_key,
               timesteps=int(job.timesteps or t.timesteps[job.algo]))  # fmt: skip
    write_json(cached, row)
    row["cached"] = False
    return row


# ---- one task ------------------------------------------------------------------------------


#: What the anchors and the best PID are computed from, besides the task: a change to any of these
#: files computes them again (:func:`task_anchors`' cache).
_SOURCES = (
    "gripper_env/envs",
    "gripper_env/sim",
    "gripper_env/evaluation",
    "gripper_env/model",
    "tuners/probe.py",
    "tuners/rl/anchors.py",
    "tuners/rl/judge.py",
    "tuners/rl/rollouts.py",
    "tuners/rl/limits.py",
    "tuners/rl/scores.py",
    "configs",
)


def _anchors_key(t: Task, root: Path) -> str:
    """The task, its PID candidates' files and the code that computes its anchors, hashed."""
    import tuners

    h = hashlib.sha256(json.dumps([t.name, t.env_id, t.eval_kwargs, t.train_kwargs, t.episodes,
                                   t.limit, t.trivial, t.verdict, t.pid, list(t.interface),
                                   t.limit_episodes],
                                  sort_keys=True, default=str).encode())  # fmt: skip
    code = Path(tuners.__file__).resolve().parent.parent
    files: list[Path] = []
    for rel in _SOURCES:
        p = code / rel
        files += sorted(p.rglob("*.py")) + sorted(p.rglob("*.y*ml")) if p.is_dir() else [p]
    for plant in t.pid.get("plants", []):
        files += sorted((root / "results" / plant).glob("*.json"))
    files += [root / r for r in t.pid.get("registers", [])]
    for f in files:
        if f.is_file():
            h.update(str(f.name).encode() + f.read_bytes())
    return h.hexdigest()[:16]


def task_anchors(
    t: Task, cache: Path, root: Path, log: Callable[[str], None] = print
) -> dict[str, Any]:
    """The task's anchors (per episode), their standard errors, and the best-PID row; kept in
    ``<cache>/anchors/<task>.json`` and reused while the task, its PID candidates and the code
    that computes them are unchanged."""
    key = _anchors_key(t, root)
    kept = cache / "anchors" / f"{t.name}-{t.episodes}.json"
    if kept.is_file():
        stored = json.loads(kept.read_text())
        if stored.get("key") == key:
            log(f"  {t.name}: anchors and best PID reused ({kept})")
            return stored["entry"]
    entry = _task_anchors(t, cache, root, log)
    write_json(kept, {"key": key, "entry": entry})
    return entry


def _task_anchors(
    t: Task, cache: Path, root: Path, log: Callable[[str], None] = print
) -> dict[str, Any]:
    from tuners.rl.anchors import limit_returns, trivial_returns
    from tuners.rl.judge import best_pid

    r0 = trivial_returns(t)
    r100, limit_info = limit_returns(t, cache / "limits", log=log)
    anchors = {"trivial": r0.tolist(), "limit": r100.tolist()}
    n, m = len(r0), len(r100)
    pid = best_pid(t, anchors, root, log=log)
    return {
        "anchors": anchors,
        "anchor_stats": {
            "trivial": {
                "mean": float(r0.mean()),
                "se": float(r0.std(ddof=1) / math.sqrt(n)),
                "episodes": n,
            },
            "limit": {
                "mean": float(r100.mean()),
                "se": float(r100.std(ddof=1) / math.sqrt(m)),
                "episodes": m,
                **limit_info,
            },
            "episodes": n,
        },
        "pid": pid,
    }


def _cell(rows: list[dict[str, Any]]) -> dict[str, Any]:
    scores = np.array([r["score"] for r in rows])
    point, lo, hi = stratified_bootstrap_ci(scores)
    return {
        "seeds": len(rows),
        "iqm": point,
        "ci95": [lo, hi],
        "median": float(np.median(scores)),
        "per_seed": [{k: r[k] for k in ("seed", "score", "score_se", "return_mean", "admitted",
                                         "verdict", "train_wall_time_s") if k in r}
                     for r in rows],
        "return_mean": float(np.mean([r["return_mean"] for r in rows])),
        "admitted_seeds": int(sum(bool(r["admitted"]) for r in rows)),
        "max_eval_se": float(max(r["score_se"] for r in rows)),
        "timesteps": rows[0].get("timesteps"),
        "train_wall_time_s": float(np.median([r["train_wall_time_s"] for r in rows])),
        "objective_cost": _mean_dicts([r.get("objective_cost") for r in rows]),
        "constraint_cost": _mean_dicts([r.get("constraint_cost") for r in rows]),
        "held_fraction": _mean_key(rows, "held_fraction"),
        "worst_margin_db": _worst_margins(rows),
    }  # fmt: skip


def _mean_dicts(items: Sequence[dict[str, float] | None]) -> dict[str, float] | None:
    got = [d for d in items if d]
    if not got:
        return None
    return {k: float(np.mean([d[k] for d in got])) for k in got[0]}


def _mean_key(rows: list[dict[str, Any]], key: str) -> float | None:
    vals = [r[key] for r in rows if key in r]
    return float(np.mean(vals)) if vals else None


def _worst_margins(rows: list[dict[str, Any]]) -> list[float | None] | None:
    """Per seed, the worst plant's measured gain margin (dB; ``None``: none up to 40 dB)."""
    out = []
    for r in rows:
        m = r.get("margins")
        if not m:
            return None
        gms = [v["gain_margin_db"] for v in m.values()]
        out.append(None if all(g is None for g in gms) else min(g for g in gms if g is not None))
    return out


def reference_scores(
    names: Sequence[str],
    *,
    cache: Path,
    root: Path = Path("."),
    seeds: int | None = None,
    timesteps: int | None = None,
    engine_spec: str | None = None,
    train_only: bool = False,
    train: bool = True,
    episodes: int | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Every named task's anchors, best PID and reference rows (module docstring);
    ``train_only``: train and keep the seeds' agents, nothing else (an empty table).

    ``train=False`` trains nothing: a cell is scored only when every one of its seeds has an
    agent kept under ``cache`` (same recipe and budget); any other cell is listed in the task's
    ``untrained`` (seeds kept of seeds wanted, and the command that trains them) instead of
    ``cells``, never scored on the seeds it has."""
    table: dict[str, Any] = {}
    jobs: list[_Job] = []
    if train_only:
        jobs = [
            _Job(n, algo, k, timesteps, None, str(cache / "reference" / n / algo / f"seed-{k}"))
            for n in names
            for algo in ALGOS
            for k in range(seeds or task(n).seeds[algo])
        ]
        log(f"training {len(jobs)} seeds ({engine_spec or 'serial'})")
        with engine(engine_spec) as eng:
            for job, _ in zip(jobs, eng.map(_run_job, jobs), strict=True):
                log(f"  {job.task} {job.algo} seed {job.seed}: kept")
        return table
    for name in names:
        t = task(name).first(episodes)
        log(f"{name}: anchors and the best PID")
        entry = task_anchors(t, cache, root, log=log)
        entry.update(about=t.about, env_id=t.env_id, hard=t.hard, train_kwargs=t.train_kwargs,
                     eval_kwargs=t.eval_kwargs, verdict_rule=t.verdict, limit_kind=t.limit,
                     cells={})  # fmt: skip
        table[name] = entry
        untrained: dict[str, Any] = {}
        for algo in ALGOS:
            n = seeds or t.seeds[algo]
            cell_jobs = [_Job(name, algo, k, timesteps, entry["anchors"],
                              str(cache / "reference" / name / algo / f"seed-{k}"), episodes)
                         for k in range(n)]  # fmt: skip
            key = _recipe_key(t, algo, timesteps)
            kept = [j.seed for j in cell_jobs
                    if _kept_facts(Path(j.folder) / "agent", key) is not None]  # fmt: skip
            if train or len(kept) == n:
                jobs += cell_jobs
                continue
            untrained[algo.upper()] = {
                "seeds": n,
                "kept_seeds": kept,
                "timesteps": int(timesteps or t.timesteps[algo]),
                "train": _train_command(name, cache, seeds, timesteps),
            }
            log(f"  {algo.upper()}: {len(kept)} of {n} seeds kept: not trained in this run, not "
                "scored")  # fmt: skip
        if untrained:
            entry["untrained"] = untrained
        pid = entry["pid"]
        log(f"  best PID {pid['pid']}: score {pid['score']:.1f} (return {pid['return_mean']:.4g}"
            f"), {pid['verdict']}")  # fmt: skip
    rows: dict[tuple[str, str], list[dict[str, Any]]] = {}
    log(f"training {len(jobs)} seeds ({engine_spec or 'serial'})")
    with engine(engine_spec) as eng:
        for job, row in zip(jobs, eng.map(_run_job, jobs), strict=True):
            assert row is not None
            rows.setdefault((job.task, job.algo), []).append(row)
            log(f"  {job.task} {job.algo} seed {job.seed}: score {row['score']:.1f}"
                f"{' (cached)' if row['cached'] else ''}, {row['verdict']}")  # fmt: skip
    for (name, algo), cell_rows in rows.items():
        table[name]["cells"][algo.upper()] = _cell(sorted(cell_rows, key=lambda r: r["seed"]))
    for entry in table.values():
        shift = _anchor_shift(entry)
        entry["anchor_stats"]["max_cell_shift"] = shift["max"]
        entry["anchor_stats"]["shift_on"] = shift["on"]
        entry["anchor_stats"]["episodes_for_1_point_shift"] = shift["episodes_for_1_point"]
        entry["anchor_stats"]["shift_by"] = shift["by"]
        entry["max_score_seen"] = max(
            [entry["pid"]["score"]] + [s["score"] for c in entry["cells"].values()
                                       for s in c["per_seed"]])  # fmt: skip
    return table


def _train_command(name: str, cache: Path, seeds: int | None, timesteps: int | None) -> str:
    """The command that trains (and keeps) a task's missing seeds."""
    extra = "" if cache == Path("runs/rl") else f" --cache {cache}"
    extra += "" if seeds is None else f" --seeds {seeds}"
    extra += "" if timesteps is None else f" --timesteps {timesteps}"
    return f"python -m tuners.rl.reference_scores --train-only --tasks {name}{extra}"


def published_scores(entry: dict[str, Any]) -> dict[str, float]:
    """The scores a task's table publishes, by name: the best PID's and each cell's IQM with its
    interval bounds (``"PPO iqm"``, ``"PPO ci low"``, ...)."""
    out = {"best PID": float(entry["pid"]["score"])}
    for algo, c in entry["cells"].items():
        out[f"{algo} iqm"] = float(c["iqm"])
        out[f"{algo} ci low"], out[f"{algo} ci high"] = (float(x) for x in c["ci95"])
    return out


def _anchor_shift(entry: dict[str, Any]) -> dict[str, Any]:
    """How far an anchor's own standard error would move a published score on the scale (points):
    for each published score in [0, 100] (:func:`published_scores`; one below 0 is printed as
    "< 0", so its distance below the trivial policy is not a ranking the scale carries), the
    score recomputed with the trivial's mean moved by its SE, or the limit's by its SE (each
    anchor alone, both signs, the row's return held); the largest move, the score it is on, the
    anchor that moves it, and the episodes of that anchor that would bring it to 1 point (the
    SEs shrink as 1/sqrt(episodes); the limit may be computed on fewer episodes than the set).

    The IQM and its interval are order statistics of the seeds' scores, and a score is affine in
    the return, so moving an anchor moves them as it moves a single score."""
    a = entry["anchor_stats"]
    r0, r100 = a["trivial"]["mean"], a["limit"]["mean"]
    span = r100 - r0
    worst, on, by = 0.0, None, None
    for name, v in published_scores(entry).items():
        if not 0.0 <= v <= 100.0:
            continue
        r = r0 + v * span / 100.0
        for anchor, d0, d1 in (("trivial", a["trivial"]["se"], 0.0),
                               ("limit", 0.0, a["limit"]["se"])):  # fmt: skip
            for sign in (1.0, -1.0):
                move = abs(float(normalise(r, r0 + sign * d0, r100 + sign * d1)) - v)
                if move > worst:
                    worst, on, by = move, name, anchor
    n = int(a[by].get("episodes", a["episodes"])) if by else 0
    return {"max": worst, "on": on, "by": by,
            "episodes_for_1_point": math.ceil(n * worst**2) if on else None}  # fmt: skip


def aggregate(table: dict[str, Any], hard_only: bool = True) -> dict[str, Any]:
    """Per algorithm, the IQM over the (hard) tasks' runs with its stratified-bootstrap
    interval (rliable's aggregate)."""
    out = {}
    for algo in (a.upper() for a in ALGOS):
        groups = {name: np.array([s["score"] for s in e["cells"][algo]["per_seed"]])
                  for name, e in table.items()
                  if algo in e["cells"] and (e["hard"] or not hard_only)}  # fmt: skip
        if groups:
            point, lo, hi = stratified_bootstrap_ci(groups)
            out[algo] = {"iqm": point, "ci95": [lo, hi], "tasks": sorted(groups)}
    return out


# ---- the report ----------------------------------------------------------------------------


def _f(x: float | None, fmt: str = ".1f") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def _cell_text(c: dict[str, Any] | None, missing: dict[str, Any] | None = None) -> str:
    if missing:
        return f"not trained in this run ({len(missing['kept_seeds'])}/{missing['seeds']} seeds)"
    if not c:
        return "-"
    return (f"{_pub(c['iqm'])} [{_pub(c['ci95'][0])}, {_pub(c['ci95'][1])}] "
            f"({c['admitted_seeds']}/{c['seeds']})")  # fmt: skip


def _pub(score: float) -> str:
    """A published score: below 0 (worse than command = reference) it is "< 0", its distance
    below the trivial policy not being a ranking the scale carries (the task's section gives
    the unclipped score and the raw return)."""
    return "< 0" if score < 0 else f"{score:.1f}"


def _shift_text(a: dict[str, Any]) -> str:
    return "-" if a.get("shift_on", "") is None else f"{a['max_cell_shift']:.2f}"


def render(table: dict[str, Any], agg: dict[str, Any]) -> str:
    """``reference_scores.md``."""
    lines = [
        "# Reference scores of the RL benchmark",
        "",
        "Written by `python -m tuners.rl.reference_scores --out results` (commit, date, library "
        "versions and each seed's training wall time: `reference_scores.provenance.json`). Tasks: "
        "`configs/rl_zoo/tasks.yaml`; scoring: `tuners/rl/scores.py`, `anchors.py`, `judge.py`.",
        "",
        "**The scale.** Score = 100 (R - R_0) / (R_100 - R_0), R the mean return over the task's "
        "fixed evaluation set (the episodes `reset(seed=100000 + i)` draws: random references "
        "and the gripper's friction, stops and noise drawn per episode). **0 = the trivial "
        "policy** (the servo commanded the reference); **100 = the limit**, a return no policy "
        "can reach: `reward-lp` is the exact linear program of the reward on each episode "
        "(plant, 20 ms hold, 0-180 deg, sensor delay; tuners/rl/limits.py), `objective-lp` the "
        "floor w_iae x least IAE under the objective's cost, `oracle` a stated hindsight "
        "oracle that knows where the object is (tuners/rl/anchors.py). The anchors are "
        "computed on the very episodes every policy runs, so they are exact constants of the "
        "set (where a task's limit takes seconds an episode, on the set's first episodes only, "
        "an estimate of the set's with the SE its section gives: `limit_episodes` in "
        "tasks.yaml); `eval SE` is how far a score would move on another set of the same size "
        "(anchors and policy resampled together), `anchor shift` how far an anchor's own "
        "standard error (each task's section gives both) alone would move the farthest "
        "published score in [0, 100] (the best PID's, each cell's IQM and its interval bounds; "
        "`-`: none is in [0, 100]). **A published score below 0 is printed as `< 0`**: the "
        "policy does worse than commanding the reference, and how far below is not a ranking "
        "the scale is meant to carry (its span is the trivial policy to the limit); the task's "
        "section gives the unclipped score and the raw return, and the aggregates over the hard "
        "tasks and the performance profiles use the unclipped scores of every run.",
        "",
        "**The protocol** (Agarwal et al. 2021): PPO and SAC with the task's rl-zoo3 recipe "
        "(`configs/rl_zoo/tasks/`), one run per training seed; a cell is the **interquartile "
        "mean of the seeds' scores [stratified-bootstrap 95 % interval]** and (admitted seeds / "
        "seeds); the verdict per seed is the task's (`margin`: measured gain margin >= 8.52 dB "
        "on every evaluation plant and no diverged episode; `feasible`: the gains meet Ms <= "
        "1.6 and 6 dB on every episode; `held`: every object held through its hold without a "
        "trip). The best PID is the committed gains file with the best return on 32 selection "
        "episodes of the training arguments, among those the verdict admits there.",
        "",
        "| task | hard | best PID | PPO | SAC | limit | eval SE (max) | anchor shift |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, e in table.items():
        pid = e["pid"]
        cells = e["cells"]
        untrained = e.get("untrained", {})
        se = max([pid["score_se"]] + [c["max_eval_se"] for c in cells.values()])
        lines.append(
            f"| {name} | {'yes' if e['hard'] else 'no'} | {_pub(pid['score'])} "
            f"({'admitted' if pid['admitted'] else 'not admitted'}) | "
            f"{_cell_text(cells.get('PPO'), untrained.get('PPO'))} | "
            f"{_cell_text(cells.get('SAC'), untrained.get('SAC'))} | "
            f"{e['limit_kind']} | {se:.2f} | {_shift_text(e['anchor_stats'])} |"
        )
    if agg:
        overall = "; ".join(f"{a} {v['iqm']:.1f} [{v['ci95'][0]:.1f}, {v['ci95'][1]:.1f}] "
                            f"({', '.join(v['tasks'])})" for a, v in agg.items())  # fmt: skip
        lines += ["", "Over the hard tasks with a scored cell (IQM of every run's score, "
                  f"stratified bootstrap over seeds within tasks): {overall}. Performance "
                  f"profiles: `{FIGURE}`."]  # fmt: skip
    missing = [(name, algo, m) for name, e in table.items()
               for algo, m in e.get("untrained", {}).items()]  # fmt: skip
    if missing:
        lines += ["", "**Not trained in this run** (no score is given for a cell until every "
                  "one of its seeds is trained; the seeds kept so far are not scored): "
                  + "; ".join(f"{name} {algo} ({len(m['kept_seeds'])} of {m['seeds']} seeds "
                              "kept)" for name, algo, m in missing)
                  + ". Each task's section gives the command that trains its seeds (kept "
                  "under `runs/rl/reference`); `python -m tuners.rl.reference_scores --out "
                  "results` then scores them."]  # fmt: skip
    for name, e in table.items():
        a = e["anchor_stats"]
        pid = e["pid"]
        lines += [
            "", f"## {name}: {e['about']}", "",
            f"`{e['env_id']}`, training `{e['train_kwargs']}`, evaluation `{e['eval_kwargs']}`, "
            f"{a['episodes']} episodes. Trivial return {a['trivial']['mean']:.4g} (SE "
            f"{a['trivial']['se']:.2g}); limit ({e['limit_kind']}) {a['limit']['mean']:.4g} (SE "
            f"{a['limit']['se']:.2g}{_limit_episodes_text(a)}); the largest score any run reached: "
            f"{e['max_score_seen']:.1f}. {_shift_sentence(a)}", "",
            "| row | score | eval SE | return (mean ± sd) | objective's cost | constraint cost "
            "| held | worst measured GM dB | verdict |",
            "|---|---|---|---|---|---|---|---|---|",
            f"| trivial (command = reference) | 0 | 0 | {a['trivial']['mean']:.4g} | | | | | |",
            _pid_line(pid),
        ]  # fmt: skip
        for algo, c in e["cells"].items():
            lines.append(
                f"| {algo} ({c['seeds']} seeds x {c['timesteps']} steps) | {c['iqm']:.1f} "
                f"[{c['ci95'][0]:.1f}, {c['ci95'][1]:.1f}] (median "
                f"{c['median']:.1f}) | {c['max_eval_se']:.2f} | {c['return_mean']:.4g} | "
                f"{_costs(c['objective_cost'])} | {_costs(c['constraint_cost'])} | "
                f"{_f(c['held_fraction'], '.0%')} | {_margins_text(c['worst_margin_db'])} | "
                f"{c['admitted_seeds']}/{c['seeds']} admitted |"
            )
        for algo, m in e.get("untrained", {}).items():
            lines.append(
                f"| {algo} ({m['seeds']} seeds x {m['timesteps']} steps) | not trained in this "
                f"run: {len(m['kept_seeds'])} of {m['seeds']} seeds kept (train them: "
                f"`{m['train']}`) | | | | | | | not scored |"
            )
        lines.append(f"| limit ({e['limit_kind']}) | 100 | 0 | {a['limit']['mean']:.4g} | | | | "
                     "| |")  # fmt: skip
    return "\n".join(lines) + "\n"


def _limit_episodes_text(a: dict[str, Any]) -> str:
    """ ", on the first M episodes" where the limit covers fewer than the set."""
    m = a["limit"].get("episodes", a["episodes"])
    return "" if m == a["episodes"] else f", on the first {m} episodes"


def _shift_sentence(a: dict[str, Any]) -> str:
    if a.get("shift_on", "") is None:
        return "No published score is in [0, 100], so the anchors' SEs move none (anchor shift -)."
    if "shift_on" not in a:
        return f"Anchor shift {a['max_cell_shift']:.2f} points."
    by = a.get("shift_by")
    whose = f" of the {by}" if by else ""
    return (
        f"Anchor shift {a['max_cell_shift']:.2f} points, on the {a['shift_on']} score, by the "
        f"{by or 'anchors'}'s SE ({a['episodes_for_1_point_shift']} episodes{whose} would make "
        "it 1 point)."
    )


def _pid_line(pid: dict[str, Any]) -> str:
    gm = None
    if pid.get("margins"):
        gms = [v["gain_margin_db"] for v in pid["margins"].values()]
        gm = (
            "none" if all(g is None for g in gms) else f"{min(g for g in gms if g is not None):.1f}"
        )
    return (f"| best PID ({pid['pid']}) | {pid['score']:.1f} | {pid['score_se']:.2f} | "
            f"{pid['return_mean']:.4g} ± {pid['return_sd']:.2g} | "
            f"{_costs(pid.get('objective_cost'))} | {_costs(pid.get('constraint_cost'))} | "
            f"{_f(pid.get('held_fraction'), '.0%')} | "
            f"{gm or '-'} | {pid['verdict']} |")  # fmt: skip


def _costs(d: dict[str, float] | None) -> str:
    if not d:
        return "-"
    return ", ".join(f"{k} {v:.3g}" for k, v in d.items())


def _margins_text(worst: list[float | None] | None) -> str:
    if not worst:
        return "-"
    vals = [math.inf if w is None else w for w in worst]
    return f"{min(vals):.1f} to {max(vals):.1f}".replace("inf", "none")


def profiles_figure(table: dict[str, Any], path: Path) -> Path:
    """Performance profiles over the hard tasks (fraction of runs above each score), with the
    best PID's scores marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tuners.rl.scores import performance_profile

    hard = {n: e for n, e in table.items() if e["hard"]}
    tau = np.linspace(-100.0, 100.0, 201)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for algo, colour in (("PPO", "tab:blue"), ("SAC", "tab:orange")):
        groups = {n: np.array([s["score"] for s in e["cells"][algo]["per_seed"]])
                  for n, e in hard.items() if algo in e["cells"]}  # fmt: skip
        if not groups:
            continue
        frac, lo, hi = performance_profile(groups, tau)
        ax.plot(tau, frac, color=colour, label=f"{algo} ({sum(len(g) for g in groups.values())} "
                f"runs, {len(groups)} tasks)")  # fmt: skip
        ax.fill_between(tau, lo, hi, color=colour, alpha=0.2, linewidth=0)
    pid = {n: np.array([e["pid"]["score"]]) for n, e in hard.items()}
    if pid:
        frac, _, _ = performance_profile(pid, tau, reps=1)
        ax.plot(tau, frac, color="k", linestyle="--", label="best PID (one per task)")
    ax.set_xlabel("normalised score (0 = command = reference, 100 = limit)")
    ax.set_ylabel("fraction of runs with score > x")
    ax.set_title("Performance profiles over the hard tasks (95 % stratified bootstrap)")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


# ---- the command ---------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m tuners.rl.reference_scores``."""
    return cli.run(_main, argv)


def _main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.rl.reference_scores",
        description="The RL benchmark's reference scores: every task's anchors, best PID, and "
        "PPO and SAC over training seeds, on a scale from command = reference (0) to the limit "
        "(100).",
    )
    parser.add_argument("--out", type=Path, default=cli.DEFAULT_OUT, help="output folder")
    parser.add_argument("--tasks", default=None,
                        help="comma-separated tasks (default: every task of "
                             "configs/rl_zoo/tasks.yaml)")  # fmt: skip
    parser.add_argument("--seeds", type=int, default=None,
                        help="training seeds per cell (default: each task's)")  # fmt: skip
    parser.add_argument(
        "--timesteps",
        type=int,
        default=None,
        help="training budget per seed (default: each recipe's n_timesteps)",
    )
    parser.add_argument("--engine", default=None, help=ENGINE_HELP)
    parser.add_argument("--episodes", type=int, default=None,
                        help="only the first N episodes of each evaluation set (a quick look; "
                             "the published scores use the whole set)")  # fmt: skip
    parser.add_argument(
        "--train-only",
        action="store_true",
        help="train and keep the seeds' agents under --cache, score nothing",
    )
    parser.add_argument(
        "--no-train",
        action="store_true",
        help="train nothing: score the cells whose seeds are all kept under --cache and list "
        "the others as not trained in this run (with the command that trains them)",
    )
    parser.add_argument("--cache", type=Path, default=Path("runs/rl"),
                        help="where the limits, each seed's agent and row are kept and reused "
                             "(default runs/rl)")  # fmt: skip
    args = cli.parse(parser, argv)
    names = list(load_tasks()) if args.tasks is None else [
        n.strip() for n in args.tasks.split(",") if n.strip()]  # fmt: skip
    for n in names:
        task(n)  # an unknown name: one line that lists the tasks
    if args.seeds is not None and not 1 <= args.seeds <= 100:
        raise ValueError(f"--seeds must be 1 to 100, got {args.seeds}")
    if args.timesteps is not None and args.timesteps < 1:
        raise ValueError(f"--timesteps must be at least 1, got {args.timesteps}")
    from tuners.rl.envs import require_rl

    require_rl()
    if args.train_only and args.no_train:
        raise ValueError("--train-only and --no-train exclude each other")
    if args.train_only:
        reference_scores(names, cache=args.cache, seeds=args.seeds, timesteps=args.timesteps,
                         engine_spec=args.engine, train_only=True)  # fmt: skip
        print(f"kept the agents under {args.cache / 'reference'}")
        return 0
    _publishable(args.out)
    with collect_provenance(args.out, "reference_scores", command=args.command):
        table = reference_scores(names, cache=args.cache, seeds=args.seeds,
                                 timesteps=args.timesteps, engine_spec=args.engine,
                                 train=not args.no_train, episodes=args.episodes)  # fmt: skip
        agg = aggregate(table)
        write_result_json(args.out / "reference_scores.json",
                          {"format": "gripper-rl-reference-scores", "version": 2,
                           "tasks": table, "aggregate_hard": agg})  # fmt: skip
        write_atomic(args.out / "reference_scores.md", render(table, agg))
        if any(e["hard"] and e["cells"] for e in table.values()):
            profiles_figure(table, args.out / FIGURE)
    print(f"wrote {args.out / 'reference_scores.md'}")
    return 0


def _publishable(out: Path) -> None:
    """Refuse to write the committed reference scores from a tree with uncommitted changes (the
    provenance would name a commit that did not make them), and load the learning libraries so
    that the provenance records their versions (the seeds train in worker processes)."""
    import importlib.util

    import stable_baselines3  # noqa: F401
    import torch  # noqa: F401

    if importlib.util.find_spec("rl_zoo3") is not None:
        import rl_zoo3  # noqa: F401
    committed = Path(__file__).resolve().parents[2] / "results"
    if out.resolve() == committed and run_facts()["git_dirty"]:
        raise ValueError(f"--out {out}: the committed results are written from a clean tree "
                         "(git status shows changes to tracked files): commit them first, or "
                         "write elsewhere (--out runs/rl/scores)")  # fmt: skip


def load_reference(path: str | Path = "results/reference_scores.json") -> dict[str, Any]:
    """The committed reference scores (anchors per episode, rows), for scoring an agent.

    Raises
    ------
    ValueError
        The file is missing or of another format (the message names the command that writes
        it).
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: no reference scores; run 'python -m tuners.rl.reference_scores "
                         "--out results' first (or give --reference)")  # fmt: skip
    data = json.loads(read_bounded(p, MAX_DATA_BYTES, "reference scores file"))
    if data.get("format") != "gripper-rl-reference-scores" or data.get("version") != 2:
        raise ValueError(f"{p}: not the RL benchmark's reference scores (version 2); "
                         "regenerate them with python -m tuners.rl.reference_scores")  # fmt: skip
    return data


if __name__ == "__main__":
    sys.exit(main())
