"""Hostile input to the bus commands: each case is refused with exit status 2 and one line on
stderr that names the option, or the file and the key, with no traceback. The commands run as
real processes, a few at a time (a refusal takes a few seconds, nearly all of it importing the
package); nothing is sent to a servo in any case (the port does not exist)."""

from __future__ import annotations

import json
import math
import subprocess
from dataclasses import dataclass, replace
from pathlib import Path

import pytest
from bus_arm import command

from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_servo import load_bus_servo

CONCURRENCY = 3
HANG_GUARD_S = 120
NO_PORT = "/no/such/port"


@dataclass(frozen=True)
class Case:
    name: str
    module: str
    args: tuple[str, ...]
    names: tuple[str, ...]


CASES = [
    Case("virtual --link into a missing folder", "tuners.bus.virtual",
         ("--link", "{missing}/sts3215"), ("--link", "does not exist")),
    Case("virtual --link onto a file", "tuners.bus.virtual",
         ("--link", "{a_file}"), ("--link", "a_file", "a file is there")),
    Case("virtual --id -1", "tuners.bus.virtual", ("--id", "-1"), ("--id", "'-1'")),
    Case("virtual --limits reversed", "tuners.bus.virtual",
         ("--limits", "3000", "1000"), ("--limits",)),
    Case("record --id -1", "tuners.bus.record",
         ("--port", NO_PORT, "--id", "-1", "--jaw", "{jaw}"), ("--id", "'-1'")),
    Case("deploy --id -1", "tuners.bus.deploy",
         ("--registers", "{registers}", "--port", NO_PORT, "--id", "-1"), ("--id", "'-1'")),
    Case("calibrate --id 300", "tuners.bus.calibrate",
         ("--port", NO_PORT, "--id", "300"), ("--id", "'300'")),
    Case("record on a model file with kp = inf", "tuners.bus.record",
         ("--port", NO_PORT, "--id", "6", "--model", "{kp_inf}", "--jaw", "{jaw}"),
         ("kp_inf.json", "scale.kp", "finite")),
    Case("tune on a model file with kp = inf", "tuners.bus.tune",
         ("--model", "{kp_inf}", "--out", "{out}"), ("kp_inf.json", "scale.kp")),
    Case("tune on a model with NaN uncertainties", "tuners.bus.tune",
         ("--model", "{nan_unc}", "--out", "{out}"), ("nan_unc.json", "uncertainty.kp", "nan")),
    Case("deploy a registers file with NaN uncertainties", "tuners.bus.deploy",
         ("--registers", "{nan_reg}", "--port", NO_PORT, "--id", "6"),
         ("nan_reg.json", "uncertainty_rel_std.kd")),
    Case("record --jaw missing", "tuners.bus.record",
         ("--port", NO_PORT, "--id", "6", "--jaw", "{missing}/jaw.json"), ("jaw.json",)),
    Case("record --sample-ms 0", "tuners.bus.record",
         ("--port", NO_PORT, "--id", "6", "--jaw", "{jaw}", "--sample-ms", "0"), ("--sample-ms",)),
    Case("record --settings 1,2", "tuners.bus.record",
         ("--port", NO_PORT, "--id", "6", "--settings", "1,2"), ("--settings", "'1,2'")),
    Case("deploy --hold -1", "tuners.bus.deploy",
         ("--registers", "{registers}", "--port", NO_PORT, "--id", "6", "--hold", "-1"),
         ("--hold",)),
    Case("calibrate --closed-ticks alone", "tuners.bus.calibrate",
         ("--port", NO_PORT, "--id", "6", "--closed-ticks", "1800"), ("--closed-ticks",)),
    Case("calibrate --lerobot without the motor", "tuners.bus.calibrate",
         ("--port", NO_PORT, "--id", "6", "--lerobot", "{arm_json}"),
         ("arm.json", "no motor 'gripper'")),
    Case("record on a port that does not exist", "tuners.bus.record",
         ("--port", NO_PORT, "--id", "6", "--jaw", "{jaw}"), (NO_PORT, "nothing was written")),
    # names from files never become paths (gripper_env.io.files.safe_name): deploy's default
    # folder is deploy_<model name> beside the registers, tune writes <model name>_registers
    Case("deploy a registers file whose model name climbs", "tuners.bus.deploy",
         ("--registers", "{climbing_reg}", "--port", NO_PORT, "--id", "6",
          "--allow-infeasible"), ("climbing_reg.json", "model name", "../../escaped")),
    Case("deploy a registers file whose model name holds a NUL", "tuners.bus.deploy",
         ("--registers", "{nul_reg}", "--port", NO_PORT, "--id", "6", "--allow-infeasible"),
         ("nul_reg.json", "model name", "\\x00")),
    Case("tune on a model file whose name climbs", "tuners.bus.tune",
         ("--model", "{climbing_model}", "--trials", "4", "--out", "{out}"),
         ("climbing_model.json", "model name", "../escaped")),
    Case("tune on a model file with an absolute name", "tuners.bus.tune",
         ("--model", "{absolute_model}", "--trials", "4", "--out", "{out}"),
         ("absolute_model.json", "model name", "/escaped-absolute")),
    Case("identify --name climbing out of --out", "tuners.bus.identify",
         ("{missing}/record.csv", "--name", "../escaped", "--out", "{out}"),
         ("--name", "../escaped")),
    Case("identify --out naming a file", "tuners.bus.identify",
         ("{missing}/record.csv", "--out", "{a_file}"), ("--out", "a_file")),
    # records out of what a servo gives: one line naming the file and the line, at once
    Case("identify a record holding 1e308", "tuners.bus.identify",
         ("{rec_huge}", "{rec_good}", "--generations", "1", "--out", "{out}"),
         ("rec_huge.csv", "line 10", "position_deg = 1e+308")),
    Case("identify a record whose time runs backwards", "tuners.bus.identify",
         ("{rec_good}", "{rec_back}", "--out", "{out}"),
         ("rec_back.csv", "line 12", "must increase")),
    Case("identify a record whose goal writes run backwards", "tuners.bus.identify",
         ("{rec_good}", "{rec_goal_back}", "--out", "{out}"),
         ("rec_goal_back.csv", "goal writes' time stamps must increase")),
    Case("identify a record read 9x slower than asked", "tuners.bus.identify",
         ("{rec_good}", "{rec_slow}", "--out", "{out}"),
         ("rec_slow.csv", "against the 2 ms asked", "more than 5x slower")),
    Case("calibrate --closed-ticks 2000 --open-ticks 2000", "tuners.bus.calibrate",
         ("--port", NO_PORT, "--id", "6", "--closed-ticks", "2000", "--open-ticks", "2000"),
         ("--closed-ticks 2000 and --open-ticks 2000 are 0.0 deg apart",)),
]  # fmt: skip


def _records(write) -> None:
    """A record of the shipped STS3215 (simulated, read every 2-4 ms as asked) and copies of
    it spoilt one way each."""
    from gripper_env.sysid.bus_experiments import simulate_record
    from gripper_env.sysid.bus_servo import write_bus_record

    model = load_bus_servo("sts3215")
    for key, sample in (("good", (0.002, 0.004)), ("slow", (0.016, 0.020))):
        rec = simulate_record(model, model.factory, sample_s=sample)
        rec = replace(rec, stats={"readings": rec.t_s.size, "lost": 0, "slow": 0,
                                  "sample_us": 2000})  # fmt: skip
        path = write_bus_record(write("rec_" + key, f"rec_{key}.csv", ""), rec)
        lines = path.read_text().splitlines()
        if key == "good":
            good = lines
    rows = [k for k, line in enumerate(good) if line[:1].isdigit()]
    huge = list(good)
    t, g, _y, *rest = huge[rows[6]].split(",")  # file line 10 (3 lines before the rows)
    huge[rows[6]] = ",".join([t, g, "1e308", *rest])
    write("rec_huge", "rec_huge.csv", "\n".join(huge) + "\n")
    back = list(good)
    back[rows[7]], back[rows[8]] = back[rows[8]], back[rows[7]]  # file lines 11 and 12
    write("rec_back", "rec_back.csv", "\n".join(back) + "\n")
    goal_lines = [k for k, line in enumerate(good) if line.startswith("# ") and
                  line[2:3].isdigit()]  # fmt: skip
    goal_back = list(good)
    goal_back[goal_lines[2]], goal_back[goal_lines[3]] = (goal_back[goal_lines[3]],
                                                          goal_back[goal_lines[2]])  # fmt: skip
    write("rec_goal_back", "rec_goal_back.csv", "\n".join(goal_back) + "\n")


def _files(folder):
    paths = {"missing": str(folder / "missing"), "out": str(folder / "runs")}

    def write(key, name, text):
        paths[key] = p = folder / name
        p.write_text(text)
        return p

    model = load_bus_servo("sts3215")
    cal = JawCalibration(family="sts3215", servo_id=6, closed_ticks=1760, open_ticks=2940)
    write("a_file", "a_file", "not a link\n")
    write("jaw", "jaw.json", cal.model_dump_json())
    calibrated = model.calibrated(cal).model_dump()
    registers = {"model": calibrated, "registers": model.factory.model_dump()}
    write("registers", "registers.json", json.dumps(registers))
    inf = json.loads(json.dumps(calibrated))
    inf["scale"]["kp"] = math.inf
    write("kp_inf", "kp_inf.json", json.dumps({"model": inf}))  # Python's JSON: Infinity
    write("nan_unc", "nan_unc.json", json.dumps({"model": calibrated,
                                                  "uncertainty": {"kp": math.nan}}))  # fmt: skip
    write("nan_reg", "nan_reg.json", json.dumps({**registers, "uncertainty_rel_std": {
        "kp": 0.1, "kd": math.nan}}))  # fmt: skip
    absolute = str(folder / "escaped-absolute")  # tune would write <name>_registers.json there
    for key, name in (("climbing", "../../escaped"), ("nul", "a\0b"), ("absolute", absolute)):
        named = {**calibrated, "name": name}
        write(f"{key}_reg", f"{key}_reg.json", json.dumps({**registers, "model": named}))
        write(f"{key}_model", f"{key}_model.json", json.dumps({"model": named}))
    write(
        "arm_json",
        "arm.json",
        json.dumps(
            {
                "shoulder_pan": {
                    "id": 1,
                    "drive_mode": 0,
                    "homing_offset": 0,
                    "range_min": 800,
                    "range_max": 3300,
                }
            }
        ),
    )
    _records(write)
    return {k: str(v) for k, v in paths.items()}


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bus-hostile")
    files = _files(folder)
    cwd = folder / "cwd"  # where a default output would land (runs/bus/...): must stay empty
    cwd.mkdir()
    inputs = set(folder.rglob("*"))
    results, queue, running = {}, list(CASES), []
    while queue or running:
        while queue and len(running) < CONCURRENCY:
            case = queue.pop(0)
            proc = command(case.module, *(a.format(**files) for a in case.args), cwd=cwd)
            running.append((case, proc))
        case, proc = running.pop(0)
        try:
            _, err = proc.communicate(timeout=HANG_GUARD_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
        results[case.name] = (proc.returncode, err)
    out = Path(files["out"])
    written = sorted(str(p.relative_to(folder)) for p in set(folder.rglob("*")) - inputs
                     if p != out and out not in p.parents)  # fmt: skip
    return results, written + [str(p) for p in folder.parent.glob("escaped*")]


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_refused_in_one_line_naming_the_input(case, outcomes):
    code, err = outcomes[0][case.name]
    lines = err.strip().splitlines()
    assert code == 2, err[-2000:]
    assert "Traceback" not in err
    assert len(lines) == 1, err[-2000:]
    assert "error" in lines[0]
    for name in case.names:
        assert name in lines[0], lines[0]


def test_nothing_is_written_outside_out(outcomes):
    """Every case is refused before its work: nothing new beside the inputs (where a climbing
    or absolute name would land), in the folder a default output would go to (``cwd``) or
    above the inputs' folder; only --out may hold anything."""
    assert outcomes[1] == [], outcomes[1]
