"""Training leaves nothing in the system's temporary directory (``tuners.rl.agents.quiet_logger``).

stable-baselines3 makes an empty ``SB3-<date-time>`` folder there at every ``learn`` of a model
without a logger of its own; 130 of them had piled up on a development machine.
"""

from __future__ import annotations

import tempfile

import gymnasium as gym
import pytest

pytest.importorskip("stable_baselines3")

from stable_baselines3 import PPO

from tuners.rl.agents import quiet_logger


def _learn(quiet: bool) -> None:
    env = gym.make("gripper_env/GripperServo-v0")
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu",
                verbose=0)  # fmt: skip
    if quiet:
        quiet_logger(model)
    model.learn(32)
    env.close()


@pytest.mark.parametrize("quiet", [False, True], ids=["sb3's default", "quiet_logger"])
def test_learn_makes_a_temporary_folder_only_without_the_quiet_logger(quiet, tmp_path,
                                                                       monkeypatch):  # fmt: skip
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    _learn(quiet)
    made = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("SB3-"))
    assert (made == []) is quiet, made
