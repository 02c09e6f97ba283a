"""Registration, time limits, spaces and the documentation of each environment."""

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from helpers import (
    BENCHMARK_IDS,
    BUS_GRASP,
    BUS_SERVO,
    ENV_IDS,
    GAIN_SCHEDULE,
    GRASP,
    PID_TUNE,
    PID_TUNE_RELATIVE,
    ROBUST,
    SERVO,
)

import gripper_env

WORKTREE = Path(__file__).resolve().parents[2]


SO101_JOINT = "gripper_env/SO101Joint-v0"


def test_ids_registered_with_time_limits():
    assert set(gripper_env.ENV_IDS) == {*ENV_IDS, BUS_SERVO, SO101_JOINT, *BENCHMARK_IDS}
    # each TimeLimit is its default episode's length: 20 s, 10 s (bus: 500; robust: 500), the
    # grasp scenarios' 4.5 s and 4.2 s at the 20 ms control period
    limits = {SERVO: 1000, PID_TUNE: None, GAIN_SCHEDULE: 1000, BUS_SERVO: 500,
              PID_TUNE_RELATIVE: None, ROBUST: 500, GRASP: 225, BUS_GRASP: 210,
              SO101_JOINT: 500}  # fmt: skip
    no_vector = {BUS_SERVO, GRASP, BUS_GRASP, SO101_JOINT}
    for env_id, limit in limits.items():
        spec = gym.spec(env_id)
        assert spec.max_episode_steps == limit
        # the bus servo and the grasp ids have no native vector form (gym.make_vec makes a
        # SyncVectorEnv)
        assert (spec.vector_entry_point is None) == (env_id in no_vector)
        env = gym.make(env_id)
        assert isinstance(env, gym.wrappers.TimeLimit) == (limit is not None)
        env.close()


def test_pid_tune_episode_ends_terminated_not_truncated():
    """One step is a whole episode: terminated, never truncated (single and vector)."""
    env = gym.make(PID_TUNE)
    env.reset(seed=0)
    _, _, terminated, truncated, _ = env.step(np.zeros(3, np.float32))
    assert terminated is True and truncated is False
    envs = gym.make_vec(PID_TUNE, num_envs=2, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    _, _, terminated, truncated, _ = envs.step(np.zeros((2, 3), np.float32))
    assert terminated.all() and not truncated.any()


def test_make_without_prior_import_in_fresh_interpreter():
    code = (
        "import gymnasium as gym\n"
        "for i in ('GripperServo-v0', 'GripperPIDTune-v0', 'GripperGainSchedule-v0',\n"
        "          'GripperBusServo-v0', 'GripperPIDTuneRelative-v0', 'GripperServoRobust-v0',\n"
        "          'GripperGrasp-v0', 'GripperBusGrasp-v0'):\n"
        "    env = gym.make(f'gripper_env:gripper_env/{i}')\n"
        "    env.reset(seed=0)\n"
        "    print(env.spec.id, env.spec.max_episode_steps)\n"
        "v = gym.make_vec('gripper_env:gripper_env/GripperServo-v0', num_envs=2,\n"
        "                 vectorization_mode='vector_entry_point')\n"
        "print(type(v).__name__)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=WORKTREE, capture_output=True, text=True, check=True
    )
    assert "gripper_env/GripperServo-v0 1000" in out.stdout
    assert "gripper_env/GripperPIDTune-v0 None" in out.stdout
    assert "gripper_env/GripperBusServo-v0 500" in out.stdout
    assert "gripper_env/GripperGrasp-v0 225" in out.stdout
    assert "GripperServoVectorEnv" in out.stdout


@pytest.mark.parametrize(
    ("env_id", "n_act", "n_obs", "n_obs_ctx"),
    [(SERVO, 1, 6, 24), (GAIN_SCHEDULE, 3, 9, 27), (PID_TUNE, 3, 18, 18)],
)
def test_spaces(env_id, n_act, n_obs, n_obs_ctx):
    env = gym.make(env_id)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (n_act,), np.float32)
    assert env.observation_space.shape == (n_obs,)
    assert env.observation_space.dtype == np.float32
    assert np.all(np.isfinite(env.observation_space.low))
    if env_id != PID_TUNE:
        ctx = gym.make(env_id, observe_context=True)
        assert ctx.observation_space.shape == (n_obs_ctx,)


@pytest.mark.parametrize("env_id", [*ENV_IDS, BUS_SERVO])
def test_docstring_has_gymnasium_sections(env_id):
    doc = type(gym.make(env_id).unwrapped).__doc__
    for section in (
        "## Description",
        "## Action Space",
        "## Observation Space",
        "## Rewards",
        "## Starting State",
        "## Episode End",
        "## Arguments",
        "gym.make(",
        "## Version History",
    ):
        assert section in doc, section
