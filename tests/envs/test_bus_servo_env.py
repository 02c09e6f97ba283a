"""GripperBusServo-v0: Gymnasium's and stable-baselines3's checkers, seeds, copies, arguments,
PPO in worker processes, and the environment against the simulation core run independently
(simulate_bus, the evaluation's scenarios, the reward written out with numpy)."""

import copy
import json
import math
import pickle
import warnings

import cloudpickle
import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import passive_env_checker
from gymnasium.utils.env_checker import check_env as gym_check_env
from helpers import BUS_SERVO
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import gripper_env
from gripper_env.evaluation.bus_servo import tracking_goal
from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
from gripper_env.sim.bus_servo import simulate_bus

MADE = "gripper_env:" + BUS_SERVO  # importable in a fresh worker process
JC, JH = 205.0, 55.0  # centre and half-width of the shipped models' jaw range (deg)
DPT = 360.0 / 4096  # deg per encoder tick
VARIANTS = [
    {},
    {"model": "xl330", "reference": "tracking"},
    {"model": "xl430", "residual": "reference", "residual_deg": 10.0},
    {"reference": "grasp"},
    {"object_deg": 190.0, "registers": "lerobot", "control_period_s": 0.010, "episode_s": 2.0},
]


XL_DEADBAND = {"p": 400, "torque_limit": 885, "deadband": 2}  # an XL has no dead-zone register


def action_for(goal_deg):
    return np.array([(goal_deg - JC) / JH], dtype=np.float32)


def rollout(env, n_steps, seed=5, action_seed=0):
    """Observations, rewards, flags and infos under random actions (reset when an episode ends)."""
    rng = np.random.default_rng(action_seed)
    out = [env.reset(seed=seed)[0]]
    for _ in range(n_steps):
        action = rng.uniform(-1.2, 1.2, (1,)).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        out.append(np.append(obs, [reward, terminated, truncated, info["position_deg"]]))
        if terminated or truncated:
            out.append(env.reset()[0])
    return np.concatenate(out)


# ---- registration and checkers -----------------------------------------------------------------


def test_registered_in_env_ids_with_a_time_limit_and_no_vector_entry_point():
    assert BUS_SERVO in gripper_env.ENV_IDS
    assert gripper_env.envs.BUS_HARDWARE_ENV_ID not in gripper_env.ENV_IDS
    spec = gym.spec(BUS_SERVO)
    # the default episode (the 10 s random reference at 20 ms); "grasp"'s 10 s hold is 510
    assert spec.max_episode_steps == 500 and spec.vector_entry_point is None
    env = gym.make(BUS_SERVO)
    assert isinstance(env, gym.wrappers.TimeLimit)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    assert env.observation_space == gym.spaces.Box(-10.0, 10.0, (6,), np.float32)
    assert env.observation_space == gym.make("gripper_env/GripperServo-v0").observation_space
    vec = gym.make_vec(BUS_SERVO, num_envs=2)  # no native form: Gymnasium's SyncVectorEnv
    assert isinstance(vec, gym.vector.SyncVectorEnv)
    vec.reset(seed=0)
    vec.step(np.zeros((2, 1), np.float32))
    vec.close()


@pytest.mark.parametrize("kwargs", [*VARIANTS, {"render_mode": "rgb_array"}])
def test_gymnasium_and_sb3_checkers_pass_on_the_env_as_made(kwargs):
    env = gym.make(BUS_SERVO, **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version")
        gym_check_env(env, skip_render_check="render_mode" not in kwargs)
        sb3_check_env(env, warn=True)
    env.close()


def test_passive_checker_finds_nothing():
    """gym.make's PassiveEnvChecker and the passive checks called directly, warnings as errors."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(BUS_SERVO)
        env.reset(seed=0)
        for _ in range(3):
            env.step(env.action_space.sample())
        raw = gym.make(BUS_SERVO, disable_env_checker=True).unwrapped
        passive_env_checker.check_action_space(raw.action_space)
        passive_env_checker.check_observation_space(raw.observation_space)
        obs, info = passive_env_checker.env_reset_passive_checker(raw, seed=1)
        assert raw.observation_space.contains(obs) and isinstance(info, dict)
        for _ in range(3):
            passive_env_checker.env_step_passive_checker(raw, raw.action_space.sample())
        drawn = gym.make(BUS_SERVO, render_mode="rgb_array", disable_env_checker=True).unwrapped
        drawn.reset(seed=0)
        passive_env_checker.env_render_passive_checker(drawn)


# ---- seeds and copies ----------------------------------------------------------------------------


@pytest.mark.parametrize("kwargs", VARIANTS)
def test_same_seed_same_trajectory(kwargs):
    a = rollout(gym.make(BUS_SERVO, **kwargs), 300, seed=7)
    b = rollout(gym.make(BUS_SERVO, **kwargs), 300, seed=7)
    np.testing.assert_array_equal(a, b)
    if kwargs.get("reference", "random") == "random":  # the others draw nothing
        c = rollout(gym.make(BUS_SERVO, **kwargs), 300, seed=8)
        assert a.shape != c.shape or not np.array_equal(a, c)


COPIERS = {
    "pickle": lambda env: pickle.loads(pickle.dumps(env)),
    "cloudpickle": lambda env: cloudpickle.loads(cloudpickle.dumps(env)),
    "deepcopy": copy.deepcopy,
}


@pytest.mark.parametrize("how", COPIERS)
@pytest.mark.parametrize("kwargs", [{}, {"reference": "grasp"}, {"render_mode": "rgb_array"}])
def test_a_copy_taken_mid_episode_continues_identically(how, kwargs):
    original = gym.make(BUS_SERVO, **kwargs)
    original.reset(seed=9)
    rng = np.random.default_rng(3)
    for _ in range(37):
        original.step(rng.uniform(-1, 1, (1,)).astype(np.float32))
    twin = COPIERS[how](original)
    actions = rng.uniform(-1, 1, (80, 1)).astype(np.float32)
    for action in actions:
        a, b = original.step(action), twin.step(action)
        for x, y in zip(a[:4], b[:4], strict=True):
            np.testing.assert_array_equal(x, y)
        assert a[4] == b[4]
        if a[2] or a[3]:
            break
    # and both are independent working environments afterwards
    np.testing.assert_array_equal(rollout(twin, 60), rollout(original, 60))
    fresh = COPIERS[how](gym.make(BUS_SERVO, **kwargs))
    np.testing.assert_array_equal(rollout(fresh, 60), rollout(gym.make(BUS_SERVO, **kwargs), 60))


# ---- actions and arguments -----------------------------------------------------------------------


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_action_is_refused_naming_the_env_and_the_action(bad):
    env = gym.make(BUS_SERVO)
    env.reset(seed=0)
    env.step(np.array([0.3], np.float32))
    with pytest.raises(ValueError, match=r"GripperBusServo-v0: action must be finite.*(nan|inf)"):
        env.step(np.array([bad], np.float32))
    with pytest.raises(ValueError, match="GripperBusServo-v0: action must be finite"):
        env.step([bad])
    # the refused steps changed nothing
    clean = gym.make(BUS_SERVO)
    clean.reset(seed=0)
    clean.step(np.array([0.3], np.float32))
    good = np.array([-0.25], np.float32)
    for a, b in zip(env.step(good)[:4], clean.step(good)[:4], strict=True):
        np.testing.assert_array_equal(a, b)


def test_malformed_and_out_of_range_actions():
    env = gym.make(BUS_SERVO)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="GripperBusServo-v0"):
        env.step("close")
    results = []
    for action in (np.array([-3.0], np.float32), np.array([-1.0], np.float32), [-3.0], -3.0):
        env = gym.make(BUS_SERVO)
        env.reset(seed=4)
        results.append(env.step(action))
    for obs, reward, *_, info in results[1:]:
        np.testing.assert_array_equal(obs, results[0][0])
        assert reward == results[0][1] and info == results[0][4]
    assert results[0][0][5] == -1.0  # the observation shows the clipped action
    assert results[0][4]["goal_deg"] == pytest.approx(150.0, abs=DPT)  # the closed stop


def test_step_after_the_end_needs_a_reset():
    env = gym.make(BUS_SERVO, episode_s=0.1).unwrapped
    env.reset(seed=0)
    for _ in range(5):
        *_, truncated, _ = env.step(np.zeros(1, np.float32))
    assert truncated
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, np.float32))


@pytest.mark.filterwarnings("ignore:.*render_mode")  # gym.make's own warning, before ours
@pytest.mark.parametrize(
    ("kwargs", "name", "value"),
    [
        ({"model": "sts9999"}, "model", "sts9999"),
        ({"model": 3}, "model", "3"),
        ({"registers": {"p": -1, "torque_limit": 500}}, "registers", "p"),
        ({"registers": {"p": 16, "torque_limit": 500, "gain": 1}}, "registers", "gain"),
        ({"registers": {"p": 300, "torque_limit": 500}}, "registers", "300"),  # STS: 0-254
        ({"registers": {"p": 16, "torque_limit": 5000}}, "registers", "5000"),
        ({"model": "xl330", "registers": XL_DEADBAND}, "registers", "deadband"),
        ({"registers": "community"}, "registers", "community"),
        ({"registers": "missing.json"}, "registers", "missing.json"),
        ({"registers": 32}, "registers", "32"),
        ({"control_period_s": 0.0105}, "control_period_s", "0.0105"),
        ({"control_period_s": 0.0}, "control_period_s", "0.0"),
        ({"control_period_s": "fast"}, "control_period_s", "fast"),
        ({"reference": "step"}, "reference", "step"),
        ({"reference": [240.0, math.nan] * 20}, "reference", "non-finite"),
        ({"reference": [240.0] * 5}, "reference", "5"),
        ({"episode_s": -1.0}, "episode_s", "-1.0"),
        ({"episode_s": 0.001}, "episode_s", "0.001"),
        ({"hold_s": (1.0, 0.5)}, "hold_s", "1.0"),
        ({"hold_s": 0}, "hold_s", "0"),
        ({"object_deg": 100.0}, "object_deg", "100.0"),
        ({"object_deg": 250.0}, "object_deg", "250.0"),  # on the open side of the start
        ({"object_deg": "yes"}, "object_deg", "yes"),
        ({"residual": "pid"}, "residual", "pid"),
        ({"residual": "reference", "residual_deg": 0.0}, "residual_deg", "0.0"),
        ({"overshoot_weight": -1.0}, "overshoot_weight", "-1.0"),
        ({"chatter_weight": math.inf}, "chatter_weight", "inf"),
        ({"force_weight": -0.5}, "force_weight", "-0.5"),
        ({"render_mode": "ascii"}, "render_mode", "ascii"),
    ],
)
def test_bad_arguments_are_refused_in_one_line_naming_the_argument(kwargs, name, value):
    with pytest.raises(ValueError) as excinfo:
        gym.make(BUS_SERVO, **kwargs)
    message = str(excinfo.value)
    assert message.startswith(f"GripperBusServo-v0: argument '{name}'"), message
    assert value in message and "\n" not in message, message


def test_unknown_argument_is_named():
    with pytest.raises(TypeError, match="plant"):
        gym.make(BUS_SERVO, plant="test2")


def test_registers_as_a_set_a_dict_a_name_or_a_tuned_file(tmp_path):
    sts = load_bus_servo("sts3215")
    regs = RegisterSet(p=20, i=2, d=24, torque_limit=700, deadband=1)

    def made(**kwargs):
        return gym.make(BUS_SERVO, **kwargs).unwrapped.settings

    assert made().registers == sts.factory
    assert made(registers=regs).registers == regs
    assert made(registers=regs.model_dump()).registers == regs
    assert made(registers="lerobot").registers == sts.community["lerobot"]
    # a registers file of python -m tuners.bus.tune brings the model it was tuned on
    xl = load_bus_servo("xl430")
    tuned = RegisterSet(p=900, d=3000, torque_limit=700)
    path = tmp_path / "xl430_registers.json"
    path.write_text(json.dumps({"registers": tuned.model_dump(), "model": xl.model_dump()}))
    s = made(registers=str(path))
    assert s.registers == tuned and s.model == xl
    assert made(registers=path, model=xl).registers == tuned
    with pytest.raises(ValueError, match=r"argument 'registers'.*tuned for the xl430"):
        gym.make(BUS_SERVO, registers=str(path), model="sts3215")


# ---- the environment against the core, run independently ---------------------------------------


def test_constant_goal_equals_simulate_bus_sampled_at_the_control_period():
    """A constant goal from the first step is simulate_bus's run of that goal (a model without
    the bus's delay, so that simulate_bus's padding is not in the way); the reward is the
    docstring's formula written out with numpy, against the tuners' tracking scenario."""
    sts = load_bus_servo("sts3215")
    model = sts.with_updates(physics=sts.physics.model_copy(update={"delay_s": 0.0}))
    env = gym.make(BUS_SERVO, model=model, reference="tracking")
    env.reset(seed=0)
    action = np.array([0.5], np.float32)  # 232.5 deg, 2645 ticks
    goal = round((JC + JH * 0.5) / DPT) * DPT
    steps = 200
    positions, rewards = [], []
    for _ in range(steps):
        _, reward, terminated, truncated, info = env.step(action)
        assert info["goal_deg"] == goal and not terminated and not truncated
        positions.append(info["position_deg"])
        rewards.append(reward)
    run = simulate_bus(model, model.factory, np.full(20 * steps + 1, goal), start_deg=240.0)
    y = run.position[0] * DPT  # the encoder at the start of each tick
    np.testing.assert_array_equal(positions, y[20::20][:steps])
    ref = tracking_goal(model)[0][: 20 * steps]
    after = y[1 : 20 * steps + 1].reshape(steps, 20)  # the encoder after each tick
    track = np.abs(ref.reshape(steps, 20) - after).mean(axis=1) / JH
    chatter = np.zeros(steps)
    chatter[0] = 0.1 * abs(goal - round(240.0 / DPT) * DPT) / JH
    # overshoot: past the reference in the direction of its latest move (0 before any)
    direction = np.zeros(20 * steps)
    for k in range(1, 20 * steps):
        step = np.sign(ref[k] - ref[k - 1])
        direction[k] = step if step else direction[k - 1]
    assert set(direction) == {0.0, -1.0, 1.0}  # closing moves, then opening ones
    over = np.maximum(0.0, direction * (after.ravel() - ref)).reshape(steps, 20).mean(axis=1) / JH
    np.testing.assert_allclose(rewards, -(track + over + chatter), rtol=1e-12, atol=1e-12)


def test_the_bus_delay_as_simulate_bus_applies_it():
    """The shipped model (2 ms from a written goal to the loop): the start held for three periods,
    then a constant goal, equals simulate_bus of the same goal per tick."""
    model = load_bus_servo("sts3215")
    assert model.physics.delay_s == 0.002
    env = gym.make(BUS_SERVO, reference="tracking")
    env.reset(seed=0)
    start = round(240.0 / DPT) * DPT
    goal = round(170.0 / DPT) * DPT
    goals = [start] * 3 + [goal] * 60
    positions = []
    for g in goals:
        _, _, _, _, info = env.step(action_for(g))
        assert info["goal_deg"] == g
        positions.append(info["position_deg"])
    run = simulate_bus(model, model.factory, np.repeat([*goals, goal], 20), start_deg=240.0)
    np.testing.assert_array_equal(positions, (run.position[0] * DPT)[20::20][: len(goals)])


@pytest.mark.parametrize("family", ["sts3215", "xl330", "xl430"])
def test_registers_change_the_servo_the_env_runs(family):
    """A quarter of the factory P leaves a wider dead band, as simulate_bus says for each."""
    model = load_bus_servo(family)
    soft = model.factory.model_copy(update={"p": max(model.factory.p // 4, 1)})
    start, goal = round(240.0 / DPT) * DPT, round(236.0 / DPT) * DPT
    goals = [start] + [goal] * 50
    finals = []
    for regs in (model.factory, soft):
        env = gym.make(BUS_SERVO, model=family, registers=regs, reference="tracking")
        env.reset(seed=0)
        for g in goals:
            _, _, _, _, info = env.step(action_for(g))
        run = simulate_bus(model, regs, np.repeat([*goals, goal], 20), start_deg=240.0)
        assert info["position_deg"] == run.position[0, 20 * len(goals)] * DPT
        finals.append(info["position_deg"])
    assert abs(finals[1] - 236.0) >= abs(finals[0] - 236.0)


def test_grasp_holds_an_object_or_trips_the_overload():
    """The tuners' grasp scenario: a goal a few degrees past the object holds it with more than
    20 % of the stall force and no force penalty; the closed stop trips the overload (the
    episode ends, -(100 + steps left))."""
    model = load_bus_servo("sts3215")
    stall_n = model.stall_force_n()
    # the grasp's 10 s hold is 510 steps, beyond the registered TimeLimit (the default episode)
    env = gym.make(BUS_SERVO, reference="grasp", max_episode_steps=510)
    _, info = env.reset(seed=0)
    assert info["object_deg"] == model.jaw.object_deg == 185.0
    rewards = []
    while True:
        _, reward, terminated, truncated, info = env.step(action_for(181.0))
        rewards.append(reward)
        if terminated or truncated:
            break
    assert truncated and not terminated and len(rewards) == 510  # 0.2 s open, 10 s of hold
    assert info["trip"] == "none" and info["force_n"] >= 0.2 * stall_n
    assert 182.0 < info["position_deg"] < 185.0  # pressed into the object, held there
    assert max(rewards[100:]) > -0.05  # no force shortfall, the jaw tracks the object
    # while the jaw closes on the object, the force's shortfall counts
    no_force = gym.make(BUS_SERVO, reference="grasp", force_weight=0.0)
    no_force.reset(seed=0)
    free = [no_force.step(action_for(181.0))[1] for _ in range(40)]
    assert free[:10] == rewards[:10]  # open: nothing asked of the force yet
    assert sum(free) > sum(rewards[:40]) + 1.0

    env.reset(seed=0)
    steps = 0
    while True:
        _, reward, terminated, truncated, info = env.step(action_for(150.0))
        steps += 1
        if terminated or truncated:
            break
    assert terminated and not truncated and info["trip"] == "overload"
    assert 1.5 <= steps * 0.02 <= 3.0  # the STS's 2 s protection time
    assert reward == -(100 + 510 - steps)


def test_residual_zero_action_sends_the_reference():
    env = gym.make(BUS_SERVO, residual="reference", reference="tracking")
    obs, _ = env.reset(seed=0)
    ref = tracking_goal(load_bus_servo("sts3215"))[0]
    for k in range(60):
        r = obs[1] * JH + JC
        obs, _, _, _, info = env.step(np.zeros(1, np.float32))
        assert info["goal_deg"] == round(ref[20 * k] / DPT) * DPT
        assert abs(r - ref[20 * k]) < 1e-4
    assert obs[5] == 0.0


def test_rgb_array_frames_and_human_under_agg():
    env = gym.make(BUS_SERVO, render_mode="rgb_array")
    assert env.metadata["render_fps"] == 50.0
    env.reset(seed=0)
    first = env.render()
    for _ in range(30):
        env.step(env.action_space.sample())
    frame = env.render()
    for img in (first, frame):
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert not np.array_equal(first, frame)  # the episode was drawn
    env.close()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        human = gym.make(BUS_SERVO, render_mode="human", control_period_s=0.04)
        assert human.metadata["render_fps"] == 25.0
        human.reset(seed=0)
        human.step(human.action_space.sample())
        assert human.render() is None
        human.close()


# ---- training ----------------------------------------------------------------------------------


def test_ppo_learns_a_little_in_two_worker_processes():
    """stable-baselines3 PPO on a SubprocVecEnv of two environments made in the workers (by the
    id with its module prefix, as in a fresh process)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    torch.set_num_threads(1)
    gym.make(MADE).reset(seed=0)  # imported and compiled here: forked workers start at once
    venv = make_vec_env(MADE, n_envs=2, seed=0, vec_env_cls=SubprocVecEnv,
                        env_kwargs={"episode_s": 2.0},
                        vec_env_kwargs={"start_method": "fork"})  # fmt: skip
    try:
        model = PPO("MlpPolicy", venv, n_steps=128, batch_size=64, n_epochs=2, seed=0,
                    device="cpu", policy_kwargs={"net_arch": [16, 16]})  # fmt: skip
        model.learn(total_timesteps=512)
        assert model.num_timesteps >= 512
        obs = venv.reset()
        action, _ = model.predict(obs, deterministic=True)
        _, reward, _, _ = venv.step(action)
        assert action.shape == (2, 1) and np.all(np.isfinite(reward))
    finally:
        venv.close()


def test_the_docs_example_runs():
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "envs.md").read_text()
    section = text[text.index("## Bus servos") : text.index("## A bus servo on its bus")]
    (code,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    namespace: dict = {}
    exec(compile(code, "<docs/envs.md>", "exec"), namespace)
    assert namespace["env"].unwrapped.settings.registers.p == 16  # lerobot's
