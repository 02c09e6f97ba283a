"""Score any agent on a task of the RL benchmark (``python -m tuners.rl evaluate AGENT --task T``).

The agent (:func:`tuners.rl.agents.load_any`: a stable-baselines3 zip, an rl-zoo3 log folder,
this project's agent folder, or ``module:callable``) runs the task's fixed evaluation set; it is
scored against the task's anchors from the committed reference scores
(``results/reference_scores.json``, per episode) and judged by the task's verdict
(:mod:`tuners.rl.judge`). One run gives its score with the 95 % interval over the evaluation
episodes; several runs (an rl-zoo3 experiment folder, one run per seed) give the IQM of their
scores with the stratified-bootstrap interval over the runs, as the reference rows have.

The result is one JSON row (:data:`ROW_FORMAT`) with the agent, the task, the score, every run's
returns, objective's cost, constraint cost, measured margins and verdict: what
:mod:`tuners.rl.leaderboard` ranks. Its provenance (the commit, whether the tree had changes, the
library versions, Python, the machine, the date, the command) is the row's sidecar,
``<name>.provenance.json`` beside it (:func:`gripper_env.io.files.collect_provenance`), so a
rerun with the same numbers leaves the row unchanged.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tuners.rl.agents import LoadedAgent, load_any
from tuners.rl.reference_scores import load_reference
from tuners.rl.scores import stratified_bootstrap_ci
from tuners.rl.suite import Task, task

__all__ = ["ROW_FORMAT", "evaluate_agent", "print_row", "row_path"]

ROW_FORMAT = "gripper-rl-row"


def _interface(t: Task, agent: LoadedAgent) -> tuple[dict[str, Any], list[str]]:
    """The agent's arguments the task lets it bring (its action map, the PID it corrects), and
    notes on those it does not (the task's own are used)."""
    iface, notes = {}, []
    for key, value in agent.env_kwargs.items():
        if key in t.interface:
            iface[key] = tuple(value) if isinstance(value, list) and key in (
                "pid_gains", "gain_max", "gain_center") else value  # fmt: skip
        elif t.train_kwargs.get(key, value) != value or key not in t.train_kwargs:
            notes.append(f"{key}={value!r} (trained with) replaced by the task's")
    if agent.env_id and agent.env_id != t.env_id:
        notes.append(f"trained on {agent.env_id}; evaluated on {t.env_id}")
    return iface, notes


def _check_spaces(t: Task, agent: LoadedAgent, iface: dict[str, Any]) -> None:
    """An SB3 agent's spaces against the task's environment (one line if they differ)."""
    import gymnasium as gym

    model = getattr(agent.policy, "model", None)
    if model is None:
        return
    env = gym.make(t.env_id, **t.kwargs_with(iface))
    obs, act = env.observation_space.shape, env.action_space.shape
    env.close()
    if model.observation_space.shape != obs or model.action_space.shape != act:
        raise ValueError(
            f"AGENT {agent.name}: it observes {model.observation_space.shape} and acts "
            f"{model.action_space.shape}, task {t.name} ({t.env_id}) gives {obs} and takes {act}"
        )


def _batch_callable(t: Task, agent: LoadedAgent, iface: dict[str, Any]) -> tuple[Any, str]:
    """A callable agent as a batch policy, probed on the task's observation space."""
    import gymnasium as gym

    from tuners.rl.agents import batch_policy

    env = gym.make(t.env_id, **t.kwargs_with(iface))
    space = env.observation_space
    env.close()
    return batch_policy(agent.policy, space, agent.name)


def _subset(t: Task, anchors: dict[str, Any], episodes: int | None) -> tuple[Task, dict]:
    short = t.first(episodes)
    return short, {k: list(v[: short.episodes]) for k, v in anchors.items()}


def evaluate_agent(
    spec: str,
    task_name: str,
    *,
    reference: str | Path = "results/reference_scores.json",
    algo: str | None = None,
    name: str | None = None,
    episodes: int | None = None,
    margins: bool = True,
    interface: dict[str, Any] | None = None,
    model: str = "final",
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Score the agent(s) ``spec`` on ``task_name``; the row (module docstring).

    Parameters
    ----------
    spec : str
        The agent (see :func:`tuners.rl.agents.load_any`).
    task_name : str
        A task of ``configs/rl_zoo/tasks.yaml``.
    reference : path
        The reference scores with the task's anchors.
    algo : str, optional
        The stable-baselines3 algorithm of a bare zip (default: read from the zip).
    name : str, optional
        The row's label (default: the agent's).
    episodes : int, optional
        Only the first ``episodes`` of the evaluation set (a quick look: the published scores
        use the whole set).
    margins : bool
        Measure the controller's margins (the ``margin`` verdict needs them).
    interface : dict, optional
        The agent's action interface (the task's ``interface`` arguments it was trained with;
        ``{}``: the task's own), over what the agent records. A bare zip records none and is
        refused without it (the same weights score -421.9 or 0.3 on the servo task as their
        actions are read as absolute or residual).
    model : str
        An rl-zoo3 run's ``final`` model, or the ``best`` one its evaluation callback kept.
    """
    from tuners.rl.agents import one_torch_thread
    from tuners.rl.judge import judge_policy

    one_torch_thread()
    t = task(task_name)
    ref = load_reference(reference)
    if task_name not in ref["tasks"]:
        raise ValueError(f"{reference}: no anchors for task {task_name}; regenerate with "
                         f"python -m tuners.rl.reference_scores --tasks {task_name}")  # fmt: skip
    entry = ref["tasks"][task_name]
    anchors = entry["anchors"]
    if len(anchors["trivial"]) != t.episodes:
        raise ValueError(f"{reference}: task {task_name}'s anchors hold {len(anchors['trivial'])} "
                         f"episodes, the task {t.episodes}; regenerate them")  # fmt: skip
    t, anchors = _subset(t, anchors, episodes)
    agents = load_any(spec, algo, model)
    runs = []
    for k, agent in enumerate(agents):
        if interface is not None:
            agent.env_kwargs = {**agent.env_kwargs, **interface}
        elif agent.kind == "sb3-zip" and "interface_file" not in agent.facts and t.interface:
            raise ValueError(
                f"AGENT {agent.name}: a bare stable-baselines3 zip does not say how its actions "
                f"act on task {t.name} ({', '.join(t.interface)}): pass --interface KEY=VALUE "
                "as it was trained (--interface task: the task's own), or write them as JSON to "
                f"{Path(agent.name).with_suffix('.interface.json').name} beside it"
            )
        iface, notes = _interface(t, agent)
        _check_spaces(t, agent, iface)
        if agent.kind == "callable":
            agent.policy, written = _batch_callable(t, agent, iface)
            per_row = ": called once per observation" if written != "batch" else ""
            notes.append(f"{agent.name} takes {written}{per_row}")
        if agent.kind == "rl-zoo3":
            notes.append(f"scoring rl-zoo3's {model} model ({agent.facts.get('model')})"
                         + ("; --model best scores best_model.zip, which rl-zoo3 chose on its "
                            "own evaluation environment" if model == "final" else ""))  # fmt: skip
        for note in notes:
            log(f"note: {note}")
        log(f"run {k + 1}/{len(agents)}: {agent.name} on {t.name} ({t.episodes} episodes)")
        try:
            row = judge_policy(t, agent.policy, anchors, iface, margins=margins)
        except (TypeError, IndexError) as exc:  # a callable that does not fit the task
            raise ValueError(f"AGENT {agent.name}: its actions do not fit task {t.name} "
                             f"({t.env_id}): {exc}") from None  # fmt: skip
        row.update(run=agent.name, kind=agent.kind, facts=_plain(agent.facts),
                   interface=_plain(iface))  # fmt: skip
        runs.append(row)
    scores = np.array([r["score"] for r in runs])
    if len(runs) > 1:
        point, lo, hi = stratified_bootstrap_ci(scores)
        how = f"IQM of {len(runs)} runs, stratified-bootstrap 95 % interval over the runs"
    else:
        point, (lo, hi) = float(scores[0]), runs[0]["score_interval_episodes"]
        how = "95 % interval over the evaluation episodes (paired with the anchors)"
    label = name or _label(spec)
    return {
        "format": ROW_FORMAT,
        "version": 1,
        "task": task_name,
        "env_id": t.env_id,
        "name": label,
        "agent": spec,
        "kind": agents[0].kind,
        "episodes": t.episodes,
        "complete": t.episodes == task(task_name).episodes,
        "score": point,
        "interval": [lo, hi],
        "interval_kind": how,
        "admitted": all(r["admitted"] for r in runs),
        "admitted_runs": sum(bool(r["admitted"]) for r in runs),
        "verdict": "; ".join(sorted({r["verdict"] for r in runs})),
        "anchors": {
            "trivial": float(np.mean(anchors["trivial"])),
            "limit": float(np.mean(anchors["limit"])),
            "limit_kind": t.limit,
            "best_pid": entry["pid"]["score"],
        },
        "runs": runs,
    }


def _label(spec: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.+-]+", "_", spec.strip("/").replace("/", "-"))[-80:]


def _plain(d: dict[str, Any]) -> dict[str, Any]:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


def row_path(row: dict[str, Any], out: Path | None) -> Path:
    """Where a row goes: ``out`` if it names a ``.json`` file, else ``<out>/<task>/<name>.json``
    (default ``runs/rl/evaluate``)."""
    if out is not None and out.suffix == ".json":
        return out
    folder = (out or Path("runs/rl/evaluate")) / row["task"]
    return folder / f"{row['name']}.json"


def print_row(row: dict[str, Any]) -> None:
    """What a user reads: score and interval, cost, margin, verdict."""
    a = row["anchors"]
    lo, hi = row["interval"]
    print(f"{row['name']} on task {row['task']} ({row['env_id']}, {row['episodes']} evaluation "
          f"episodes{'' if row['complete'] else ', a subset: not a published score'})")  # fmt: skip
    print(
        f"  score {row['score']:.1f} [{lo:.1f}, {hi:.1f}] ({row['interval_kind']}); 0 = command "
        f"= reference, 100 = the limit ({a['limit_kind']}), best PID {a['best_pid']:.1f}"
    )
    for r in row["runs"]:
        prefix = f"  {Path(r['run']).name}: " if len(row["runs"]) > 1 else "  "
        print(f"{prefix}return {r['return_mean']:.4g} ± {r['return_sd']:.2g} (trivial "
              f"{a['trivial']:.4g}, limit {a['limit']:.4g}); score {r['score']:.1f}, eval SE "
              f"{r['score_se']:.2f}")  # fmt: skip
        if r.get("objective_cost"):
            print(f"{prefix}objective's cost: " + ", ".join(
                f"{p} {c:.4g}" for p, c in r["objective_cost"].items()))  # fmt: skip
        if r.get("constraint_cost"):
            print(f"{prefix}constraint cost per episode: " + ", ".join(
                f"{k} {v:.3g}" for k, v in r["constraint_cost"].items()))  # fmt: skip
        if r.get("margins"):
            print(f"{prefix}measured gain margin: " + ", ".join(
                f"{p} {_db(m['gain_margin_db'])}" for p, m in r["margins"].items()))  # fmt: skip
        if "held_fraction" in r:
            print(f"{prefix}held {100 * r['held_fraction']:.0f} %, tripped "
                  f"{100 * r['trip_fraction']:.0f} %")  # fmt: skip
        print(f"{prefix}{'admitted' if r['admitted'] else 'NOT admitted'}: {r['verdict']}")


def _db(x: float | None) -> str:
    return "none up to 40 dB" if x is None or not math.isfinite(x) else f"{x:.1f} dB"
