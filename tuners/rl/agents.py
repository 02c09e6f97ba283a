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
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.files import write_atomic, write_json
from gripper_env.model.pid import PIDGains

__all__ = [
    "AGENT_FORMAT",
    "Agent",
    "agent_kwargs",
    "load_agent",
    "reproducible_zip",
    "save_agent",
    "save_model",
]

AGENT_FORMAT = "gripper-agent"


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
    meta = json.loads(meta_path.read_text())
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
