"""The RL benchmark's tasks, anchors and verdicts."""

import dataclasses
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from gripper_env.envs.robust import margin_floor_db
from gripper_env.evaluation.scoring import robustness
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.sim import simulate
from tuners.rl.anchors import draw, trivial_returns
from tuners.rl.judge import judge_policy, pid_interface
from tuners.rl.rollouts import constant_policy, run_episodes
from tuners.rl.suite import EVAL_SEED, load_tasks, recipe, task

OPTUNA_TEST2 = PIDGains(3.432, 67.52, -0.008661)
AMIGO_ROBUST = PIDGains(0.4731, 5.415, 0.0)
CLAMPED = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")


def small(name, episodes=4):
    return dataclasses.replace(task(name), episodes=episodes)


def test_every_task_makes_its_environments_and_follows_the_protocol():
    tasks = load_tasks()
    assert sum(t.hard for t in tasks.values()) >= 3
    for t in tasks.values():
        for kwargs in (t.train_kwargs, t.eval_kwargs):
            env = gym.make(t.env_id, **kwargs)
            env.reset(seed=0)
            env.close()
        for algo in ("ppo", "sac"):
            assert recipe(t.name, algo)["env_id"] == t.env_id
            assert t.seeds[algo] >= 5  # rliable's protocol (10 where a seed trains in < 2 min)
        assert t.eval_seeds[0] == EVAL_SEED and len(t.eval_seeds) == t.episodes >= 100


def test_the_published_cells_have_the_protocols_seeds_for_their_measured_training_time():
    """rliable's protocol as the issue states it: at least 10 seeds where a seed trains in under
    2 minutes (the median of the published run's own wall times), at least 5 elsewhere; and the
    published table has the seeds tasks.yaml asks for, each with its measured time."""
    results = Path(__file__).resolve().parents[2] / "results"
    table = json.loads((results / "reference_scores.json").read_text())["tasks"]
    measured = json.loads((results / "reference_scores.provenance.json").read_text())
    times = measured["files"]["reference_scores.json"]
    tasks = load_tasks()
    assert set(table) == set(tasks)
    for name, t in tasks.items():
        for algo in ("ppo", "sac"):
            cell = table[name]["cells"][algo.upper()]
            prefix = f"/tasks/{name}/cells/{algo.upper()}/per_seed/"
            walls = [v for k, v in times.items()
                     if k.startswith(prefix) and k.endswith("/train_wall_time_s")]  # fmt: skip
            assert len(cell["per_seed"]) == t.seeds[algo] == len(walls), (name, algo)
            median = float(np.median(walls))
            assert t.seeds[algo] >= (10 if median < 120.0 else 5), (name, algo, median)


def test_an_unknown_task_is_one_line_naming_them():
    with pytest.raises(ValueError, match=r"no such task; choose from servo, .*grasp"):
        task("cartpole")


def test_an_agent_may_bring_its_action_map_but_not_change_the_task():
    t = task("servo")
    assert t.kwargs_with({"residual": "reference"})["residual"] == "reference"
    with pytest.raises(ValueError, match=r"not plant \(that would change the task\)"):
        t.kwargs_with({"plant": "test4"})


@pytest.mark.parametrize("name", ["servo", "robust", "pid-tune", "generalisation"])
def test_the_drawn_episodes_are_the_ones_reset_plays(name):
    """anchors.draw reproduces each reset's episode (its noise seed, plant and reference)."""
    t = small(name, 5)
    s, episodes = draw(t, t.eval_seeds)
    env = gym.make(t.env_id, **t.eval_kwargs)
    for seed, ep in zip(t.eval_seeds, episodes, strict=True):
        _, info = env.reset(seed=seed)
        assert info["noise_seed"] == ep.noise_seed
        assert info["plant"] == s.plants[ep.plant_index].name
    assert len({len(ep.reference) for ep in episodes}) == 1  # 5 s random profiles
    assert len({float(ep.reference.values_deg.sum()) for ep in episodes}) == 5  # not replicates


def test_the_gain_schedule_task_plays_the_servo_tasks_episodes():
    """Its trivial return is the servo environment's on the same episodes (the reward depends
    only on the reference, the jaw and the servo's command)."""
    gs, sv = small("gain-schedule"), small("servo")
    for seed in gs.eval_seeds:
        a = gym.make(gs.env_id, **gs.eval_kwargs).reset(seed=seed)[1]
        b = gym.make(sv.env_id, **sv.eval_kwargs).reset(seed=seed)[1]
        assert a == b
    np.testing.assert_array_equal(trivial_returns(gs), trivial_returns(sv))


def test_the_trivial_policy_commands_the_reference():
    """residual="reference" with the zero action through the task's environment is the
    simulation core's open loop (the servo commanded the reference) on the same episode."""
    from gripper_env.envs.rollout import policy_trajectory

    t = small("servo", 2)
    s, episodes = draw(t, t.eval_seeds)
    for ep in episodes:
        traj = policy_trajectory(constant_policy([0.0]), [ep.noise_seed], residual="reference",
                                 plant="test2", reference=ep.reference,
                                 run_disturbances=[ep.disturbance])  # fmt: skip
        core = simulate(s.plants[ep.plant_index], ep.reference, None, ep.disturbance,
                        seeds=[ep.noise_seed])  # fmt: skip
        np.testing.assert_allclose(traj.y_true[0], core.y_true[0, : traj.y_true.shape[1]],
                                   atol=1e-9)  # fmt: skip


def test_a_pid_through_the_servo_task_is_the_pid_of_the_core():
    from gripper_env.envs.rollout import policy_trajectory

    iface, policy = pid_interface(task("servo"), OPTUNA_TEST2, CLAMPED)
    traj = policy_trajectory(policy, [0], reference="step", plant="test2", **iface)
    core = simulate("test2", "step", [OPTUNA_TEST2.as_array()], "actual", seeds=[0],
                    pid_options=CLAMPED)  # fmt: skip
    np.testing.assert_allclose(traj.y_true[0], core.y_true[0], atol=1e-9)


@pytest.mark.parametrize("name", ["pid-tune", "gain-schedule"])
def test_a_pid_through_the_gain_maps_is_the_pid(name):
    """The constant action on GripperPIDTuneRelative-v0's relative map and
    GripperGainSchedule-v0's log map (each widened where the gains lie beyond it) sets exactly
    those gains."""
    t = task(name)
    iface, policy = pid_interface(t, OPTUNA_TEST2, CLAMPED)
    env = gym.make(t.env_id, **t.kwargs_with(iface))
    obs, _ = env.reset(seed=0)
    action = policy(obs[None, :])[0]
    if name == "pid-tune":
        gains = env.step(action)[4]["gains"]
        got = [gains[k] for k in "PID"]
    else:
        env.step(action)
        got = list(env.unwrapped._batch.sim.params[0, :3])
    assert got == pytest.approx([OPTUNA_TEST2.P, OPTUNA_TEST2.I, OPTUNA_TEST2.D], rel=1e-4)


@pytest.mark.slow
def test_the_margin_verdict_admits_the_robust_pi_and_refuses_a_pid_unstable_on_test4():
    """AMIGO's robust PI (its measured gain margin on test2 the linear one with the hold) is
    admitted on the servo task; Optuna's test2 PID, unstable on test4 with the hold, is not on the
    generalisation task (evaluated on test4)."""
    fake = {"trivial": [-30.0, -30.0], "limit": [-1.0, -1.0]}
    rows = {}
    for label, name, gains in (("amigo", "servo", AMIGO_ROBUST),
                               ("optuna", "generalisation", OPTUNA_TEST2)):  # fmt: skip
        t = dataclasses.replace(task(name), episodes=2)
        iface, policy = pid_interface(t, gains, CLAMPED)
        rows[label] = judge_policy(t, policy, fake, iface, seeds=[100000])
    good = rows["amigo"]
    assert good["admitted"], good["verdict"]
    # the probe's margin is the lifted linear loop's (gripper_env.evaluation.stability)
    linear = robustness(load_plant("test2"), load_disturbance("actual"),
                        AMIGO_ROBUST.as_array()[None, :], 1).row(0)["gain_margin_db"]  # fmt: skip
    assert good["margins"]["test2"]["gain_margin_db"] == pytest.approx(linear, abs=0.5)
    assert linear >= margin_floor_db()
    assert set(good["objective_cost"]) == {"test2"}
    bad = rows["optuna"]
    assert not bad["admitted"]
    assert bad["margins"]["test4"]["gain_margin_db"] == 0.0  # oscillates without a change


def test_run_episodes_returns_the_environments_returns():
    t = small("grasp", 3)
    stats = run_episodes(t.env_id, t.kwargs_with({"residual": "reference"}),
                         constant_policy([0.0]), t.eval_seeds, grasp=True)  # fmt: skip
    for seed, ret, held, trip in zip(t.eval_seeds, stats.returns, stats.held, stats.tripped,
                                     strict=True):  # fmt: skip
        env = gym.make(t.env_id, **t.kwargs_with({"residual": "reference"}))
        env.reset(seed=seed)
        total, done, infos = 0.0, False, []
        while not done:
            _, r, te, tr, info = env.step(np.zeros(1, np.float32))
            total, done = total + r, te or tr
            infos.append(info)
        assert ret == total
        assert trip == infos[-1]["trip"] and not held  # command = reference: a full stall


@pytest.mark.parametrize(
    ("name", "iface"),
    [("robust", {"residual": "reference"}), ("servo", {}), ("gain-schedule", {})],
)
def test_run_episodes_on_the_vector_env_equals_the_single_envs(name, iface, monkeypatch):
    """The ids with a native vector form run their evaluation episodes on it: returns,
    lengths, ends and the summed constraint costs equal one gym.make per episode."""
    t = small(name, 6)
    kwargs = t.kwargs_with(iface)
    rng = np.random.default_rng(1)
    weights = rng.normal(0.0, 0.8, (gym.make(t.env_id, **kwargs).observation_space.shape[0], 3))

    def policy(obs):
        n_act = 3 if "GainSchedule" in t.env_id else 1
        return np.tanh(obs @ weights[:, :n_act]).astype(np.float32)

    fast = run_episodes(t.env_id, kwargs, policy, t.eval_seeds, batch=4)
    spec = gym.spec(t.env_id)
    assert spec.vector_entry_point is not None
    monkeypatch.setattr(spec, "vector_entry_point", None)
    slow = run_episodes(t.env_id, kwargs, policy, t.eval_seeds, batch=4)
    np.testing.assert_array_equal(fast.returns, slow.returns)
    np.testing.assert_array_equal(fast.lengths, slow.lengths)
    np.testing.assert_array_equal(fast.terminated, slow.terminated)
    assert fast.sums.keys() == slow.sums.keys() == ({"cost", "cost_swing", "cost_stop"}
                                                   if name == "robust" else set())  # fmt: skip
    for key in fast.sums:
        np.testing.assert_array_equal(fast.sums[key], slow.sums[key])


def test_the_limit_may_cover_the_first_episodes_of_the_set(tmp_path, monkeypatch):
    """limit_episodes: the limit's seeds are the set's first ones, a quick look keeps at most
    as many, and a value outside 2..episodes is one line naming the key."""
    t = task("robust")
    assert t.limit_episodes < t.episodes
    assert t.limit_seeds == t.eval_seeds[: t.limit_episodes]
    short = t.first(64)
    assert short.limit_seeds == t.eval_seeds[:64]
    assert task("worn").limit_seeds == task("worn").eval_seeds
    import gripper_env.io.config as config
    from gripper_env.io.config import ConfigError
    from tuners.rl import suite

    root = tmp_path / "configs"
    (root / "rl_zoo" / "tasks").mkdir(parents=True)
    src = config.CONFIG_DIR / "rl_zoo"
    for f in ("robust-ppo.yml", "robust-sac.yml"):
        (root / "rl_zoo" / "tasks" / f).write_text((src / "tasks" / f).read_text())
    import yaml

    entry = yaml.safe_load((src / "tasks.yaml").read_text())["robust"]
    entry["limit_episodes"] = entry["episodes"] + 1
    (root / "rl_zoo" / "tasks.yaml").write_text(yaml.safe_dump({"robust": entry}))
    monkeypatch.setattr(suite, "CONFIG_DIR", root)
    suite.load_tasks.cache_clear()
    try:
        with pytest.raises(ConfigError, match="limit_episodes must be an int from 2 to episodes"):
            suite.load_tasks()
    finally:
        monkeypatch.undo()
        suite.load_tasks.cache_clear()
