"""Action checks, clipping, and keyword arguments that fail at construction naming themselves."""

import gymnasium as gym
import numpy as np
import pytest
from helpers import ENV_IDS, GAIN_SCHEDULE, PID_TUNE, SERVO

import gripper_env  # noqa: F401


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_action_raises(env_id, bad):
    env = gym.make(env_id)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, np.float32)
    action[-1] = bad
    with pytest.raises(ValueError, match="finite"):
        env.step(action)
    # the refused step changed nothing: the next one equals a fresh environment's first step
    clean = gym.make(env_id)
    clean.reset(seed=0)
    good = np.full(env.action_space.shape, 0.25, np.float32)
    for a, b in zip(env.step(good)[:4], clean.step(good)[:4], strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_malformed_action_raises(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(7, np.float32))
    with pytest.raises(ValueError):
        env.step("open")


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_out_of_range_actions_are_clipped(env_id):
    shape = gym.make(env_id).action_space.shape
    big = np.full(shape, 5.0, np.float32)
    big[0] = -3.0
    clipped = np.clip(big, -1.0, 1.0)
    results = []
    for action in (big, clipped, big.astype(np.float64), big.tolist()):
        env = gym.make(env_id)
        env.reset(seed=4)
        results.append(env.step(action)[:2])
    for obs, reward in results[1:]:
        np.testing.assert_array_equal(obs, results[0][0])
        assert reward == results[0][1]
    if env_id != PID_TUNE:  # the observation shows the clipped action
        np.testing.assert_array_equal(results[0][0][-len(clipped) :], clipped)


def test_step_after_episode_end_needs_reset():
    env = gym.make(PID_TUNE).unwrapped
    env.reset(seed=0)
    env.step(np.zeros(3, np.float32))
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(3, np.float32))


@pytest.mark.filterwarnings("ignore:.*render_mode")  # gym.make's own warning, before ours
@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"plant": "test9"}, "plant"),
        ({"plant": []}, "plant"),
        ({"disturbance": "no_such_preset"}, "disturbance"),
        ({"disturbance": {"friction": {"S_deg": -1.0}}}, "disturbance"),
        ({"disturbance": 3}, "disturbance"),
        ({"reference": "no_such_profile"}, "reference"),
        ({"reference": "missing.csv"}, "reference"),
        ({"randomize": {"friction.nope": [0.0, 1.0]}}, "randomize"),
        ({"randomize": "yes"}, "randomize"),
        ({"render_mode": "ascii"}, "render_mode"),
        ({"episode_s": -1.0}, "episode_s"),
        ({"gain_max": (1.0, 2.0)}, "gain_max"),
        ({"gain_scaling": "cubic"}, "gain_scaling"),
        ({"derivative_filter": 5000.0}, "derivative_filter"),
        ({"pid_options": {"sign": 2}}, "pid_options"),
    ],
)
def test_bad_kwargs_name_the_argument(env_id, kwargs, name):
    with pytest.raises(ValueError, match=f"'{name}'"):
        gym.make(env_id, **kwargs)


@pytest.mark.parametrize("env_id", [SERVO, GAIN_SCHEDULE])
@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"control_period_s": 0.0105}, "control_period_s"),
        ({"control_period_s": 0.0}, "control_period_s"),
        ({"command_range_deg": (10.0, 5.0)}, "command_range_deg"),
        ({"observe_context": "yes"}, "observe_context"),
        ({"chatter_weight": -1.0}, "chatter_weight"),
    ],
)
def test_bad_step_env_kwargs_name_the_argument(env_id, kwargs, name):
    with pytest.raises(ValueError, match=f"'{name}'"):
        gym.make(env_id, **kwargs)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_unknown_kwarg_is_named(env_id):
    with pytest.raises(TypeError, match="plants"):
        gym.make(env_id, plants="test2")


def test_vector_bad_kwargs_name_the_argument():
    with pytest.raises(ValueError, match="'plant'"):
        gym.make_vec(SERVO, num_envs=2, vectorization_mode="vector_entry_point", plant="x")
    with pytest.raises(ValueError, match="'render_mode'"):
        gym.make_vec(SERVO, num_envs=2, vectorization_mode="vector_entry_point",
                     render_mode="ascii")  # fmt: skip
    with pytest.raises(ValueError, match="'num_envs'"):
        gym.make_vec(PID_TUNE, num_envs=0, vectorization_mode="vector_entry_point")


def test_plant_yaml_path_and_csv_reference(tmp_path):
    plant = tmp_path / "mine.yaml"
    plant.write_text("name: mine\nnum: [10.0]\nden: [1.0, 10.0]\n")
    csv = tmp_path / "ref.csv"
    csv.write_text("t_s,reference_deg\n0,92\n0.5,92\n0.501,30\n2,30\n")
    env = gym.make(SERVO, plant=str(plant), reference=str(csv), disturbance={"extends": "actual"})
    _, info = env.reset(seed=0)
    assert info["plant"] == "mine"
    steps = 0
    while True:
        *_, terminated, truncated, _ = env.step(np.zeros(1, np.float32))
        steps += 1
        if terminated or truncated:
            break
    assert steps == 100  # 2.001 s of reference in whole 20 ms periods
