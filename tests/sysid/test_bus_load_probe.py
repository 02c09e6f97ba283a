"""The load probe that ``python -m tuners.bus.record`` runs before its steps: a creep both ways
around where the servo holds, whose mean output is the steady load (gravity on an arm joint)
and half whose difference is the friction; a steady load above the limit is refused."""

from __future__ import annotations

import pytest

from gripper_env.hardware.bus import ControlTable, VirtualBus
from gripper_env.hardware.bus.gripper import BusGripper
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_servo import load_bus_servo
from gripper_env.sysid.bus_experiments import (
    STEADY_LOAD_LIMIT,
    BusRecorder,
    LoadProbe,
    check_load,
    settings_registers,
)


def test_the_two_directions_split_friction_from_a_steady_load():
    # worked by hand: friction 0.07 each way, a steady 0.01 on top
    probe = LoadProbe(at_deg=200.0, reach_deg=3.0, forth=0.08, back=-0.06, readings=34)
    assert probe.steady == pytest.approx(0.01) and probe.friction == pytest.approx(0.07)
    model = load_bus_servo("sts3215")
    assert check_load(probe, model) == ""
    sagging = LoadProbe(at_deg=200.0, reach_deg=-3.0, forth=0.25, back=0.11, readings=34)
    assert sagging.steady == pytest.approx(0.18) and sagging.friction == pytest.approx(0.07)
    with pytest.raises(ValueError) as caught:
        check_load(sagging, model)
    text = str(caught.value)
    assert "steady load 18.0 % of full drive (0.34 N m)" in text  # 0.18 x 1.91 N m
    assert "arm joint under gravity" in text and "--risk-arm-joint" in text
    assert "recorded anyway" in check_load(sagging, model, risk_arm_joint=True)
    edge = LoadProbe(0.0, 3.0, STEADY_LOAD_LIMIT, STEADY_LOAD_LIMIT, 2)
    assert check_load(edge, model) == ""  # the limit itself passes


@pytest.mark.parametrize("family", ["sts3215", "xl330", "xl430"])
def test_a_gripper_on_the_virtual_bus_shows_its_friction_and_no_steady_load(family):
    """The virtual servo's jaw (the shipped model: Coulomb 0.05, static 0.09 of stall on the
    STS3215) creeping both ways: the friction is seen, the steady load is not, and the servo
    holds where it began."""
    model = load_bus_servo(family)
    table = ControlTable(family, 6)
    unit = ServoUnit(model, angle_deg=210.0)
    cal = JawCalibration(family=family, servo_id=6, closed_ticks=round(150 * 4096 / 360),
                         open_ticks=round(260 * 4096 / 360))  # fmt: skip
    with VirtualBus(family, ids=[table], physics={6: unit}) as bus:
        with BusGripper(bus.path, model, 6, calibration=cal) as jaw:
            start = jaw.position_deg()
            regs = max(settings_registers(model), key=lambda r: r.p)  # as record probes
            probe = BusRecorder(jaw).probe_load(regs)
            assert probe.readings >= 30 and abs(probe.reach_deg) >= 3.0 - 0.1
            assert abs(probe.steady) <= STEADY_LOAD_LIMIT, probe
            assert 0.3 * model.physics.coulomb <= probe.friction <= 2 * model.physics.static
            assert abs(jaw.position_deg() - start) < 1.5  # back where it held
