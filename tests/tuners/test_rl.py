"""The RL tuners: the commands as printed, the tuner's export, the controller's study."""

import json
import math
import re
import shlex
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from gripper_env.evaluation.objective import load_objective
from gripper_env.evaluation.stability import stability_report
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from tests.tuners.conftest import REPO
from tuners import cli
from tuners.rl import command as rl
from tuners.settings import OptunaSettings, load_settings

TEST2 = load_plant("test2")
ACTUAL, IDEAL = load_disturbance("actual"), load_disturbance("ideal")
OBJECTIVE = load_objective()

#: The budget option appended to each command of the README and docs (the only change).
BUDGET = {
    "train": ["--timesteps", "256"],
    "controller": ["--timesteps", "4096"],
    "tuners.optuna": ["--trials", "16", "--search-seeds", "1"],
}


def _printed_commands() -> list[str]:
    """Every ``python -m tuners.rl`` command printed in the README and docs/, in order, with
    the ``python -m tuners.optuna`` commands before them that they build on, and the manual and
    classical tuners' commands."""
    out = []
    for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for line in path.read_text().splitlines():
            m = re.match(r"^\s*(?:\$ )?(python -m tuners\.(?:rl|optuna|manual|classical) [^#`]*)",
                         line)  # fmt: skip
            if m:
                out.append(m.group(1).strip())
    return out


def _git_status() -> str:
    return subprocess.run(["git", "status", "--porcelain"], cwd=REPO, capture_output=True,
                          text=True).stdout  # fmt: skip


@pytest.mark.readme  # a part of the README walk (tests/test_readme_walk.py): run with it, in CI
def test_the_readme_rl_commands_run_as_printed(tmp_path):
    """Issue 19: every RL command the README and docs print exits 0 from a fresh directory,
    progress shown, with only its budget shortened (``--timesteps``, documented). Issue 21: the
    walk-through changes nothing in the repository (runs go to ./runs)."""
    before = _git_status()
    commands = _printed_commands()
    assert any(" tuners.rl train" in c for c in commands)
    assert any(" tuners.rl controller" in c for c in commands)
    assert any(" tuners.rl play" in c for c in commands)
    (tmp_path / "results").symlink_to(REPO / "results")  # the committed agents, as printed
    for command in commands:
        if "runs/rl_zoo" in command:
            continue  # needs an rl-zoo3 run first: the README walk trains one and runs it
        argv = shlex.split(command)
        if argv[2] == "tuners.optuna" and ("--plants" in argv or "test" not in argv[4]):
            continue  # not the base PID an RL command builds on
        key = argv[3] if argv[2] == "tuners.rl" else argv[2]
        argv = [sys.executable, *argv[1:], *BUDGET.get(key, [])]
        proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, f"{command}\n{proc.stderr[-3000:]}"
        assert "Traceback" not in proc.stderr, command
        if key in ("train", "controller"):
            assert "step/s" in proc.stderr or "it/s" in proc.stderr or "%|" in proc.stderr
    assert (tmp_path / "runs").is_dir() and _git_status() == before


def test_a_missing_rl_extra_is_one_line(monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "torch" else real(name, *a))  # fmt: skip
    code = rl.main(["train", "--plant", "test2"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "torch" in err and "gripper-env[rl]" in err


@pytest.mark.slow
def test_the_tuner_exports_the_best_evaluated_gains(tmp_path, capsys, small_eval_config):
    common = ["--plant", "test2", "--out", str(tmp_path), "--eval-config", str(small_eval_config)]
    code = rl.main(["train", *common, "--timesteps", "1024", "--no-progress", "--json"])
    assert code == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    run = json.loads((tmp_path / "rl" / "pid-tune-test2" / "seed-0" / "history.json").read_text())
    evaluated = [e for e in run["evaluations"] if e["feasible"] and not e["on_bound"]]
    best = min(evaluated, key=lambda e: e["tuning_cost"])
    assert summary["per_seed"][0]["gains"] == best["gains"]
    # the first evaluation is the centre design: the textbook rule with its knob set
    assert run["evaluations"][0]["episodes"] == 0 and run["center"]["rule"] == "simc"
    code = rl.main(["export", *common, "--json"])
    assert code == 0
    content = json.loads(capsys.readouterr().out)
    assert [content[k] for k in "PIDN"] == pytest.approx(best["gains"])
    t = content["tuning"]
    assert t["chosen_seed"] == 0 and t["at_episodes"] == best["episodes"]
    assert t["best_value_tuning"] == pytest.approx(best["tuning_cost"])
    # the exported gains meet the constraints on the loop as it runs (checked independently)
    from gripper_env.model.pid import PIDGains

    assert stability_report(TEST2, PIDGains(*best["gains"]), disturbance=ACTUAL).meets(1.6, 6.0)


@pytest.mark.slow
def test_the_same_seed_gives_the_same_gains(tmp_path, small_eval_config):
    from tuners.rl.tune import load_tune_settings, train_tuner

    args = ["--plant", "test2", "--eval-config", str(small_eval_config)]
    inputs = cli.resolve(rl.build_parser().parse_args(["export", *args]))
    s = load_tune_settings().model_copy(update={"eval_every": 128})
    runs = [train_tuner(inputs, s, seed=3, run_dir=tmp_path / f"r{i}", episodes=512,
                        progress=False, log=lambda m: None) for i in range(2)]  # fmt: skip
    assert runs[0]["best"]["gains"] == runs[1]["best"]["gains"]
    assert [e["tuning_cost"] for e in runs[0]["evaluations"]] == [
        e["tuning_cost"] for e in runs[1]["evaluations"]
    ]


@pytest.mark.slow
def test_the_controller_study_uses_three_disjoint_seed_sets_and_measures_margins(
    tmp_path, capsys, small_eval_config
):
    import yaml

    from gripper_env.io.config import CONFIG_DIR
    from tuners.evaluation import evaluate
    from tuners.rl.agents import agent_kwargs, load_agent
    from tuners.rl.controller import evaluate_policy

    config = yaml.safe_load((CONFIG_DIR / "tuners" / "rl_controller.yaml").read_text())
    config.update(n_envs=4, n_steps=64, batch_size=64, n_epochs=2, checkpoints=2, net_arch=[16])
    config["validation_seeds"] = {"start": 200000, "count": 2}
    path = tmp_path / "controller.yaml"
    path.write_text(yaml.safe_dump(config))
    code = rl.main(["controller", "--plant", "test2", "--out", str(tmp_path), "--eval-config",
                    str(small_eval_config), "--config", str(path), "--base", "2.4,39,0",
                    "--timesteps", "512", "--seeds", "2", "--no-progress", "--json"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    content = json.loads(capsys.readouterr().out)
    assert content["tuner"] == "rl-controller" and content["training_seeds"] == [0, 1]
    # validation, tuning and held-out seeds are three disjoint sets
    study = json.loads((tmp_path / "rl" / "controller-test2" / "study.json").read_text())
    validation = set(study["seeds"][0]["training"]["validation_seeds"])
    tuning = set(load_settings(OptunaSettings).tuning_seeds.seeds().tolist())
    held_out = set(content["evaluation"]["seeds"])
    assert not (validation & tuning) and not (validation & held_out) and not (tuning & held_out)
    # the base's figures are what every tuner's evaluation gives that PID
    options = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")
    pid = evaluate(
        TEST2, PIDGains_(2.4, 39.0, 0.0), options, profile=load_reference("step", TEST2.dt_s),
        disturbance=ACTUAL, ideal=IDEAL, objective=OBJECTIVE, seeds=sorted(held_out),
    )  # fmt: skip
    assert content["base"]["actual"]["mean"]["cost"] == pytest.approx(
        pid.actual["mean"]["cost"], rel=1e-12
    )
    # the base PID's measured gain margin is its linear one (the probe's validation)
    linear = stability_report(TEST2, PIDGains_(2.4, 39.0, 0.0), disturbance=ACTUAL).gain_margin_db
    assert content["base"]["measured_margins"]["gain_margin_db"] == pytest.approx(linear, abs=0.3)
    assert set(content["measured_margins"]["per_seed"]) == {"0", "1"}
    # per held-out seed, the row's cost is the mean over the training seeds
    per_seed = np.array([[r["cost"] for r in e["plants"]["test2"]["runs"]]
                         for e in study["seeds"]])  # fmt: skip
    assert content["per_seed_cost"] == pytest.approx(per_seed.mean(axis=0).tolist())
    # a saved agent loads alone and reproduces its held-out runs
    agent = load_agent(tmp_path / "rl" / "controller-test2" / "seed-1" / "best")
    assert agent.base is not None and agent.base.P == 2.4
    inputs = cli.resolve(rl.build_parser().parse_args(
        ["export", "--plant", "test2", "--eval-config", str(small_eval_config)]))  # fmt: skip
    _, runs, _, _ = evaluate_policy(agent, inputs, agent_kwargs(agent), np.array(sorted(held_out)))
    assert [r["cost"] for r in runs] == pytest.approx(
        [r["cost"] for r in study["seeds"][1]["plants"]["test2"]["runs"]], rel=1e-9
    )
    assert (tmp_path / "rl" / "controller-test2" / "learning_curve.png").is_file()


def PIDGains_(p, i, d):
    from gripper_env.model.pid import PIDGains

    return PIDGains(p, i, d, 100.0)


def test_controller_base_pid_is_required_and_checked(tmp_path, capsys):
    code = rl.main(["controller", "--plant", "test2", "--out", str(tmp_path)])
    assert code == 2 and "python -m tuners.optuna" in capsys.readouterr().err
    code = rl.main(["controller", "--plant", "test2", "--base", "1,nan,0"])
    assert code == 2 and "--base" in capsys.readouterr().err


@pytest.mark.parametrize("bad", ["0", "1-", "a,b", "3,3", "-2"])
def test_bad_seeds_are_one_line(bad, tmp_path, capsys):
    code = rl.main(["train", "--plant", "test2", "--seeds", bad, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "--seeds" in err and "Traceback" not in err


def test_export_without_a_run_is_bad_input(tmp_path, capsys):
    code = rl.main(["export", "--plant", "test2", "--out", str(tmp_path / "r")])
    assert code == 2 and "no trained tuner" in capsys.readouterr().err


@pytest.mark.slow
def test_a_policy_on_a_step_by_step_env_trains_and_reports(tmp_path, capsys, small_eval_config):
    code = rl.main(["train", "--plant", "test2", "--env", "gain-schedule", "--timesteps", "64",
                    "--out", str(tmp_path), "--eval-config", str(small_eval_config),
                    "--no-progress", "--json"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    content = json.loads(capsys.readouterr().out)
    assert content["tuner"] == "rl-gain-schedule"
    r = content["seeds"][0]
    assert r["metrics"]["actual"]["n_seeds"] == 3 and math.isfinite(r["per_seed_cost"][0])
    assert (
        tmp_path / "rl" / "gain-schedule-ppo-test2" / "seed-0" / "agent" / "agent.json"
    ).is_file()


@pytest.mark.slow
def test_play_runs_a_saved_agent_on_another_plant(tmp_path, capsys, small_eval_config):
    code = rl.main(["train", "--plant", "test2", "--env", "servo", "--timesteps", "64",
                    "--out", str(tmp_path), "--no-progress", "--json",
                    "--eval-config", str(small_eval_config)])  # fmt: skip
    assert code == 0
    capsys.readouterr()
    agent = tmp_path / "rl" / "servo-ppo-test2" / "seed-0" / "agent"
    code = rl.main(["play", str(agent), "--plant", "test4", "--out", str(tmp_path),
                    "--eval-config", str(small_eval_config)])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0 and "agent on test4" in out
    assert (tmp_path / "play" / "test4-actual" / "response.png").is_file()
    code = rl.main(["play", str(tmp_path), "--plant", "test4"])
    assert code == 2 and "no agent in" in capsys.readouterr().err


def test_subprocess_entry_point_reports_bad_input_in_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "tuners.rl", "train", "--plant", "nope"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "nope" in proc.stderr


@pytest.mark.slow
def test_a_tuner_run_with_the_same_recipe_is_reused_not_retrained(tmp_path, small_eval_config):
    from tuners.rl.tune import load_tune_settings, train_seeds

    args = ["--plant", "test2", "--eval-config", str(small_eval_config)]
    inputs = cli.resolve(rl.build_parser().parse_args(["export", *args]))
    s = load_tune_settings().model_copy(update={"eval_every": 128})
    first = train_seeds(inputs, s, [0], tmp_path, episodes=256, progress=False, reuse=True)
    history = tmp_path / "seed-0" / "history.json"
    stamp = history.stat().st_mtime_ns
    again = train_seeds(inputs, s, [0], tmp_path, episodes=256, progress=False, reuse=True)
    assert history.stat().st_mtime_ns == stamp  # read, not trained again
    assert again[0]["best"] == first[0]["best"] and again[0]["gains"] == first[0]["gains"]
    other = s.model_copy(update={"learning_rate": 3e-4})  # another recipe: trained again
    train_seeds(inputs, other, [0], tmp_path, episodes=256, progress=False, reuse=True)
    assert history.stat().st_mtime_ns != stamp


@pytest.mark.slow
def test_the_centre_rule_list_falls_back_to_a_rule_that_meets_the_constraints():
    """SIMC cannot meet the admission rule on test2-test4 at once (Ms; its row says so), nor can
    PIDTUNE (the open stop); the robust RL tuner centres on the next rule of its list, AMIGO PI,
    whose knob the scan sets (the benchmark's robust rows say the same)."""
    from tuners.rl.tune import RLTuneSettings, design_center
    from tuners.tasks import make_scorer

    assert RLTuneSettings(center="migo").center == ["migo"]
    with pytest.raises(ValueError, match="unknown rule 'ziegler'"):
        RLTuneSettings(center=["ziegler"])
    inputs = cli.resolve(rl.build_parser().parse_args(["export", "--plant", "test2"]))
    names = ["test2", "test3", "test4"]
    s = RLTuneSettings(center=["simc", "pidtune", "amigo-pi"])
    gains, record = design_center(inputs, s, names, make_scorer(inputs, None, names))
    assert record["rule"] == "amigo-pi"
    assert record["refused"][0].startswith("simc: infeasible: no setting of tau_c_factor")
    assert record["refused"][1].startswith("pidtune: infeasible: no setting of pidtune_wc_hz")
    assert record["gains"][:3] == [gains.P, gains.I, gains.D]


def test_the_tuners_reward_applies_the_admission_rule_to_each_episode():
    """The RL tuner trains on the searches' rule: an episode whose jaw passes the nearest stop
    the preset can draw (less the searches' back-off) is penalised even if its drawn stop was
    not touched; a calm episode is not."""
    import gymnasium as gym

    import gripper_env.envs  # noqa: F401 - registers the environments
    from tuners.rl.tune import episode_admission

    env = gym.make("gripper_env/GripperPIDTune-v0", plant="test2", disturbance="actual",
                   randomize=True, gain_scaling="relative", gain_center=(0.6925, 17.78, -0.0063),
                   gain_max=(1.0, 1.0, 0.01))  # fmt: skip
    infos = []
    for action in ([0.0, 0.0, 0.0], [-0.3, -0.5, 0.63]):  # the centre overshoots; calm gains
        env.reset(seed=3)
        infos.append(env.step(np.array(action, dtype=np.float32))[4])
    env.close()
    rule = episode_admission(infos, OBJECTIVE, ACTUAL, True)
    lows = [i["jaw_min_deg"] for i in infos]
    need = 15.0 + OBJECTIVE.constraints.limits(search=True)["stop_clearance_deg"]
    assert lows[0] < need and "stop_clearance" in rule.missed(0)
    assert lows[1] > need and rule.feasible[1] and rule.violation[1] == 0.0
    assert rule.violation[0] >= (need - lows[0]) / 10.0  # 10 deg past is one unit


def test_robust_controller_training_draws_raised_gains_half_the_time():
    from tuners.rl.controller import ControllerSettings, training_plants

    s = ControllerSettings(gain_spread_db=9.0, gain_levels=3)
    plants = training_plants(["test2", "test4"], s)
    assert len(plants) == 12
    ratios = [p.num[-1] / load_plant(p.name.split("*")[0]).num[-1] for p in plants]
    nominal = [r for r in ratios if r == pytest.approx(1.0)]
    assert len(nominal) == 6  # half nominal
    raised = sorted({round(20 * math.log10(r), 6) for r in ratios if r != pytest.approx(1.0)})
    assert raised == pytest.approx([3.0, 6.0, 9.0])
    assert training_plants(["test2"], ControllerSettings()) == ["test2"]


def test_the_floor_check_agrees_with_the_linear_gain_margin():
    """meets_floor on the base PID alone (the zero policy) is the linear margin test: a PID
    with 10 dB passes the 8.5 dB floor, one with 7 dB does not."""
    from gripper_env.model.pid import PIDGains
    from tuners.rl.controller import ControllerSettings, env_kwargs, meets_floor

    inputs = cli.load_inputs("test2")
    zero = lambda obs: np.zeros((len(obs), 1))  # noqa: E731 - the base PID itself
    for gains in ((2.4, 39.0, 0.0), (4.4, 50.0, 0.0)):
        g = PIDGains(*gains, 100.0)
        gm = stability_report(TEST2, g, disturbance=ACTUAL).gain_margin_db
        kwargs = env_kwargs(inputs, g, ControllerSettings())
        assert meets_floor(zero, inputs, kwargs, ["test2"]) == (gm > 8.6), (gains, gm)


def test_a_policys_grasp_is_its_pids_when_it_does_not_correct():
    """The policy grasp scenario (tuners.rl.grasp) with the zero policy is the base PID's own
    grasp verdict (gripper_env.evaluation.grasp.grasp_admission): the same heat and force."""
    from gripper_env.evaluation.grasp import grasp_admission
    from gripper_env.model.pid import PIDGains
    from tuners.rl.controller import ControllerSettings, env_kwargs
    from tuners.rl.grasp import policy_grasp

    inputs = cli.load_inputs("test2")
    g = PIDGains(2.4, 39.0, 0.0, 100.0)
    kwargs = env_kwargs(inputs, g, ControllerSettings())
    seeds = [100000, 100001, 100002]
    zero = lambda obs: np.zeros((len(obs), 1))  # noqa: E731 - the base PID itself
    policy = policy_grasp(zero, kwargs, TEST2, ACTUAL, seeds)
    pid = grasp_admission([[g.P, g.I, g.D]], inputs.settings.options(1)[1], TEST2, ACTUAL, seeds)
    assert policy["held"] == pid.held_runs[0].tolist() == [True] * 3
    assert policy["peak_heat"] == pytest.approx(pid.peak_heat[0].tolist(), abs=0.01)
    assert policy["min_force_n"] == pytest.approx(pid.min_force_n[0].tolist(), rel=0.02)
