"""SO101Joint-v0: Gymnasium's checker, the payload and pose drawn per seed, the arm's weight
making LeRobot's P 16 sag where a stiffer loop does not."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from gripper_env.envs.bus_joint import SO101JointEnv

ID = "gripper_env/SO101Joint-v0"


def test_checker_and_time_limit():
    env = gym.make(ID)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.spec.max_episode_steps == 500
    env.close()


def test_payload_and_pose_drawn_per_seed():
    env = SO101JointEnv(joint="elbow_flex")
    _, a = env.reset(seed=3)
    _, b = env.reset(seed=3)
    _, c = env.reset(seed=4)
    assert a["payload_kg"] == b["payload_kg"] and a["pose_rad"] == b["pose_rad"]
    assert a["payload_kg"] != c["payload_kg"]
    assert 0.0 <= c["payload_kg"] <= 0.1
    assert abs(c["pose_rad"]["shoulder_lift"]) <= 0.3 + 1e-12
    assert a["gravity_nm"] > 0.3  # the forearm, wrist and gripper, about horizontal


def test_lerobots_p16_sags_under_the_load():
    """Holding the joint's start (the reference's first value) with the zero residual action:
    P 16 sags degrees under the 100 g payload; P 64 a quarter as much."""
    sag = {}
    for p in (16, 64):
        regs = {"p": p, "i": 0, "d": 32, "torque_limit": 1000}
        env = SO101JointEnv(joint="elbow_flex", payload_kg=(0.1, 0.1), pose_jitter_rad=0.0,
                            registers=regs, reference=np.full(2000, 180.0),
                            residual="reference")  # fmt: skip
        env.reset(seed=0)
        for _ in range(50):
            *_, info = env.step(np.zeros(1, np.float32))
        sag[p] = abs(info["position_deg"] - 180.0)
    assert sag[16] > 4.0
    assert sag[64] < sag[16] / 3


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [({"joint": "gripper"}, "'joint'"), ({"payload_kg": (0.2, 0.1)}, "'payload_kg'"),
     ({"pose": {"knee": 0.1}}, "'pose'"), ({"pose_jitter_rad": 2.0}, "'pose_jitter_rad'")],
)  # fmt: skip
def test_bad_arguments_name_themselves(kwargs, says):
    with pytest.raises(ValueError, match=says):
        SO101JointEnv(**kwargs)
