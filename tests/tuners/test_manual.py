import csv
import json

import pytest

from tests.tuners.conftest import run_cli
from tuners import cli, manual


def run(argv, capsys):
    code = cli.run(manual.main, [str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_paper_untuned_overshoots_and_tuned_does_not(tmp_path, capsys, small_eval_config):
    base = ["--plant", "test2", "--out", tmp_path, "--json", "--eval-config", small_eval_config]
    code, out, _ = run([*base, "--gains", "paper-untuned"], capsys)
    assert code == 0
    untuned = json.loads(out)
    code, out, _ = run([*base, "--gains", "paper-tuned"], capsys)
    tuned = json.loads(out)
    # the paper's Figure 11 on the model (TF test2): about 40 % overshoot untuned, none tuned
    assert 35 < untuned["metrics"]["ideal"]["grip"]["overshoot_pct"] < 45
    assert tuned["metrics"]["ideal"]["grip"]["overshoot_pct"] < 1
    # and on the actual gripper (Figure 11a): the untuned gains overshoot until the stops
    assert untuned["metrics"]["actual"]["mean"]["grip"]["overshoot_pct"] > 5
    assert tuned["metrics"]["actual"]["mean"]["grip"]["overshoot_pct"] < 3
    assert untuned["robustness"]["stable"] and tuned["robustness"]["stable"]
    # with the servo's 20 ms hold the untuned gains have 3.2 dB of gain margin: not robust
    assert not untuned["robustness"]["meets_constraints"]
    assert tuned["robustness"]["meets_constraints"]
    for name in ("manual-paper-untuned", "manual-paper-tuned"):
        assert (tmp_path / "test2" / f"{name}.json").is_file()
        assert (tmp_path / "test2" / f"{name}.png").stat().st_size > 10_000
    # who ran it, when, on what: not in the gains file, in the run's one sidecar
    assert tuned["provenance"]["command"].startswith("python -m tuners.manual")
    assert not {"version", "git_commit", "date", "wall_time_s"} & set(tuned["provenance"])
    sidecar = json.loads((tmp_path / "test2" / "manual-paper-tuned.provenance.json").read_text())
    assert sidecar["format"] == "gripper-provenance" and sidecar["date"] and sidecar["version"]
    assert "git_commit" in sidecar and sidecar["machine"]["cpus"] >= 1
    assert sidecar["command"] == tuned["provenance"]["command"]
    assert "/provenance/wall_time_s" in sidecar["files"]["manual-paper-tuned.json"]
    assert sorted(p.name for p in (tmp_path / "test2").iterdir()) == [
        f"{name}{ext}" for name in ("manual-paper-tuned", "manual-paper-untuned")
        for ext in (".json", ".png", ".provenance.json")
    ]  # fmt: skip


def test_hardware_gains_use_the_opposite_sign_and_say_so(tmp_path, capsys, small_eval_config):
    code, out, _ = run(
        [
            "--plant",
            "test2",
            "--gains",
            "paper-hw-tuned",
            "--out",
            tmp_path,
            "--eval-config",
            small_eval_config,
        ],
        capsys,
    )
    assert code == 0
    assert "e = y - r" in out and "note:" in out
    content = json.loads((tmp_path / "test2" / "manual-paper-hw-tuned.json").read_text())
    assert content["sign"] == -1 and content["robustness"]["stable"]
    assert content["metrics"]["actual"]["stable_fraction"] == 1.0


def test_typed_gains_table_and_trajectory(tmp_path, capsys, small_eval_config):
    csv_path = tmp_path / "run.csv"
    code, out, _ = run(
        [
            "--plant",
            "test3",
            "--gains",
            "1,9,-0.001,50",
            "--out",
            tmp_path,
            "--save-trajectory",
            csv_path,
            "--eval-config",
            small_eval_config,
        ],
        capsys,
    )
    assert code == 0
    assert "IAE" in out and "loop as it runs (servo command held 20 ms)" in out
    with csv_path.open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["t_s", "reference_deg", "command_deg", "position_deg"]
    assert len(rows) == 20001
    content = json.loads((tmp_path / "test3" / "manual.json").read_text())
    assert content["N"] == 50.0


def test_a_gains_file_can_be_evaluated_on_another_plant(tmp_path, capsys, small_eval_config):
    run(
        [
            "--plant",
            "test2",
            "--gains",
            "paper-tuned",
            "--out",
            tmp_path,
            "--eval-config",
            small_eval_config,
        ],
        capsys,
    )
    code, out, _ = run(
        [
            "--plant",
            "test4",
            "--gains",
            tmp_path / "test2" / "manual-paper-tuned.json",
            "--out",
            tmp_path,
            "--eval-config",
            small_eval_config,
        ],
        capsys,
    )
    assert code == 0 and "gains from" in out


@pytest.mark.parametrize(
    "args, message",
    [
        (["--plant", "test9", "--gains", "paper-tuned"], "unknown plant 'test9'"),
        (["--plant", "test2", "--gains", "1,x,3"], "--gains must be"),
        (["--plant", "test2", "--gains", "1,nan,3"], "--gains must be"),
        (
            ["--plant", "test2", "--gains", "paper-tuned", "--disturbance", "nope"],
            "unknown disturbance",
        ),
        (["--plant", "test2", "--gains", "paper-tuned", "--profile", "nope"], "unknown reference"),
    ],
)
def test_bad_input_is_one_line_exit_2_nothing_written(tmp_path, capsys, args, message):
    out_dir = tmp_path / "results"
    code, _, err = run([*args, "--out", out_dir], capsys)
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err
    assert not out_dir.exists()


def test_malformed_config_and_incompatible_gains_file(tmp_path, capsys):
    bad = tmp_path / "eval.yaml"
    bad.write_text("pid:\n  output_limits_deg: [180, 0]\n")
    out_dir = tmp_path / "results"
    code, _, err = run(
        ["--plant", "test2", "--gains", "paper-tuned", "--out", out_dir, "--eval-config", bad],
        capsys,
    )
    assert code == 2 and "output_limits_deg" in err and str(bad) in err
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"format": "gripper-gains", "format_version": 0, "P": 1}))
    code, _, err = run(["--plant", "test2", "--gains", old, "--out", out_dir], capsys)
    assert code == 2 and "format version" in err
    assert not out_dir.exists()


def test_command_line_bad_input_has_no_traceback(tmp_path):
    proc = run_cli("tuners.manual", "--plant", "test2", "--gains", "a,b,c", "--out", tmp_path / "r")
    assert proc.returncode == 2
    assert proc.stderr.startswith("error:") and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1
    assert not (tmp_path / "r").exists()


def test_help_documents_every_flag():
    proc = run_cli("tuners.manual", "--help")
    assert proc.returncode == 0
    for flag in (
        "--plant",
        "--disturbance",
        "--profile",
        "--seed",
        "--out",
        "--json",
        "--gains",
        "--save-trajectory",
        "--sign",
    ):
        assert flag in proc.stdout
