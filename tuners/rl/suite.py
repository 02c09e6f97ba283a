"""The RL benchmark's tasks: what an agent trains on, the fixed set it is evaluated on, and the
anchors of its score.

A :class:`Task` is one entry of ``configs/rl_zoo/tasks.yaml`` (that file says what each key
means) with its rl-zoo3 recipes, ``configs/rl_zoo/tasks/<task>-ppo.yml`` and ``-sac.yml``, whose
``env_kwargs`` are the training arguments. :func:`load_tasks` reads and checks them;
:func:`task` gives one by name, with a one-line error that lists the names.

The evaluation set is fixed: episode ``i`` is the one the task's environment draws at
``reset(seed=EVAL_SEED + i)`` (a random profile, the randomised gripper, a plant), the same for
every agent, so the anchors are exact constants on it and every score is paired with them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

from gripper_env.io.config import CONFIG_DIR, ConfigError, load_yaml

__all__ = [
    "ALGOS",
    "EVAL_SEED",
    "SELECTION_EPISODES",
    "SELECTION_SEED",
    "Task",
    "load_tasks",
    "recipe",
    "task",
]

#: The evaluation episodes are ``reset(seed=EVAL_SEED + i)``.
EVAL_SEED = 100_000
#: The best PID is chosen on ``SELECTION_EPISODES`` episodes ``reset(seed=SELECTION_SEED + i)``
#: of the training arguments (disjoint from the evaluation set).
SELECTION_SEED = 200_000
SELECTION_EPISODES = 32
#: The reference rows' algorithms.
ALGOS = ("ppo", "sac")

_LIMITS = ("reward-lp", "objective-lp", "oracle")
_VERDICTS = ("margin", "feasible", "held")
_KEYS = {"about", "env_id", "hard", "evaluate", "episodes", "limit", "trivial", "pid",
         "verdict", "interface", "seeds"}  # fmt: skip
#: Keys a task may leave out.
_OPTIONAL = {"limit_episodes"}


@dataclass(frozen=True)
class Task:
    """One task of the benchmark (``configs/rl_zoo/tasks.yaml``).

    Attributes
    ----------
    name : str
    about : str
        One line: what the agent does and why a PID falls short.
    env_id : str
        The registered environment.
    train_kwargs : dict
        The training arguments (the recipes' ``env_kwargs``).
    eval_overrides : dict
        What changes for the evaluation (``generalisation``: ``plant: test4``).
    hard : bool
        One of the tasks where a PID is structurally short.
    episodes : int
        Size of the evaluation set (the trivial policy and every policy run all of it).
    limit, trivial, verdict : str
        The 100 and the 0 of the scale; how an agent is admitted.
    pid : dict
        Where the best-PID row's candidates come from.
    interface : tuple of str
        Arguments an agent may bring (its action map, the PID it corrects).
    timesteps, seeds : dict
        Per algorithm, the reference rows' budget per seed and training seeds.
    limit_episodes : int
        The limit is computed on the first ``limit_episodes`` episodes of the set (its linear
        programs take seconds each; the first episodes are a simple random sample of the set,
        their mean an estimate of the set's with the standard error the reference scores
        publish); ``0``: on all of them.
    """

    name: str
    about: str
    env_id: str
    train_kwargs: dict[str, Any]
    eval_overrides: dict[str, Any]
    hard: bool
    episodes: int
    limit: str
    trivial: str
    verdict: str
    pid: dict[str, Any]
    interface: tuple[str, ...]
    timesteps: dict[str, int] = field(default_factory=dict)
    seeds: dict[str, int] = field(default_factory=dict)
    limit_episodes: int = 0

    @property
    def eval_kwargs(self) -> dict[str, Any]:
        """The evaluation environment's arguments."""
        return {**self.train_kwargs, **self.eval_overrides}

    @property
    def eval_seeds(self) -> list[int]:
        """The evaluation set: one ``reset`` seed per episode."""
        return [EVAL_SEED + i for i in range(self.episodes)]

    @property
    def limit_seeds(self) -> list[int]:
        """The episodes the limit is computed on: the first :attr:`limit_episodes` of the set."""
        n = self.limit_episodes or self.episodes
        return self.eval_seeds[: min(n, self.episodes)]

    @property
    def selection_seeds(self) -> list[int]:
        """The best PID's selection episodes (training arguments; fewer for a set cut short)."""
        return [SELECTION_SEED + i for i in range(min(SELECTION_EPISODES, self.episodes))]

    def first(self, episodes: int | None) -> Task:
        """The task on the first ``episodes`` of its evaluation set (a quick look; ``None``: the
        whole set)."""
        import dataclasses

        if episodes is None:
            return self
        if not 2 <= episodes <= self.episodes:
            raise ValueError(f"--episodes must be 2 to {self.episodes} (task {self.name}'s "
                             f"set), got {episodes}")  # fmt: skip
        limit = min(self.limit_episodes, episodes) if self.limit_episodes else 0
        return dataclasses.replace(self, episodes=episodes, limit_episodes=limit)

    @property
    def family(self) -> str:
        """``tracking`` (the servo's reward, an LP limit), ``pid-tune`` or ``grasp``."""
        if self.limit == "reward-lp":
            return "tracking"
        return "pid-tune" if self.limit == "objective-lp" else "grasp"

    def recipe_file(self, algo: str) -> Any:
        """The rl-zoo3 recipe of ``algo`` (a path inside the shipped configurations)."""
        return CONFIG_DIR.joinpath("rl_zoo", "tasks", f"{self.name}-{algo}.yml")

    def kwargs_with(self, interface: dict[str, Any] | None, *, evaluate: bool = True) -> dict:
        """The environment's arguments with an agent's ``interface`` arguments; any other key
        an agent brings is refused (it would change the task)."""
        base = self.eval_kwargs if evaluate else dict(self.train_kwargs)
        extra = dict(interface or {})
        bad = sorted(set(extra) - set(self.interface))
        if bad:
            raise ValueError(
                f"task {self.name}: an agent may set {', '.join(self.interface) or 'nothing'} "
                f"of the environment, not {', '.join(bad)} (that would change the task)"
            )
        return {**base, **extra}


def recipe(task_name: str, algo: str) -> dict[str, Any]:
    """The rl-zoo3 hyperparameters of ``task_name`` for ``algo``
    (``configs/rl_zoo/tasks/<task>-<algo>.yml``), as a dict with ``env_id``."""
    import yaml

    path = CONFIG_DIR.joinpath("rl_zoo", "tasks", f"{task_name}-{algo}.yml")
    try:
        data = yaml.load(path.read_text(), Loader=yaml.UnsafeLoader)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no {algo} recipe for task {task_name}") from None
    if not isinstance(data, dict) or len(data) != 1:
        raise ConfigError(f"{path}: expected one environment id with its hyperparameters")
    env_id, params = next(iter(data.items()))
    return {"env_id": env_id, **dict(params)}


@functools.cache
def load_tasks() -> dict[str, Task]:
    """Every task of ``configs/rl_zoo/tasks.yaml``, in the file's order (checked)."""
    path = CONFIG_DIR / "rl_zoo" / "tasks.yaml"
    data = load_yaml(path)
    tasks = {}
    for name, entry in data.items():
        where = f"{path}: task {name}"
        if not isinstance(entry, dict) or not _KEYS <= set(entry) <= _KEYS | _OPTIONAL:
            missing = _KEYS - set(entry or {})
            extra = set(entry or {}) - _KEYS - _OPTIONAL
            raise ConfigError(f"{where}: keys {sorted(missing)} missing, {sorted(extra)} unknown")
        if entry["limit"] not in _LIMITS or entry["verdict"] not in _VERDICTS:
            raise ConfigError(f"{where}: limit must be one of {_LIMITS}, verdict one of "
                              f"{_VERDICTS}")  # fmt: skip
        recipes = {algo: recipe(name, algo) for algo in ALGOS}
        interface = tuple(entry["interface"])
        # the recipes' env_kwargs: the task's training arguments, plus the agent's interface
        kwargs = [{k: v for k, v in (r.get("env_kwargs") or {}).items() if k not in interface}
                  for r in recipes.values()]  # fmt: skip
        ids = {r["env_id"] for r in recipes.values()}
        if ids != {entry["env_id"]} or any(k != kwargs[0] for k in kwargs):
            raise ConfigError(f"{where}: its recipes must name {entry['env_id']} with the same "
                              "training arguments (env_kwargs beyond the interface)")  # fmt: skip
        if not (isinstance(entry["episodes"], int) and entry["episodes"] >= 2):
            raise ConfigError(f"{where}: episodes must be an int >= 2")
        limit_episodes = entry.get("limit_episodes", 0)
        if not (isinstance(limit_episodes, int) and (limit_episodes == 0 or 2 <= limit_episodes
                                                     <= entry["episodes"])):  # fmt: skip
            raise ConfigError(f"{where}: limit_episodes must be an int from 2 to episodes "
                              f"({entry['episodes']}), or 0 for all of them")  # fmt: skip
        tasks[name] = Task(
            name=name, about=str(entry["about"]), env_id=str(entry["env_id"]),
            train_kwargs=kwargs[0], eval_overrides=dict(entry["evaluate"] or {}),
            hard=bool(entry["hard"]), episodes=int(entry["episodes"]), limit=entry["limit"],
            trivial=str(entry["trivial"]), verdict=entry["verdict"], pid=dict(entry["pid"]),
            interface=interface,
            timesteps={a: int(r["n_timesteps"]) for a, r in recipes.items()},
            seeds={a: int(v) for a, v in entry["seeds"].items()},
            limit_episodes=0 if limit_episodes == entry["episodes"] else limit_episodes,
        )  # fmt: skip
    return tasks


def task(name: str) -> Task:
    """The task ``name``.

    Raises
    ------
    ValueError
        No such task (the message lists them).
    """
    tasks = load_tasks()
    if name not in tasks:
        raise ValueError(f"--task {name!r}: no such task; choose from {', '.join(tasks)}")
    return tasks[name]
