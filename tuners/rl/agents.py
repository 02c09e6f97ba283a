"""Trained agents that carry what rebuilds their environment, and run on any plant.

An agent folder holds:

* ``model.zip``: the stable-baselines3 model;
* ``vecnormalize.pkl``: the ``VecNormalize`` statistics its observations were normalised with
  (absent if none);
* ``agent.json``: the environment id and the keyword arguments it was trained with (plant(s),
  preset, residual mode, the base PID's gains and options, randomisation), the algorithm, seed
  and budget.

:func:`load_agent` gives an :class:`Agent`, a policy ``obs -> actions`` that applies the
normalisation; :func:`agent_kwargs` rebuilds its environment's arguments for another plant,
preset or profile, so that::

    from tuners.rl.agents import load_agent, agent_kwargs
    from gripper_env.envs.rollout import policy_trajectory
    agent = load_agent("results/rl/controller-test2/seed-0/best")
    kwargs = agent_kwargs(agent, plant="test4")
    traj = policy_trajectory(agent, [100000], env_id=agent.env_id, reference="step", **kwargs)

runs a committed agent on test4 (``python -m tuners.rl play`` does this and prints the metrics).

:func:`load_any` loads any agent the benchmark scores (``python -m tuners.rl evaluate AGENT``):
a stable-baselines3 zip, an rl-zoo3 log folder (one run, or an experiment folder of several),
this project's agent folder, or ``module:callable`` (a function of a batch, ``obs (B, n) ->
actions (B, m)``, or of one observation, ``obs (n,) -> action (m,)``: :func:`batch_policy` tells
them apart; or an object with a stable-baselines3 ``predict``). A bare zip carries no action
interface (how its actions act: residual or absolute, the PID it corrects); it reads one from
``<zip>.interface.json`` beside it, or takes it from ``--interface``.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pickle
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.config import MAX_CONFIG_BYTES, check_input, read_bounded
from gripper_env.io.files import write_atomic, write_json
from gripper_env.model.pid import PIDGains

__all__ = [
    "AGENT_FORMAT",
    "Agent",
    "LoadedAgent",
    "agent_kwargs",
    "batch_policy",
    "load_agent",
    "load_any",
    "one_torch_thread",
    "quiet_logger",
    "reproducible_zip",
    "save_agent",
    "save_model",
]

AGENT_FORMAT = "gripper-agent"

#: The most an agent (its folder's files, a model zip, a normalizer) may hold (bytes): the
#: committed agents take 156 KiB; SB3's MLP policies of a few layers take a few MiB at most.
MAX_AGENT_BYTES = 256 << 20


class Agent:
    """A trained policy with its observation normalisation: ``agent(obs) -> actions``.

    Attributes
    ----------
    model : stable-baselines3 model
    normalizer : VecNormalize or None
    env_id : str
    env_kwargs : dict
        The environment's keyword arguments it was trained with (without the reference).
    base : PIDGains or None
        The PID a residual policy corrects.
    facts : dict
        Algorithm, seed, budget, what it was trained on.
    """

    def __init__(
        self,
        model: Any,
        normalizer: Any,
        env_id: str,
        env_kwargs: dict[str, Any],
        base: PIDGains | None = None,
        facts: dict[str, Any] | None = None,
    ) -> None:
        self.model = model
        self.normalizer = normalizer
        self.env_id = env_id
        self.env_kwargs = dict(env_kwargs)
        self.base = base
        self.facts = dict(facts or {})

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if self.normalizer is not None:
            obs = self.normalizer.normalize_obs(obs)
        return self.model.predict(obs, deterministic=True)[0]


def one_torch_thread() -> None:
    """Run torch on one thread in this process. The policies are small MLPs whose calls cost
    their overhead, not their arithmetic, and torch's default (a thread per core) spins against
    whatever else runs: 1024 robust episodes of a PPO agent beside two training workers took
    66.5 s on two threads, 7.3 s on one."""
    import torch

    torch.set_num_threads(1)


def _json_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    """The environment's arguments as JSON: objects by their name, tuples as lists."""
    out: dict[str, Any] = {}
    for key, value in kwargs.items():
        if hasattr(value, "name") and not isinstance(value, str | int | float):
            value = value.name
        if isinstance(value, tuple):
            value = list(value)
        out[key] = value
    return out


def quiet_logger(model: Any) -> Any:
    """``model`` (a stable-baselines3 algorithm) with a logger that writes nothing.

    Without a logger of its own (no ``tensorboard_log``), every ``learn`` makes an empty
    ``SB3-<date-time>`` folder in the system's temporary directory (``configure(None)``), which
    no one removes: a training command's folders piled up there by the hundred. The values the
    algorithm records are still kept for its callbacks; only no file is written.
    """
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def save_agent(agent: Agent, folder: str | os.PathLike[str], facts: dict[str, Any]) -> Path:
    """Write ``agent`` into ``folder`` (see the module docstring); return the folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_model(agent.model, folder / "model.zip")
    if agent.normalizer is not None:  # VecNormalize.save's pickle, written atomically
        write_atomic(folder / "vecnormalize.pkl", pickle.dumps(agent.normalizer))
    base = agent.base
    write_json(
        folder / "agent.json",
        {
            "format": AGENT_FORMAT,
            "version": 1,
            "env_id": agent.env_id,
            "env_kwargs": _json_kwargs(agent.env_kwargs),
            "base_gains": None if base is None else [base.P, base.I, base.D, base.N],
            "normalized_observations": agent.normalizer is not None,
            **facts,
        },
    )
    return folder


#: What a saved model leaves out: when training started and the episodes' wall times (the
#: monitor's ``t``) - inference needs neither, and they would make every rerun's file differ.
_UNSTABLE_PARAMS = ("start_time", "ep_info_buffer", "ep_success_buffer")


def save_model(model: Any, path: str | os.PathLike[str]) -> Path:
    """``model.save`` whose bytes depend on the training only, not on the process, the clock or
    the machine: without the time-dependent parameters, with the spaces saved without a random
    generator, the memory addresses in the zip's readable ``data`` (``<function ... at
    0x7f...>``) dropped, without ``system_info.txt`` (the machine's OS and library versions:
    the run's provenance sidecar has them; loading does not read it) and entries dated 1980.
    The same training gives the same file on every engine and machine."""
    import io

    import gymnasium as gym

    path = Path(path)
    for name in ("observation_space", "action_space"):  # a space saved with its sampler's state
        space = getattr(model, name)
        if isinstance(space, gym.spaces.Box):
            setattr(model, name, gym.spaces.Box(space.low, space.high, space.shape, space.dtype))
    saved = io.BytesIO()
    model.save(saved, exclude=list(_UNSTABLE_PARAMS))
    return write_atomic(path, reproducible_zip(saved.getvalue()))


def reproducible_zip(data: bytes) -> bytes:
    """A saved model's zip (bytes) without what differs between runs of the same training
    (:func:`save_model`)."""
    import io
    import re
    import zipfile

    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            if info.filename == "system_info.txt":
                continue
            content = src.read(info)
            if info.filename == "data":
                content = re.sub(rb" at 0x[0-9a-f]+>", b">", content)
            fixed = zipfile.ZipInfo(info.filename, date_time=(1980, 1, 1, 0, 0, 0))
            fixed.compress_type = info.compress_type
            fixed.external_attr = info.external_attr
            dst.writestr(fixed, content)
    return out.getvalue()


def load_agent(folder: str | os.PathLike[str]) -> Agent:
    """The agent saved in ``folder``.

    Raises
    ------
    ValueError
        ``folder`` holds no agent (no ``agent.json`` of this format, or no ``model.zip``).
    """
    import json

    folder = Path(folder)
    meta_path = folder / "agent.json"
    if not meta_path.is_file() or not (folder / "model.zip").is_file():
        raise ValueError(f"no agent in {folder}: it needs agent.json and model.zip")
    check_input(folder, MAX_AGENT_BYTES, "agent", folder=True)
    meta = json.loads(read_bounded(meta_path, MAX_CONFIG_BYTES, "agent description"))
    if meta.get("format") != AGENT_FORMAT:
        raise ValueError(f"{meta_path}: not a {AGENT_FORMAT} file")
    from tuners.rl.envs import require_rl

    require_rl()
    from stable_baselines3 import PPO, SAC

    algo: Any = {"ppo": PPO, "sac": SAC}[meta.get("algo", "ppo")]
    model = algo.load(folder / "model.zip", device="cpu")
    normalizer = None
    if meta.get("normalized_observations"):
        with open(folder / "vecnormalize.pkl", "rb") as f:
            normalizer = pickle.load(f)
        normalizer.training = False
    base = meta.get("base_gains")
    facts = {k: v for k, v in meta.items() if k not in ("env_kwargs", "base_gains")}
    return Agent(
        model, normalizer, meta["env_id"], meta["env_kwargs"],
        None if base is None else PIDGains(*base), facts,
    )  # fmt: skip


def agent_kwargs(agent: Agent, **changes: Any) -> dict[str, Any]:
    """The agent's environment arguments with ``changes`` (``plant``, ``disturbance``,
    ``randomize``, ...); a residual PID's gains stay the agent's."""
    kwargs = dict(agent.env_kwargs)
    kwargs.update({k: v for k, v in changes.items() if v is not None})
    for key in ("pid_gains",):
        if key in kwargs and isinstance(kwargs[key], list):
            kwargs[key] = tuple(kwargs[key])
    return kwargs


# ---- any agent: what python -m tuners.rl evaluate scores -----------------------------------

#: stable-baselines3's algorithms by the module of their policy class (a zip does not name its
#: algorithm; its policy's module does, up to PPO and A2C, which act alike).
_ALGO_BY_POLICY = (("sac", "SAC"), ("td3", "TD3"), ("ddpg", "DDPG"), ("dqn", "DQN"))


@dataclass
class LoadedAgent:
    """An agent to score: a policy and what is known about it.

    Attributes
    ----------
    policy : callable
        ``obs (B, n_obs) -> actions (B, n_actions)``, deterministic.
    name : str
        A label (the folder, file or callable).
    kind : str
        ``sb3-zip``, ``rl-zoo3``, ``agent-folder`` or ``callable``.
    env_id : str or None
        The environment it was trained on, when known.
    env_kwargs : dict
        Its environment's arguments, when known (its action map among them).
    facts : dict
        Algorithm, seed, source.
    """

    policy: Any
    name: str
    kind: str
    env_id: str | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    facts: dict[str, Any] = field(default_factory=dict)


def _sb3_class(algo: str | None, zip_path: Path) -> Any:
    """The algorithm class to load ``zip_path`` with: ``algo`` if given, else the one its
    policy class's module names (PPO for the actor-critic policies)."""
    import json
    import zipfile

    import stable_baselines3 as sb3

    if algo is not None:
        name = algo.upper()
        if not hasattr(sb3, name):
            raise ValueError(f"--algo {algo!r}: not a stable-baselines3 algorithm")
        return getattr(sb3, name)
    try:
        with zipfile.ZipFile(zip_path) as z:
            data = json.loads(z.read("data"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{zip_path}: not a stable-baselines3 model zip ({exc})") from None
    module = str((data.get("policy_class") or {}).get("__module__", "")).lower()
    for key, cls in _ALGO_BY_POLICY:
        if f".{key}." in module:
            return getattr(sb3, cls)
    return sb3.PPO


def _normalizer(path: Path | None) -> Any:
    if path is None or not path.is_file():
        return None
    check_input(path, MAX_AGENT_BYTES, "observation normalizer")
    with open(path, "rb") as f:
        norm = pickle.load(f)
    norm.training = False
    return norm


def _zip_agent(path: Path, algo: str | None, normalizer: Path | None = None) -> LoadedAgent:
    check_input(path, MAX_AGENT_BYTES, "stable-baselines3 model", "AGENT")
    cls = _sb3_class(algo, path)
    model = cls.load(path, device="cpu")
    norm = _normalizer(normalizer if normalizer is not None else path.parent / "vecnormalize.pkl")
    agent = Agent(model, norm, "", {})
    facts = {"algo": cls.__name__.lower(), "normalized": norm is not None}
    loaded = LoadedAgent(agent, str(path), "sb3-zip", facts=facts)
    recorded = path.with_suffix(".interface.json")  # how its actions act, if its trainer said
    if recorded.is_file():
        import json

        try:
            loaded.env_kwargs = dict(json.loads(recorded.read_text()))
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{recorded}: not a JSON object of environment arguments ({exc})"
                             ) from None  # fmt: skip
        loaded.facts["interface_file"] = recorded.name
    return loaded


def _zoo_runs(folder: Path) -> list[Path]:
    """The rl-zoo3 run folders in ``folder``: itself (``<env>.zip`` beside ``<env>/args.yml``),
    or its ``<env>_<k>`` sub-folders (an experiment of several runs, sorted by ``k``)."""

    def is_run(p: Path) -> bool:
        return any((z.with_suffix("") / "args.yml").is_file() for z in p.glob("*.zip"))

    if is_run(folder):
        return [folder]
    runs = [p for p in folder.iterdir() if p.is_dir() and is_run(p)]

    def order(p: Path) -> tuple[str, int]:
        stem, _, k = p.name.rpartition("_")
        return (stem, int(k)) if k.isdigit() else (p.name, 0)

    return sorted(runs, key=order)


def _zoo_agent(run: Path, algo: str | None, model: str = "final") -> LoadedAgent:
    """One rl-zoo3 run: its final model (``<env>.zip``), or with ``model="best"`` the
    ``best_model.zip`` rl-zoo3's evaluation callback kept (chosen on rl-zoo3's own evaluation
    environment, not on the task's seeds)."""
    import yaml

    model_zip = next(
        z for z in sorted(run.glob("*.zip")) if (z.with_suffix("") / "args.yml").is_file()
    )
    saved = model_zip.with_suffix("")
    args = dict(yaml.load(read_bounded(saved / "args.yml", MAX_CONFIG_BYTES, "rl-zoo3 args"),
                          Loader=yaml.UnsafeLoader))  # fmt: skip
    config = dict(yaml.load(read_bounded(saved / "config.yml", MAX_CONFIG_BYTES, "rl-zoo3 config"),
                            Loader=yaml.UnsafeLoader)) if (
        saved / "config.yml").is_file() else {}  # fmt: skip
    chosen = model_zip
    if model == "best":
        chosen = run / "best_model.zip"
        if not chosen.is_file():
            raise ValueError(f"--model best: {run} has no best_model.zip (rl-zoo3 writes it "
                             "with --eval-freq > 0); the final model is --model final")  # fmt: skip
    loaded = _zip_agent(chosen, algo or args.get("algo"), saved / "vecnormalize.pkl")
    env_kwargs = dict(config.get("env_kwargs") or {})
    env_kwargs.update(dict(args.get("env_kwargs") or {}))
    loaded.kind, loaded.name = "rl-zoo3", str(run)
    loaded.env_id = str(args.get("env"))
    loaded.env_kwargs = env_kwargs
    loaded.facts.update(seed=args.get("seed"), model=chosen.name, algo=args.get("algo"))
    return loaded


def batch_policy(policy: Any, observation_space: Any, name: str) -> tuple[Any, str]:
    """``policy`` as a batch policy ``obs (B, n) -> actions (B, m)``, and which it was written
    for (``"batch"`` or ``"one observation"``).

    Probed on two different observations of ``observation_space``: a policy that returns one
    action per row of the batch is a batch policy; one that fails on the batch or returns
    something else, but returns one action for one observation, is called row by row.

    Raises
    ------
    ValueError
        It takes neither (one line, with what it returned or raised).
    """
    rng = np.random.default_rng(0)
    low = np.nan_to_num(np.asarray(observation_space.low, dtype=float), neginf=-1.0)
    high = np.nan_to_num(np.asarray(observation_space.high, dtype=float), posinf=1.0)
    probe = rng.uniform(np.maximum(low, -1.0), np.minimum(high, 1.0), (2, *low.shape))
    try:
        out = np.asarray(policy(probe), dtype=float)
        if out.ndim >= 1 and out.shape[0] == 2:
            return policy, "batch"
        said = f"returned shape {out.shape} for a batch of 2"
    except Exception as exc:  # any failure: try one observation
        said = f"raised {type(exc).__name__}: {exc}"
    try:
        one = np.asarray(policy(probe[0]), dtype=float)
    except Exception as exc:
        raise ValueError(f"AGENT {name}: neither a batch policy (obs (B, n) -> actions (B, m): "
                         f"it {said}) nor one for one observation (it raised "
                         f"{type(exc).__name__}: {exc})") from None  # fmt: skip
    if one.ndim > 1:
        raise ValueError(f"AGENT {name}: one observation gave actions of shape {one.shape}; "
                         "expected one action (m,)")  # fmt: skip

    def rows(obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        return np.stack([np.atleast_1d(np.asarray(policy(o), dtype=float)) for o in obs])

    return rows, "one observation"


def _callable_agent(spec: str) -> LoadedAgent:
    module_name, _, attr = spec.rpartition(":")
    try:
        if module_name.endswith(".py"):
            path = Path(module_name)
            if not path.is_file():
                raise ModuleNotFoundError(f"no file {path}")
            mspec = importlib.util.spec_from_file_location(path.stem, path)
            assert mspec is not None and mspec.loader is not None
            module = importlib.util.module_from_spec(mspec)
            sys.modules[path.stem] = module
            mspec.loader.exec_module(module)
        else:
            module = importlib.import_module(module_name)
    except (ImportError, ModuleNotFoundError) as exc:
        raise ValueError(f"AGENT {spec!r}: cannot import {module_name!r} ({exc})") from None
    obj = getattr(module, attr, None)
    if obj is None:
        raise ValueError(f"AGENT {spec!r}: {module_name} has no {attr!r}")
    if hasattr(obj, "predict"):
        model = obj
        policy: Any = lambda obs: model.predict(obs, deterministic=True)[0]  # noqa: E731
    elif callable(obj):
        policy = obj
    else:
        raise ValueError(f"AGENT {spec!r}: {attr} is neither callable nor a model with predict")
    return LoadedAgent(policy, spec, "callable", facts={"callable": spec})


def load_any(spec: str, algo: str | None = None, model: str = "final") -> list[LoadedAgent]:
    """The agent(s) ``spec`` names (module docstring); several for an rl-zoo3 experiment folder
    of several runs (one per training seed).

    Raises
    ------
    ValueError
        ``spec`` names nothing this can load (one line saying what it looked for).
    """
    path = Path(spec)
    if path.is_dir():
        check_input(path, MAX_AGENT_BYTES, "agent", "AGENT", folder=True)
        if (path / "agent.json").is_file():
            agent = load_agent(path)
            return [LoadedAgent(agent, str(path), "agent-folder", agent.env_id,
                                dict(agent.env_kwargs), dict(agent.facts))]  # fmt: skip
        runs = _zoo_runs(path)
        if runs:
            return [_zoo_agent(run, algo, model) for run in runs]
        raise ValueError(f"AGENT {spec}: a folder with neither agent.json (this project's agent) "
                         "nor an rl-zoo3 run (<env>.zip beside <env>/args.yml)")  # fmt: skip
    if path.suffix == ".zip":  # a pipe or a device refused unopened, a large one by its size
        check_input(path, MAX_AGENT_BYTES, "stable-baselines3 model", "AGENT")
        return [_zip_agent(path, algo)]
    if ":" in spec and not path.exists():
        return [_callable_agent(spec)]
    raise ValueError(f"AGENT {spec}: expected a stable-baselines3 .zip, an rl-zoo3 log folder, an "
                     "agent folder (agent.json) or module:callable")  # fmt: skip
