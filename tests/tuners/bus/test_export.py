"""``python -m tuners.bus.export``: the files it writes load in MuJoCo and in the runtime, and
bad input is one line and exit 2."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gripper_env.model.bus_servo import load_registers_file
from tuners.bus import export

mujoco = pytest.importorskip("mujoco")


def test_export_writes_both_forms(tmp_path, capsys):
    status = export.main(["--model", "xl330", "--p", "800", "--d", "600", "--out",
                          str(tmp_path), "--no-fit"])  # fmt: skip
    assert status == 0
    out = capsys.readouterr().out
    assert "not in the native class" in out and "static friction above Coulomb" in out
    native = mujoco.MjModel.from_xml_string((tmp_path / "xl330_native.xml").read_text())
    exact = mujoco.MjModel.from_xml_string((tmp_path / "xl330_exact.xml").read_text())
    # P = 800 on the XL330: kp = 0.52 N m x 800 / (128 x 885) per tick x 4096 / 2 pi per rad
    kp = 0.52 * 800 / (128 * 885) * 4096 / (2 * math.pi)
    assert native.actuator_gainprm[0, 0] == pytest.approx(kp, rel=1e-3)
    assert exact.actuator_gear[0, 0] == pytest.approx(0.52)
    model, regs, _doc = load_registers_file(tmp_path / "xl330_exact.json")
    assert (regs.p, regs.d, model.family) == (800, 600, "xl330")
    # the runtime runs the exported pair: a 10 deg step settles within the dead band
    from gripper_env.mujoco.runtime import ExactServo

    d = mujoco.MjData(exact)
    d.qpos[0] = math.radians(model.jaw.open_deg)
    mujoco.mj_forward(exact, d)
    servo = ExactServo(exact, d, model, regs)
    servo.run(np.full(400, model.jaw.open_deg - 10.0))
    assert abs(servo.angle_deg - (model.jaw.open_deg - 10.0)) < 0.5


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--p", "-1"], "--p must be >= 0"),
        (["--registers", "missing.json"], "does not exist"),
        (["--model", "no-such-servo"], "no-such-servo"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, argv, says):
    assert export.main([*argv, "--out", str(tmp_path / "o"), "--no-fit"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o").exists()
