import json

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip(
    "gripper_env.envs", reason="tuners.rl needs the Gymnasium environments (gripper_env.envs)"
)

from gripper_env.pid import PIDOptions
from tuners import cli, rl


def test_train_then_export_a_gains_file(tmp_path, capsys, small_eval_config):
    common = ["--plant", "test2", "--out", str(tmp_path), "--eval-config", str(small_eval_config)]
    code = cli.run(
        rl.main,
        ["train", *common, "--timesteps", "512", "--n-envs", "16", "--eval-every", "128", "--json"],
    )
    assert code == 0, capsys.readouterr().err
    facts = json.loads(capsys.readouterr().out)
    run = tmp_path / "rl" / "pid-tune-ppo-test2"
    assert (run / "model.zip").is_file() and (run / "tb").is_dir()
    best = [c for _, c in facts["history"]]
    assert best and best == sorted(best, reverse=True)
    code = cli.run(rl.main, ["export", *common, "--json"])
    assert code == 0
    content = json.loads(capsys.readouterr().out)
    assert content["tuner"] == "rl" and content["tuning"]["held_out_plant"] is False
    assert (tmp_path / "test2" / "rl.json").is_file()


def test_plant_conditioned_policy_exports_for_a_held_out_plant(tmp_path, capsys, small_eval_config):
    common = ["--out", str(tmp_path), "--eval-config", str(small_eval_config)]
    code = cli.run(
        rl.main,
        [
            "train",
            "--plant",
            "test2,test3",
            *common,
            "--timesteps",
            "256",
            "--eval-every",
            "256",
            "--json",
        ],
    )
    assert code == 0, capsys.readouterr().err
    capsys.readouterr()
    code = cli.run(
        rl.main,
        ["export", "--plant", "test4", "--run", "pid-tune-ppo-test2+test3", *common, "--json"],
    )
    assert code == 0
    content = json.loads(capsys.readouterr().out)
    assert content["plant"] == "test4" and content["tuning"]["held_out_plant"] is True
    assert content["tuner"] == "rl-conditioned"


def test_export_without_a_model_is_bad_input(tmp_path, capsys):
    code = cli.run(rl.main, ["export", "--plant", "test2", "--out", str(tmp_path / "r")])
    assert code == 2 and "no trained model" in capsys.readouterr().err


def test_gain_schedule_policy_reports_metrics(tmp_path, capsys, small_eval_config):
    common = [
        "--plant",
        "test2",
        "--out",
        str(tmp_path),
        "--eval-config",
        str(small_eval_config),
        "--env",
        "gain-schedule",
    ]
    code = cli.run(
        rl.main,
        [
            "train",
            *common,
            "--timesteps",
            "64",
            "--n-envs",
            "1",
            "--eval-every",
            "100000",
            "--json",
        ],
    )
    assert code == 0, capsys.readouterr().err
    capsys.readouterr()
    code = cli.run(rl.main, ["export", *common, "--json"])
    assert code == 0, capsys.readouterr().err
    content = json.loads(capsys.readouterr().out)
    assert content["tuner"] == "rl-gain-schedule"
    assert content["metrics"]["actual"]["n_seeds"] == 3
    assert "iae" in content["metrics"]["actual"]["mean"]


def test_controller_trains_and_scores_against_its_baselines(tmp_path, capsys, small_eval_config):
    """The RL controller's row: the policy's metrics beside its baselines, and the baselines are
    what every tuner's evaluation gives the base PID and command = reference."""
    import yaml

    from gripper_env.config import CONFIG_DIR
    from gripper_env.pid import PIDGains
    from tuners.evaluation import evaluate

    config = yaml.safe_load((CONFIG_DIR / "tuners" / "rl_controller.yaml").read_text())
    config.update(n_envs=4, n_steps=32, batch_size=64, n_epochs=2, checkpoints=1, net_arch=[16])
    path = tmp_path / "controller.yaml"
    path.write_text(yaml.safe_dump(config))
    code = cli.run(
        rl.main,
        ["controller", "--plant", "test2", "--out", str(tmp_path), "--eval-config",
         str(small_eval_config), "--config", str(path), "--base", "2.4,39,0", "--timesteps",
         "256", "--json"],
    )  # fmt: skip
    assert code == 0, capsys.readouterr().err
    content = json.loads(capsys.readouterr().out)
    assert content["tuner"] == "rl-controller" and content["tuning"]["timesteps"] >= 256
    assert content["tuning"]["residual"] == "pid" and content["P"] == 2.4
    actual = content["metrics"]["actual"]
    assert actual["n_seeds"] == 3 and actual["mean"]["iae"] > 0
    seeds = [100000, 100001, 100002]
    options = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")
    pid = evaluate("test2", PIDGains(2.4, 39.0, 0.0, 100.0), options, seeds=seeds)
    base = content["tuning"]["baselines"]["base"]["actual"]["mean"]
    assert base["iae"] == pytest.approx(pid.actual["mean"]["iae"], rel=1e-12)
    assert base["cost"] == pytest.approx(pid.actual["mean"]["cost"], rel=1e-12)
    open_loop = content["tuning"]["baselines"]["command_equals_reference"]["actual"]["mean"]
    assert open_loop["iae"] > 2 * base["iae"]  # the servo alone lags and sticks
    assert (tmp_path / "rl" / "controller-test2" / "best" / "model.zip").is_file()
    assert (tmp_path / "test2" / "rl-controller.png").is_file()


def test_controller_base_pid_is_required_and_checked(tmp_path, capsys):
    code = cli.run(rl.main, ["controller", "--plant", "test2", "--out", str(tmp_path)])
    assert code == 2 and "python -m tuners.optuna" in capsys.readouterr().err
    code = cli.run(rl.main, ["controller", "--plant", "test2", "--base", "1,nan,0"])
    assert code == 2 and "--base" in capsys.readouterr().err
