"""The shipped rl-zoo3 hyperparameter files run through rl-zoo3's own train and enjoy."""

import importlib.util
import subprocess
import sys

import gymnasium as gym
import pytest
import yaml

# Not imported here: importing rl_zoo3 replaces gymnasium's TimeLimit for the whole process
# (rl_zoo3.gym_patches), which changed the infos of every later environment test. rl-zoo3 runs
# in subprocesses only.
if importlib.util.find_spec("rl_zoo3") is None:
    pytest.skip("rl-zoo3 is not installed (pip install 'gripper-env[rl]')", allow_module_level=True)

from gripper_env.io.config import CONFIG_DIR

pytestmark = pytest.mark.slow  # the end-to-end tier (pytest -m slow)

ZOO = CONFIG_DIR / "rl_zoo"
IDS = ("gripper_env/GripperServo-v0", "gripper_env/GripperGainSchedule-v0",
       "gripper_env/GripperPIDTune-v0", "gripper_env/GripperBusServo-v0")  # fmt: skip


def _load(setting: str, algo: str) -> dict:
    return yaml.load((ZOO / setting / f"{algo}.yml").read_text(), Loader=yaml.UnsafeLoader)


@pytest.mark.parametrize("setting", ["default", "randomized"])
@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_every_environment_has_a_recipe_that_makes_its_environment(setting, algo):
    import gripper_env.envs  # noqa: F401

    recipes = _load(setting, algo)
    assert set(recipes) == set(IDS)
    for env_id, params in recipes.items():
        assert params["policy"] == "MlpPolicy" and params["n_timesteps"] > 0
        env = gym.make(env_id, **params.get("env_kwargs", {}))
        env.reset(seed=0)
        env.close()
        if setting == "randomized" and "BusServo" not in env_id:  # the bus env has no preset
            assert params["env_kwargs"]["randomize"] is True


def _zoo(*args, cwd, timeout=600):
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


def test_rl_zoo3_trains_with_the_shipped_file_then_enjoys(tmp_path):
    env_id, algo, steps = "gripper_env/GripperServo-v0", "ppo", 2048
    conf = str(ZOO / "randomized" / f"{algo}.yml")
    common = ["--algo", algo, "--env", env_id, "--gym-packages", "gripper_env"]
    train = _zoo("rl_zoo3.train", *common, "-conf", conf, "-n", str(steps), "-f", "logs",
                 "--seed", "0", "--eval-freq", "-1", cwd=tmp_path)  # fmt: skip
    assert train.returncode == 0, train.stderr[-2000:]
    name = env_id.replace("/", "-")
    assert (tmp_path / "logs" / algo / f"{name}_1" / f"{name}.zip").is_file()
    enjoy = _zoo("rl_zoo3.enjoy", *common, "-f", "logs", "-n", "200", "--no-render",
                 cwd=tmp_path)  # fmt: skip
    assert enjoy.returncode == 0, enjoy.stderr[-2000:]
    assert "Loading" in enjoy.stdout


def test_every_task_recipe_makes_its_task_environment():
    """configs/rl_zoo/tasks/<task>-<algo>.yml: one id with the task's training arguments."""
    from tuners.rl.suite import load_tasks

    for name, t in load_tasks().items():
        for algo in ("ppo", "sac"):
            recipes = yaml.load((ZOO / "tasks" / f"{name}-{algo}.yml").read_text(),
                                Loader=yaml.UnsafeLoader)  # fmt: skip
            assert list(recipes) == [t.env_id]
            params = recipes[t.env_id]
            assert params["policy"] == "MlpPolicy" and params["n_timesteps"] > 0
            task_kwargs = {k: v for k, v in params["env_kwargs"].items() if k not in t.interface}
            assert task_kwargs == t.train_kwargs
