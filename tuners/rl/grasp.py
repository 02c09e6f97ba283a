"""The grasp scenario for a learned controller: does the policy hold the object?

The admission rule asks every controller to hold the grasp scenario's object
(:class:`gripper_env.evaluation.grasp.GraspScenario`: close on an object at 40 deg, hold 3 s
with at least 1 N, no thermal trip). A PID is checked by
:func:`gripper_env.evaluation.grasp.grasp_admission`; a policy runs the same scenario here,
through its environment's compiled step (as :func:`gripper_env.envs.rollout.policy_trajectory`
runs it), one control period (20 ms) at a time. Each period's increments of the simulation
core's counters give the servo's push (the mean fraction of stall over the period: the command
is held for the period), the contact and the jaw; the push is the motor's current, which the
thermal (I^2 t) model of :mod:`gripper_env.evaluation.grasp` integrates, and the fingertip force
(:func:`~gripper_env.evaluation.grasp.summarize_grasp` decides held, as for a PID). A residual
policy adds up to ``residual_deg`` to its PID's held command: 10 deg past the object is a full
stall, so a policy that keeps correcting during the hold trips the servo where its PID alone
would not.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from gripper_env.evaluation.grasp import (
    STALL_TORQUE_NM,
    GraspScenario,
    summarize_grasp,
    thermal_overload_at,
    thermal_state,
)
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.plants import Plant
from gripper_env.sim import sampling_rng

__all__ = ["policy_grasp"]


def policy_grasp(
    policy: Callable[[np.ndarray], np.ndarray],
    env_kwargs: dict[str, Any],
    plant: Plant,
    disturbance: Disturbance,
    seeds: Sequence[int] | np.ndarray,
    *,
    scenario: GraspScenario | None = None,
    randomize: bool = True,
) -> dict[str, Any]:
    """Run the grasp scenario with ``policy`` on ``plant`` under ``disturbance`` (with the
    scenario's object) once per seed.

    Returns
    -------
    dict
        ``held`` (per seed), ``lost`` (the fraction not held), ``reason`` (what failed first on
        the worst seed: ``diverged``, ``overload``, ``force``; ``""`` if every one held),
        ``peak_heat`` and ``min_force_n`` (per seed).
    """
    from gripper_env.envs import kernels as K
    from gripper_env.envs.control_batch import ControlBatch
    from gripper_env.envs.episode import Episode
    from gripper_env.envs.servo import GripperServoEnv

    sc = scenario or GraspScenario()
    ref = sc.reference(plant.dt_s)
    dist = disturbance.with_overrides({"mechanics": {"object_contact_deg": sc.object_deg}})
    ranges = {k: v for k, v in dist.randomize.items() if k != "mechanics.object_contact_deg"}
    dist = dist.model_copy(update={"randomize": ranges})
    seed_arr = np.atleast_1d(np.asarray(seeds, dtype=np.int64))
    dists = [dist.sample(sampling_rng(int(s))) if randomize else dist for s in seed_arr]
    kwargs = dict(env_kwargs, plant=plant, reference=ref, disturbance=dist, randomize=False)
    kwargs.pop("observe_context", None)
    env = GripperServoEnv(**kwargs)
    s = env.settings
    env.close()
    n = len(seed_arr)
    longest = max(round(d.sensor.delay_s / s.dt_s) for d in dists)
    batch = ControlBatch(
        s, n, env._mode, False, kwargs.get("overshoot_weight", 1.0),
        kwargs.get("chatter_weight", 0.1), env._residual, min_delay_steps=longest,
    )  # fmt: skip
    batch.reset_rows(range(n), [Episode(0, dists[b], ref, int(seed_arr[b])) for b in range(n)])
    n_sub = s.n_sub
    n_steps = int(batch.env[0, K.E_LEN])
    periods = n_steps // n_sub
    sim = batch.sim
    push, touch, jaw = (np.zeros((n, periods)) for _ in range(3))
    force_before, contact_before = sim.force_sum.copy(), sim.contact_steps.copy()
    for k in range(periods):
        actions = np.asarray(policy(batch.obs.copy()), dtype=np.float64)
        batch.actions[:] = actions.reshape(batch.actions.shape)
        batch.step()
        force, contact = sim.force_sum.copy(), sim.contact_steps.copy()
        push[:, k] = np.round(force - force_before, 12) / n_sub
        touch[:, k] = contact - contact_before
        jaw[:, k] = batch.out_yt[:, -1]
        force_before, contact_before = force, contact
    # periods from the close command; the object is on the closed side of the jaw's travel
    t = (np.arange(periods) * n_sub - ref.segments[0].start) * s.dt_s
    on_object = (touch > 0) & (jaw <= 0.5 * (sc.open_deg + (sc.object_deg or 0.0)))
    stall_force = STALL_TORQUE_NM / sc.finger_lever_m
    after = t >= -1e-9
    lo, hi = sc.hold_window_s
    hold = (t >= lo - 1e-9) & (t < hi - 1e-9)
    held, heat, least, reasons = [], [], [], []
    stable = ~np.asarray(sim.diverged, bool)
    for b in range(n):
        trip = thermal_overload_at(t[after], push[b, after])
        peak = float(np.max(thermal_state(t[after], push[b, after]), initial=0.0))
        force_n = np.where(on_object[b], push[b], 0.0) * stall_force
        one = summarize_grasp(t, force_n, on_object[b], sc, stall_force=stall_force,
                              overload_at_s=[trip], gripper="", controller="",
                              valid=stable[b : b + 1], peak_heat=[peak])  # fmt: skip
        held.append(bool(one.held))
        heat.append(peak)
        least.append(float(np.min(force_n[hold])))
        reasons.append("" if one.held else "diverged" if not stable[b]
                       else "overload" if trip is not None else "force")  # fmt: skip
    worst = next((r for r in ("diverged", "overload", "force") if r in reasons), "")
    return {
        "held": held,
        "lost": 1.0 - float(np.mean(held)),
        "reason": worst,
        "peak_heat": heat,
        "min_force_n": least,
        "seeds": [int(x) for x in seed_arr],
    }
