"""Whole episodes of a controller policy on the step-by-step environments, as a Trajectory.

:func:`policy_trajectory` runs a policy (observations -> actions, e.g. a stable-baselines3
model's ``predict``) for one episode per disturbance seed, all seeds in one batch of the
environments' compiled step, and returns a :class:`~gripper_env.sim.Trajectory` with the
reference, the controller output, the measured and the true jaw angle and the core's counters
(saturation, contact with a stop, stall, servo effort): what :func:`~gripper_env.sim.
simulate` returns for a PID, so the policy is scored by the same metrics and objective as every
tuner. The episodes are the ones ``simulate`` runs for those seeds (the same randomised
disturbance draw and sensor noise per seed); the zero action of ``residual="reference"`` is
``simulate``'s open loop (command = reference) and that of ``residual="pid"`` its closed loop.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.control_batch import ControlBatch
from gripper_env.envs.episode import Episode
from gripper_env.envs.gain_schedule import GripperGainScheduleEnv
from gripper_env.envs.servo import GripperServoEnv
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.references import Reference
from gripper_env.sim import Trajectory, sampling_rng

__all__ = ["policy_trajectory"]

_ENVS = {
    "gripper_env/GripperServo-v0": GripperServoEnv,
    "gripper_env/GripperGainSchedule-v0": GripperGainScheduleEnv,
}


def _whole_periods(reference: Reference, n_steps: int) -> Reference:
    """``reference`` cut to its first ``n_steps`` samples (an episode is whole periods)."""
    if n_steps == len(reference):
        return reference
    segments = tuple(
        dataclasses.replace(s, stop=min(s.stop, n_steps))
        for s in reference.segments
        if s.start < n_steps
    )
    return Reference(reference.name, reference.dt_s, reference.values_deg[:n_steps], segments)


def policy_trajectory(
    policy: Callable[[np.ndarray], np.ndarray],
    seeds: int | Sequence[int] | np.ndarray = 0,
    *,
    env_id: str = "gripper_env/GripperServo-v0",
    run_plants: Sequence[int] | None = None,
    run_disturbances: Sequence[Disturbance] | None = None,
    **env_kwargs: Any,
) -> Trajectory:
    """Run ``policy`` for one whole episode per seed and return the trajectories.

    Parameters
    ----------
    policy : callable
        ``policy(obs) -> actions``: observations (B, n_obs) float32 to actions (B, n_actions),
        e.g. ``lambda obs: model.predict(obs, deterministic=True)[0]``. A policy trained with
        ``VecNormalize`` needs its observation normalisation applied first
        (``venv.normalize_obs``).
    seeds : int or sequence of int
        Disturbance seeds, one episode each: the seed of the sensor noise and, with
        ``randomize``, of the disturbance parameters (drawn as
        :func:`~gripper_env.sim.simulate` draws them).
    env_id : str
        ``"gripper_env/GripperServo-v0"`` (with its residual modes) or
        ``"gripper_env/GripperGainSchedule-v0"``.
    run_plants : sequence of int, optional
        Per seed, the index of its plant in the ``plant`` list (default: one plant for all).
    run_disturbances : sequence of Disturbance, optional
        Per seed, its own actual-gripper blocks, used as given (default: the environment's
        ``disturbance``, drawn per seed with ``randomize``).
    **env_kwargs
        The environment's keyword arguments: ``plant`` (one, or several with ``run_plants``), a
        fixed ``reference`` (not ``"random"``), ``disturbance``, ``randomize``, ``residual``,
        ``observe_context``, ...

    Returns
    -------
    Trajectory
        Arrays (B, T) over the episode's whole control periods; ``u`` is the controller's
        output (the command before the servo's own path: the policy's command, the reference
        plus the correction, or the PID's output).
    """
    if env_id not in _ENVS:
        raise ValueError(f"env_id: expected one of {sorted(_ENVS)}, got {env_id!r}")
    observe_context = env_kwargs.pop("observe_context", False)
    env = _ENVS[env_id](observe_context=observe_context, **env_kwargs)
    s = env.settings
    env.close()
    if (len(s.plants) != 1 and run_plants is None) or s.reference is None:
        raise ValueError(
            "policy_trajectory: give one plant (or run_plants) and a fixed reference (a profile "
            "name or file)"
        )
    seed_arr = np.atleast_1d(np.asarray(seeds, dtype=np.int64))
    n = len(seed_arr)
    plant_index = [0] * n if run_plants is None else [int(i) for i in run_plants]
    if run_disturbances is None:
        dists = [
            s.disturbance.sample(sampling_rng(int(seed))) if s.randomize else s.disturbance
            for seed in seed_arr
        ]
    else:
        dists = list(run_disturbances)
    if len(plant_index) != n or len(dists) != n:
        raise ValueError(
            f"policy_trajectory: {n} seeds but {len(plant_index)} run_plants and {len(dists)} "
            "run_disturbances"
        )
    if not all(0 <= i < len(s.plants) for i in plant_index):
        raise ValueError(f"policy_trajectory: run_plants must index the {len(s.plants)} plants")
    longest = max(round(d.sensor.delay_s / s.dt_s) for d in dists)
    batch = ControlBatch(
        s, n, env._mode, bool(observe_context),
        env_kwargs.get("overshoot_weight", 1.0), env_kwargs.get("chatter_weight", 0.1),
        env._residual, min_delay_steps=longest,
    )  # fmt: skip
    episodes = [Episode(plant_index[b], dists[b], s.reference, int(seed_arr[b])) for b in range(n)]
    batch.reset_rows(range(n), episodes)
    n_sub = s.n_sub
    n_steps = int(batch.env[0, K.E_LEN])
    u, y, y_true = (np.full((n, n_steps), np.nan) for _ in range(3))
    out_u = batch.drive if batch.out_u is None else batch.out_u
    for t in range(0, n_steps, n_sub):
        running = batch.env[:, K.E_DONE] == K.DONE_RUNNING
        if not running.any():
            break
        actions = np.asarray(policy(batch.obs.copy()), dtype=np.float64)
        batch.actions[:] = actions.reshape(batch.actions.shape)
        bad = batch.step()[0]
        if bad >= 0:
            raise ValueError(f"policy_trajectory: the policy's action for seed "
                             f"{seed_arr[bad]} is not finite: {actions[bad]!r}")  # fmt: skip
        u[running, t : t + n_sub] = out_u[running]
        y[running, t : t + n_sub] = batch.out_y[running]
        y_true[running, t : t + n_sub] = batch.out_yt[running]
    ref = _whole_periods(s.reference, n_steps)
    sim = batch.sim
    dt = s.dt_s
    contact = sim.contact_steps.copy()
    return Trajectory(
        t=ref.t_s,
        r=np.broadcast_to(ref.values_deg, (n, n_steps)).copy(),
        u=u,
        y=y,
        y_true=y_true,
        stable=~sim.diverged,
        saturated_s=sim.saturated_steps * dt,
        reference=ref,
        closed_loop=True,
        contact_s=contact * dt,
        stall_s=sim.stall_steps * dt,
        force_proxy=np.divide(
            sim.force_sum, contact, out=np.zeros_like(contact), where=contact > 0
        ),
        servo_effort_deg=sim.servo_variation_deg.copy(),
    )
