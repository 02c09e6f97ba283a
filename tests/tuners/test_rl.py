import json

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip(
    "gripper_env.envs", reason="tuners.rl needs the Gymnasium environments (gripper_env.envs)"
)

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
