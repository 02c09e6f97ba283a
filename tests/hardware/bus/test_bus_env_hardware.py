"""GripperBusServoHardware-v0 against virtual bus servos (VirtualBus with a ServoUnit) in real
time: registration, arguments, an episode that reaches the goal as the simulated environment
does, an overload that ends the episode, and bus errors that end in a clear error with the
torque off. Real time: each test runs a few dozen 20 ms steps."""

from __future__ import annotations

import warnings
from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import gripper_env
from gripper_env.envs.bus_servo_hardware import GripperBusServoHardwareEnv
from gripper_env.hardware.bus.link import BusTimeoutError
from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.io.config import ConfigError
from gripper_env.model.bus_servo import RegisterSet

HW = "gripper_env/GripperBusServoHardware-v0"
SIM = "gripper_env/GripperBusServo-v0"
JC, JH = 205.0, 55.0  # centre and half-width of the shipped models' jaw range (deg)
#: The virtual servo's jaw as its owner would calibrate it: its stops at 150 and 260 deg.
JAW = {"closed_ticks": 1707, "open_ticks": 2958}
ON_BUS = {"servo_id": 1, "jaw": JAW}


def action_for(goal_deg: float) -> np.ndarray:
    return np.array([(goal_deg - JC) / JH], dtype=np.float32)


@pytest.fixture
def sts_bus() -> Iterator[VirtualBus]:
    with VirtualBus("sts3215", physics=ServoUnit("sts3215")) as bus:
        yield bus


# ---- without a device -------------------------------------------------------------------------


def test_registered_nondeterministic_with_a_time_limit_and_touches_no_device() -> None:
    spec = gym.spec(HW)
    assert spec.max_episode_steps == 1000 and spec.nondeterministic
    assert spec.vector_entry_point is None
    assert HW not in gripper_env.ENV_IDS
    env = gym.make(HW, port="/nonexistent/tty", **ON_BUS)  # the port is opened by reset
    assert isinstance(env, gym.wrappers.TimeLimit)
    sim = gym.make(SIM)
    assert env.action_space == sim.action_space
    assert env.observation_space == sim.observation_space
    env.close()  # closing an env that never opened its port is fine


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({}, "port"),
        ({"port": 5}, "port"),
        ({"port": "/dev/null", "reads_per_period": 0}, "reads_per_period"),
        ({"port": "/dev/null", "reads_per_period": 21}, "reads_per_period"),
        ({"port": "/dev/null", "servo_id": 300}, "servo_id"),
        ({"port": "/dev/null", "servo_id": None}, "servo_id"),
        ({"port": "/dev/null", "jaw": None}, "jaw"),
        ({"port": "/dev/null", "jaw": {"closed_ticks": 1707}}, "jaw"),
        ({"port": "/dev/null", "jaw": {"closed_ticks": 2000, "open_ticks": 2010}}, "jaw"),
        ({"port": "/dev/null", "jaw": "/nonexistent/jaw.json"}, "jaw"),
        ({"port": "/dev/null", "settle_tol_deg": -1.0}, "settle_tol_deg"),
        ({"port": "/dev/null", "registers": {"p": 16}}, "registers"),
        ({"port": "/dev/null", "control_period_s": 0.0005}, "control_period_s"),
        ({"port": "/dev/null", "render_mode": "rgb_array"}, "render_mode"),
    ],
)
def test_bad_arguments_name_themselves(kwargs: dict, name: str) -> None:
    with pytest.raises(ConfigError, match=f"GripperBusServoHardware-v0: argument '{name}'"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # gym.make's own render_mode warning
            gym.make(HW, **{**ON_BUS, **kwargs})


def test_docstring_has_gymnasium_sections() -> None:
    doc = GripperBusServoHardwareEnv.__doc__ or ""
    for section in ("## Description", "## Action Space", "## Observation Space", "## Rewards",
                    "## Starting State", "## Episode End", "## Arguments", "gym.make(",
                    "VirtualBus", "## Version History"):  # fmt: skip
        assert section in doc, section


# ---- over the virtual bus ------------------------------------------------------------------------


def test_an_episode_reaches_the_goal_as_in_simulation(sts_bus: VirtualBus) -> None:
    """Reset writes the registers (read back) and turns the torque on; a constant goal 30 deg
    away is reached as the simulated environment reaches it (the virtual servo is the same
    block of the simulation core, run by the bus as time passes); close relaxes."""
    regs = RegisterSet(p=24, d=32, torque_limit=800, deadband=1)
    table = sts_bus.table(1)
    env = gym.make(HW, port=sts_bus.path, registers=regs, reference="tracking", **ON_BUS)
    sim = gym.make(SIM, registers=regs, reference="tracking")
    obs, info = env.reset(seed=0)
    sim_obs, _ = sim.reset(seed=0)
    assert info["settled"] and abs(info["position_deg"] - 240.0) < 1.0
    assert table.get_role("torque_enable") == 1
    assert table.get_role("p_gain") == 24 and table.get_role("torque_limit") == 800
    np.testing.assert_allclose(obs, sim_obs, atol=0.02)
    goal = action_for(210.0)
    hw_y, sim_y = [], []
    for _ in range(40):  # 0.8 s
        obs, reward, terminated, truncated, info = env.step(goal)
        sim_obs, _, _, _, sim_info = sim.step(goal)
        assert not terminated and not truncated and np.isfinite(reward)
        hw_y.append(info["position_deg"])
        sim_y.append(sim_info["position_deg"])
    assert abs(hw_y[-1] - 210.0) < 2.0 and abs(sim_y[-1] - 210.0) < 2.0
    assert abs(hw_y[-1] - sim_y[-1]) < 1.0
    assert obs[5] == goal[0]
    if info["missed_deadlines"] == 0:  # the slew too, unless a loaded machine held a goal longer
        np.testing.assert_allclose(hw_y, sim_y, atol=8.0)
    env.close()
    assert table.get_role("torque_enable") == 0  # closed: the jaw is limp


def test_checker_passes_against_the_virtual_bus(sts_bus: VirtualBus) -> None:
    env = gym.make(HW, port=sts_bus.path, episode_s=0.2, **ON_BUS)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*is different from the unwrapped version")
        warnings.filterwarnings("ignore", category=RuntimeWarning)  # missed deadlines
        check_env(env, skip_render_check=True)
    env.close()
    assert sts_bus.table(1).get_role("torque_enable") == 0


def test_nan_action_is_refused_before_anything_is_sent(sts_bus: VirtualBus) -> None:
    env = gym.make(HW, port=sts_bus.path, **ON_BUS)
    env.reset(seed=0)
    before = sts_bus.packets_received
    with pytest.raises(ValueError, match=r"GripperBusServoHardware-v0: action must be finite"):
        env.step(np.array([np.nan], np.float32))
    assert sts_bus.packets_received == before
    env.close()


@pytest.mark.parametrize("family", ["sts3215", "xl330"])
def test_an_overload_ends_the_episode_with_the_torque_off(family: str) -> None:
    """An object in the jaws, the goal at the closed stop: the servo's overload protection trips
    (2 s of device time at 4x) and the episode ends (-(100 + steps left)), the torque off; the
    next reset clears the trip (an STS when its torque goes off, a Dynamixel by a REBOOT)."""
    unit = ServoUnit(family, object_deg=185.0)
    with VirtualBus(family, physics=unit, speed=4.0) as bus:
        env = gym.make(HW, port=bus.path, model=family, reference="tracking", **ON_BUS)
        env.reset(seed=0)
        steps, positions = 0, []
        t0 = unit.ticks_simulated + unit.ticks_skipped  # device time (1 ms ticks)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            while steps < 100:
                _, reward, terminated, truncated, info = env.step(action_for(150.0))
                steps += 1
                positions.append(round(info["position_deg"], 1))
                if terminated or truncated:
                    break
        said = [str(w.message) for w in caught]
        assert terminated, (steps, unit.trip, unit.force_n, positions, info, said)
        assert info["trip"] == "overload" and any("reports overload" in s for s in said)
        assert reward == -(100 + 210 - steps)
        # the protection's 2 s of overload in device time (a busy host's late steps see more
        # device time each: the step count is at most 2 s at 4x, 25 steps of 20 ms, plus the
        # approach)
        device_s = (unit.ticks_simulated + unit.ticks_skipped - t0) * 1e-3
        assert device_s >= 2.0, (device_s, steps)
        assert steps <= 45
        assert bus.table(1).get_role("torque_enable") == 0
        unit.place_object(None)
        _, info = env.reset(seed=0)
        assert info["settled"] and bus.table(1).get_role("torque_enable") == 1
        _, _, terminated, _, info = env.step(action_for(240.0))
        assert not terminated and info["errors"] == []
        env.close()
        assert bus.table(1).get_role("torque_enable") == 0


def test_a_lost_reply_is_sent_again_and_a_dead_link_ends_in_a_clear_error(
    sts_bus: VirtualBus,
) -> None:
    env = gym.make(HW, port=sts_bus.path, **ON_BUS)
    env.reset(seed=0)
    for _ in range(3):
        env.step(action_for(230.0))
    assert sts_bus.table(1).get_role("torque_enable") == 1
    link = env.unwrapped.gripper.link
    retried = link.retried
    sts_bus.drop_replies(1)  # the servo acts, its reply is lost: the link asks again
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the retry may miss a deadline
        env.step(action_for(225.0))
    assert link.retried >= retried + 1  # a loaded host may also ask again for a late reply
    sts_bus.drop_replies(1 + link.retries)  # every attempt lost
    with pytest.raises(BusTimeoutError, match=r"servo 1 on .*no reply") as excinfo:
        env.step(action_for(220.0))
    assert any("the torque is off" in note for note in excinfo.value.__notes__)
    assert sts_bus.table(1).get_role("torque_enable") == 0  # relaxed at once
    with pytest.raises(RuntimeError, match="reset"):
        env.step(action_for(220.0))
    _, info = env.reset(seed=1)  # starts again
    assert info["settled"] and sts_bus.table(1).get_role("torque_enable") == 1
    env.close()


def test_a_silent_servo_ends_in_a_clear_error_and_close_relaxes_it(sts_bus: VirtualBus) -> None:
    env = gym.make(HW, port=sts_bus.path, **ON_BUS)
    env.reset(seed=0)
    env.step(action_for(230.0))
    sts_bus.silence(1)  # unplugged: it hears nothing, not even the torque off
    with pytest.raises(BusTimeoutError, match="no reply") as excinfo:
        env.step(action_for(220.0))
    assert any("could not be turned off" in note for note in excinfo.value.__notes__)
    sts_bus.silence(1, False)
    env.close()  # plugged back: close turns the torque off
    assert sts_bus.table(1).get_role("torque_enable") == 0


def test_the_docs_example_runs() -> None:
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[3] / "docs" / "envs.md").read_text()
    section = text[text.index("## A bus servo on its bus") :]
    (code,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    namespace: dict = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a missed deadline on a loaded machine
        exec(compile(code, "<docs/envs.md>", "exec"), namespace)
    assert namespace["info"]["errors"] == []
