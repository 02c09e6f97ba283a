"""The RL benchmark's task ids: GripperPIDTuneRelative-v0, GripperServoRobust-v0, GripperGrasp-v0,
GripperBusGrasp-v0 (checkers, copies, what each adds to the id it builds on)."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from helpers import BENCHMARK_IDS, BUS_GRASP, BUS_SERVO, GRASP, PID_TUNE, PID_TUNE_RELATIVE, ROBUST

import gripper_env  # noqa: F401
from gripper_env.envs.grasp import GripperGraspEnv
from gripper_env.envs.pid_tune import DEFAULT_RELATIVE
from gripper_env.envs.robust import SwingCost, margin_floor_db, raised_plant
from gripper_env.evaluation.grasp import thermal_overload_at
from gripper_env.model.plants import load_plant

QUICK = {
    ROBUST: {"episode_s": 2.0},
    GRASP: {},
    BUS_GRASP: {"episode_s": 1.0},
    PID_TUNE_RELATIVE: {},
}


@pytest.mark.parametrize("env_id", BENCHMARK_IDS)
def test_gymnasium_and_sb3_checkers_pass_as_made(env_id):
    sb3_checker = pytest.importorskip("stable_baselines3.common.env_checker")
    env = gym.make(env_id, **QUICK[env_id])
    check_env(env.unwrapped)
    sb3_checker.check_env(env, warn=True)


@pytest.mark.parametrize("env_id", BENCHMARK_IDS)
@pytest.mark.parametrize("how", [pickle.loads, copy.deepcopy])
def test_a_copy_plays_the_same_episode(env_id, how):
    def play(env):
        env.reset(seed=5)
        rng = np.random.default_rng(1)
        out = []
        for _ in range(30):
            o, r, te, tr, _ = env.step(
                rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            )
            out.append((o.copy(), r))
            if te or tr:
                break
        return out

    env = gym.make(env_id, **QUICK[env_id])
    twin = how(pickle.dumps(env)) if how is pickle.loads else how(env)
    for (o1, r1), (o2, r2) in zip(play(env), play(twin), strict=True):
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2


# ---- GripperPIDTuneRelative-v0 -------------------------------------------------------------


def test_pid_tune_relative_is_v0_with_the_tuners_formulation():
    """Its registered defaults are pid_tune.DEFAULT_RELATIVE; the zero action is the centre design
    and the reward the -log of the exact penalty, the same episode's cost as v0's."""
    spec = gym.spec(PID_TUNE_RELATIVE)
    assert spec.kwargs == {**DEFAULT_RELATIVE}
    same = {k: v for k, v in DEFAULT_RELATIVE.items() if k != "reward"}
    v1, v0 = gym.make(PID_TUNE_RELATIVE), gym.make(PID_TUNE, **same)
    v1.reset(seed=3)
    v0.reset(seed=3)
    _, r1, _, _, i1 = v1.step(np.zeros(3, np.float32))
    _, r0, _, _, i0 = v0.step(np.zeros(3, np.float32))
    assert [i1["gains"][k] for k in "PID"] == pytest.approx(list(DEFAULT_RELATIVE["gain_center"]))
    assert i1["cost"] == i0["cost"] and r0 == -i0["penalised_cost"]
    assert i1["feasible"]  # the design is admitted on every identification
    assert r1 == pytest.approx(-np.log(i1["cost"]))


def test_pid_tune_relative_exact_penalty_takes_off_the_cliff():
    """Infeasible gains: v0 pays cost + 100 (1 + violation), Relative -log(cost + 100 violation)."""
    env = gym.make(PID_TUNE_RELATIVE)
    env.reset(seed=0)
    _, r, _, _, info = env.step(np.array([1.0, 1.0, 0.0], np.float32))  # 31x P and I
    assert not info["feasible"]
    assert r == pytest.approx(-np.log(info["penalised_cost"] - 100.0))
    assert info["penalised_cost"] - 100.0 > info["cost"]


def test_pid_tune_relative_vector_env_equals_the_single_env():
    vec = gym.make_vec(PID_TUNE_RELATIVE, num_envs=3, vectorization_mode="vector_entry_point")
    vec.reset(seed=[1, 2, 3])
    actions = np.array([[0.1, -0.2, 0.3], [0.0, 0.0, 0.0], [0.9, 0.9, -0.9]], np.float32)
    _, rewards, _, _, _ = vec.step(actions)
    for i, seed in enumerate([1, 2, 3]):
        env = gym.make(PID_TUNE_RELATIVE)
        env.reset(seed=seed)
        assert env.step(actions[i])[1] == rewards[i]


def test_pid_tune_refuses_an_unknown_reward():
    with pytest.raises(ValueError, match=r"GripperPIDTune-v0: argument 'reward'"):
        gym.make(PID_TUNE, reward="log")


# ---- GripperServoRobust-v0 -----------------------------------------------------------------


def test_robust_draws_the_identifications_and_their_margin_twins():
    env = gym.make(ROBUST, episode_s=1.0)
    names = {env.reset(seed=s)[1]["plant"] for s in range(60)}
    floor = margin_floor_db()
    assert floor == pytest.approx(20 * np.log10(1.6 / 0.6))  # 8.52 dB
    assert names == {"test2", "test3", "test4", *(f"test{k}@+8.52dB" for k in (2, 3, 4))}
    p = raised_plant(load_plant("test3"), floor)
    base = load_plant("test3")
    np.testing.assert_allclose(np.array(p.num) / np.array(base.num), 10 ** (floor / 20))
    assert p.den == base.den


def test_swing_cost_by_hand():
    cost = SwingCost(swing_deg=1.0, settle_s=0.1, window_s=0.1)  # 5 periods of 20 ms
    ref = np.r_[np.full(100, 50.0), np.full(300, 30.0)]
    settled = [30.0, 30.1, 29.9, 30.2, 30.0]
    creeping = [40.0, 36.0, 33.0, 31.0, 30.0]  # a slow loop still arriving: monotone
    swinging = [29.0, 31.0, 29.0, 31.0, 29.0]
    kw = {"dt_s": 1e-3, "control_period_s": 0.02}
    # swing = peak to peak - net change: 0.3, 0 and 2 deg
    assert cost.cost(settled, ref, 300, **kw) == 0.0
    assert cost.cost(creeping, ref, 300, **kw) == 0.0
    assert cost.cost(swinging, ref, 300, **kw) == 1.0
    assert cost.cost(swinging, ref, 250, **kw) == 0.0  # moved 0.15 s ago: 0.2 s needed
    assert cost.cost(swinging[:3], ref, 300, **kw) == 0.0  # not a whole window yet


def test_robust_cost_counts_a_loop_that_swings_and_not_one_that_settles():
    """A residual PID with the benchmark's robust gains settles: no swing cost on the nominal
    plants; with its gain 20x it oscillates (its linear gain margin is about 9 dB) and every
    hold costs."""
    opts = {"output_limits": (0.0, 180.0), "anti_windup": "clamping"}

    def episode_cost(gains, seed):
        env = gym.make(ROBUST, residual="pid", pid_gains=gains, pid_options=opts, margin_db=0.0)
        env.reset(seed=seed)
        total, done = {"cost_swing": 0.0, "cost_stop": 0.0}, False
        while not done:
            *_, te, tr, info = env.step(np.zeros(1, np.float32))
            for k in total:
                total[k] += info[k]
            assert info["cost"] == info["cost_swing"] + info["cost_stop"]
            done = te or tr
        return total

    good = [episode_cost((0.4731, 5.415, 0.0), s) for s in range(3)]
    bad = [episode_cost((20 * 0.4731, 20 * 5.415, 0.0), s) for s in range(3)]
    assert all(c["cost_swing"] == 0.0 for c in good)
    assert all(c["cost_swing"] + c["cost_stop"] > 20 for c in bad)


# ---- GripperGrasp-v0 -----------------------------------------------------------------------


def _play_grasp(env, command, seed=0):
    obs, info = env.reset(seed=seed)
    u = env.unwrapped
    o = info["object_deg"]
    cc, ch = 90.0, 90.0
    steps = []
    done = False
    while not done:
        r = 56.5 + 35.5 * float(obs[1])
        goal = command(r, o)
        obs, reward, te, tr, info = env.step(np.array([(goal - cc) / ch], np.float32))
        steps.append((reward, te, tr, info))
        done = te or tr
    return u, o, steps


def test_grasp_commanding_the_reference_trips_when_the_i2t_model_says():
    """The reference (21 deg, far past any object) is a full stall: the thermal criterion trips
    where :func:`thermal_overload_at` of the env's per-period currents trips, about 2 s after
    contact, and the episode ends with -(100 + steps left)."""
    env = gym.make(GRASP)
    _, o, steps = _play_grasp(env, lambda r, o: r)
    assert 30.0 <= o <= 50.0
    reward, te, tr, info = steps[-1]
    assert te and not tr and info["trip"]
    currents = np.array([s[3]["current_fraction"] for s in steps])
    close = round(0.5 / 0.02)  # the close command at 0.5 s
    t = np.arange(len(currents) - close) * 0.02
    trip = thermal_overload_at(t, currents[close:])  # per-period currents, held 20 ms each
    assert trip == pytest.approx(len(steps) * 0.02 - 0.5, abs=1e-9)
    assert 1.9 < trip < 2.6
    assert reward == -(100 + 225 - len(steps))


def test_grasp_a_squeeze_two_degrees_past_the_object_holds_it():
    env = gym.make(GRASP)
    for seed in range(3):
        _, _, steps = _play_grasp(env, lambda r, o: r if r > o else o - 2.0, seed)
        infos = [s[3] for s in steps]
        assert steps[-1][2] and not any(i["trip"] for i in infos)
        hold = [i for i in infos if i["in_hold"]]
        assert len(hold) >= 140 and all(i["held"] for i in hold)
        assert all(1.0 <= i["force_n"] < 0.5 * 7.45 for i in hold)


def test_grasp_refuses_an_object_outside_the_scenario():
    with pytest.raises(ValueError, match=r"GripperGrasp-v0: argument 'object_deg'"):
        GripperGraspEnv(object_deg=(10.0, 40.0))


# ---- GripperBusGrasp-v0 --------------------------------------------------------------------


def test_bus_grasp_episode_is_the_bus_servos_grasp_with_the_drawn_object():
    """Every episode equals GripperBusServo-v0(reference='grasp', object_deg=o), step for
    step."""
    env = gym.make(BUS_GRASP, episode_s=1.0)
    objects = set()
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        o = info["object_deg"]
        objects.add(o)
        assert 170.0 <= o <= 200.0 and float(o).is_integer()
        base = gym.make(BUS_SERVO, reference="grasp", object_deg=o, episode_s=1.0)
        obs_b, _ = base.reset(seed=0)
        np.testing.assert_array_equal(obs, obs_b)
        rng = np.random.default_rng(seed)
        done = False
        while not done:
            a = rng.uniform(-1, 1, (1,)).astype(np.float32)
            x, y = env.step(a), base.step(a)
            np.testing.assert_array_equal(x[0], y[0])
            assert x[1:4] == y[1:4] and x[4]["object_deg"] == o
            done = x[2] or x[3]
    assert len(objects) > 1
