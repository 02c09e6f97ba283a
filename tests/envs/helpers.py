"""Shared pieces of the environment tests."""

import numpy as np

SERVO = "gripper_env/GripperServo-v0"
PID_TUNE = "gripper_env/GripperPIDTune-v0"
GAIN_SCHEDULE = "gripper_env/GripperGainSchedule-v0"
# The hobby-servo gripper's ids (plant, disturbance, randomisation, ...), which the parametrised
# tests share; the bus servo's id takes other arguments and has its own tests
# (test_bus_servo_env.py). gripper_env.ENV_IDS holds all four.
ENV_IDS = (SERVO, PID_TUNE, GAIN_SCHEDULE)
BUS_SERVO = "gripper_env/GripperBusServo-v0"
# The RL benchmark's task ids (test_benchmark_envs.py): the tuner's formulation of PIDTune, the
# robust controller with its constraint cost, the grasp on the hobby servo and on a bus servo.
PID_TUNE_RELATIVE = "gripper_env/GripperPIDTuneRelative-v0"
ROBUST = "gripper_env/GripperServoRobust-v0"
GRASP = "gripper_env/GripperGrasp-v0"
BUS_GRASP = "gripper_env/GripperBusGrasp-v0"
BENCHMARK_IDS = (PID_TUNE_RELATIVE, ROBUST, GRASP, BUS_GRASP)

# Everything random at once: plants drawn, actual-gripper parameters drawn, random references.
RANDOMIZED = {
    "plant": ["test1", "test2", "test3", "test4"],
    "randomize": True,
    "reference": "random",
    "episode_s": 1.0,
}


def signed_log_gains(action, gain_max=(10.0, 50.0, 0.1)):
    """The documented action -> gain map, written out independently of the library."""
    a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
    return np.sign(a) * np.asarray(gain_max) * (10.0 ** (3.0 * np.abs(a)) - 1.0) / 999.0


def assert_same_info(a, b, path="info"):
    """Two (batched or single) info dicts are equal: same keys, equal values, NaN equal to NaN
    (Gymnasium's ``data_equivalence`` treats NaN as unequal to itself)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (path, sorted(a), sorted(b))
        for key in a:
            assert_same_info(a[key], b[key], f"{path}[{key!r}]")
        return
    x, y = np.asarray(a), np.asarray(b)
    assert x.dtype == y.dtype and x.shape == y.shape, (path, x, y)
    if x.dtype == object:
        for p, q in zip(x.ravel(), y.ravel(), strict=True):
            same = p is q or p == q or (isinstance(p, float) and p != p and q != q)
            assert same, (path, p, q)
    else:
        np.testing.assert_array_equal(x, y, err_msg=path)


def step_native_and_singles(native, singles, actions, pending):
    """Step a native vector env and its single envs with the same actions, assert the rows are
    equal (a single env that ended is reset, as the vector env's next-step autoreset does), and
    return which rows ended."""
    obs, rew, term, trunc, _ = native.step(actions)
    for i, env in enumerate(singles):
        if pending[i]:
            o, r, te, tr = env.reset()[0], 0.0, False, False
        else:
            o, r, te, tr, _ = env.step(actions[i])
        np.testing.assert_array_equal(obs[i], o)
        assert rew[i] == r and term[i] == te and trunc[i] == tr
    return term | trunc
