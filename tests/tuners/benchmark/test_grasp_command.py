"""``python -m tuners.benchmark.grasp``: the files it writes, a row per controller, more rows
from other grippers, and the benchmark report's section. Two held-out seeds keep it fast."""

import json
import math

import pytest

from gripper_env.evaluation.grasp import GraspResult, GraspScenario
from gripper_env.io.files import VOLATILE_KEYS
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant
from tests.tuners.conftest import REPO
from tuners.benchmark import grasp
from tuners.settings import EvaluationSettings

#: The controllers of the committed table: the servo alone, the paper's two presets and the
#: committed gains files, each PID plain and with the grasp mode.
CONTROLLERS = 1 + 2 * (len(grasp.PAPER_PRESETS) + len(grasp.COMMITTED_ROWS))


def test_the_command_writes_the_table_the_json_and_the_figure(tmp_path, capsys):
    out = tmp_path / "results"
    args = ["--out", str(out), "--seeds", "2", "--gains-from", str(REPO / "results")]
    assert grasp.main(args) == 0
    for name in ("grasp.md", "grasp.json", "grasp.provenance.json", "figures/grasp.png"):
        assert (out / name).is_file(), name
    content = json.loads((out / "grasp.json").read_text())
    every = [GraspResult.from_dict(r) for r in content["rows"]]
    rows = [r for r in every if r.gripper.startswith("arduino")]
    assert len(rows) == CONTROLLERS  # one row per controller, each named once
    assert len({r.controller for r in rows}) == CONTROLLERS
    assert rows[0].controller == "servo alone (no host loop)"
    assert rows[1].controller.startswith("paper-tuned P=1 I=9 D=-0.001")
    assert rows[2].controller.startswith("paper-tuned + grasp mode P=1 I=9 D=-0.001")
    assert any(r.controller.startswith("optuna P=") for r in rows)
    # the plain PIDs wind up and trip; with the grasp mode the fast ones hold, cool
    for plain, mode in zip(rows[1::2], rows[2::2], strict=True):
        assert mode.controller.startswith(plain.controller.split(" P=")[0] + " + grasp mode")
        assert plain.overload and not mode.overload and mode.peak_heat < 0.5
        assert mode.held or "paper-hw-tuned" in mode.controller  # slow: reaches it late
    assert content["grasp_mode"] == {"squeeze_deg": 1.0, "push_deg": 5.0, "short_deg": 0.5,
                                     "still_deg": 1.0, "dwell_s": 0.1}  # fmt: skip
    assert {r.gripper for r in rows} == {"arduino test2 (actual)"}
    # then the bus servos' rows: the committed tuned registers, the factory's, the community's
    bus = [r.controller.split(" P=")[0] for r in every[len(rows) :]]
    assert bus == ["tuned", "factory", "lerobot", "tuned", "factory"]
    assert "**Bus servos**" in (out / "grasp.md").read_text()
    assert content["gripper"]["seeds"] == [100000, 100001]
    assert content["scenario"] == GraspScenario().as_dict()
    md = (out / "grasp.md").read_text()
    table = [line for line in md.splitlines() if line.startswith("| arduino")]
    assert len(table) == CONTROLLERS
    assert "| gripper | controller | time to grasp s | holding force N (% of stall)" in md
    assert "**The grasp mode**" in md and "With the grasp mode:" in md
    # no run's date, version or wall time in the results (they are the sidecar's)
    assert not set(content) & set(VOLATILE_KEYS)
    assert json.loads((out / "grasp.provenance.json").read_text())["command"].startswith(
        "python -m tuners.benchmark.grasp --out"
    )
    assert "wrote" in capsys.readouterr().out


def test_other_grippers_add_their_rows(tmp_path):
    other = GraspResult("bus servo (virtual)", "its own loop", 0.3, 2.0, 20.0, 1.9, False, None,
                        True, 3.0)  # fmt: skip
    rows = grasp.grasp_rows("test2", extra=[lambda: [other]], seeds=[100000], gains_from=None)
    assert [r.controller.split(" P=")[0] for r in rows] == [
        "servo alone (no host loop)", "paper-tuned", "paper-tuned + grasp mode", "paper-untuned",
        "paper-untuned + grasp mode", "its own loop",
    ]  # fmt: skip
    md = grasp.render_markdown(rows)
    assert (
        "| bus servo (virtual) | its own loop | 0.300 | 2.00 (20 %) | 1.90 | - | no | yes |" in md
    )
    # and through the command
    out = tmp_path / "out"
    assert grasp.main(["--out", str(out), "--seeds", "1", "--gains-from", str(tmp_path)],
                      extra=[lambda: [other]]) == 0  # fmt: skip
    content = json.loads((out / "grasp.json").read_text())
    assert content["rows"][-1]["gripper"] == "bus servo (virtual)"


def test_missing_gains_files_are_left_out_and_said(tmp_path, capsys):
    assert grasp.main(["--out", str(tmp_path), "--seeds", "1", "--gains-from",
                       str(tmp_path / "none"), "--bus"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "optuna.json: not found, its row left out" in out
    assert len(json.loads((tmp_path / "grasp.json").read_text())["rows"]) == 5


def test_the_bus_servos_rows_judge_their_registers_on_the_hold(tmp_path):
    """The tuned registers file's set holds where the factory set trips its overload; the rows
    are the hold metrics of the bus-servo evaluation, recomputed here from the simulation."""
    from gripper_env.evaluation.bus_servo import hold_goal, hold_metrics
    from gripper_env.model.bus_servo import RegisterSet, load_bus_servo
    from gripper_env.sim.bus_servo import simulate_bus

    model = load_bus_servo("sts3215")
    tuned = RegisterSet(p=90, i=0, d=105, torque_limit=790, deadband=1)
    (tmp_path / "bus").mkdir()
    (tmp_path / "bus" / "sts3215_registers.json").write_text(
        json.dumps({"model": model.model_dump(), "registers": tuned.model_dump()})
    )
    rows = grasp.bus_rows("sts3215", tmp_path)
    assert [r.controller.split(" P=")[0] for r in rows] == ["tuned", "factory", "lerobot"]
    t, factory, _lerobot = rows
    assert t.held and not t.overload
    assert factory.overload and factory.overload_at_s == pytest.approx(
        model.protection.overload_time_s, abs=0.05
    )
    run = simulate_bus(model, [tuned], hold_goal(model), with_object=True)
    truth = hold_metrics(model, run)
    assert t.holding_force_n == pytest.approx(truth.holding_force_n)
    assert t.holding_force_pct == pytest.approx(100 * truth.holding_force_n / model.stall_force_n())
    # without a registers file: the shipped sets only; a registers file of another servo refused
    assert len(grasp.bus_rows("sts3215", tmp_path / "none")) == 2
    (tmp_path / "bus" / "xl330_registers.json").write_text(
        (tmp_path / "bus" / "sts3215_registers.json").read_text()
    )
    with pytest.raises(ValueError, match="registers of a sts3215, not a xl330"):
        grasp.bus_rows("xl330", tmp_path)


def test_bad_input_is_refused_with_one_line(tmp_path, capsys):
    assert grasp.main(["--out", str(tmp_path), "--seeds", "0"]) == 2
    assert "--seeds must be 1 to 10" in capsys.readouterr().err
    assert grasp.main(["--out", str(tmp_path), "--plant", "nosuch"]) == 2
    assert "nosuch" in capsys.readouterr().err
    assert grasp.main(["--out", str(tmp_path), "--seeds", "1", "--bus", "nosuch"]) == 2
    err = capsys.readouterr().err
    assert "nosuch" in err and "sts3215" in err and len(err.strip().splitlines()) == 1


def test_a_grasp_that_never_happens_reads_never():
    row = GraspResult("g", "c", math.nan, 0.0, 0.0, 0.0, True, 2.5, False, 3.0)
    (line,) = [x for x in grasp.table_lines([row]) if x.startswith("| g |")]
    assert line == "| g | c | never | 0.00 (0 %) | 0.00 | - | yes (2.50) | **no** |"


def test_the_benchmark_section_from_its_rows():
    """The benchmark's rows (PIDs and a learned controller, left out) through the scenario,
    and the report's section rendered again from their JSON."""
    rows = {
        "manual-paper-tuned": {"controller": "pid", "P": 1.0, "I": 9.0, "D": -0.001, "N": 100.0,
                               "sign": 1},
        "rl-controller": {"controller": "ppo-residual", "P": 3.4, "I": 67.5, "D": 0.0,
                          "N": 100.0, "sign": 1},
    }  # fmt: skip
    settings = EvaluationSettings(seeds={"start": 100000, "count": 1})
    got = grasp.benchmark_grasp(load_plant("test2"), load_disturbance("actual"), rows, settings)
    assert [r["controller"].split(" P=")[0] for r in got] == [
        "servo alone (no host loop)",
        "manual-paper-tuned",
        "manual-paper-tuned + grasp mode",
    ]
    assert [r["held"] for r in got] == [True, False, True]
    data = {"scenario": GraspScenario().as_dict(), "plants": {"test2": got}}
    lines = grasp.benchmark_section(data)
    assert "## Grasp and hold" in lines and "### test2: 2 of 3 held" in lines
    stored = json.loads(json.dumps(data, default=str).replace("NaN", "null"))
    assert grasp.benchmark_section(stored) == lines


@pytest.mark.parametrize("name", ["grasp.md", "grasp.json", "figures/grasp.png"])
def test_the_committed_results_are_registered(name):
    """The command is one of the committed results' commands and its files are listed."""
    from tuners import results

    (command,) = [c for c in results.COMMANDS if c.name == "grasp"]
    assert command.line == "python -m tuners.benchmark.grasp --out results"
    manifest = json.loads((REPO / "results" / "manifest.json").read_text())["commands"]
    assert f"results/{name}" in manifest["grasp"]["writes"]
