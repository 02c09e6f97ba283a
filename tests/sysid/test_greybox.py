"""The actual gripper identified from its own records (issue 13, defect 7).

Friction (S, J), sensor noise and offset, and delay were guesses in the ``actual`` preset; a
user's gripper got the paper's friction. ``python -m tuners.sysid greybox`` identifies them
by simulating the project's core and writes a plant file and a disturbance preset.

The log here is generated independently of the core, from the definitions (DESIGN.md
sections 1 and 3): the command latched every 20 ms and quantised to the microsecond pulse,
Choudhury's stiction (``signals.choudhury_stiction``), the servo's transfer function (scipy),
a sensor delay, Gaussian noise and a 10-bit ADC.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant

from .cli_support import run, write_log
from .signals import ADC_COUNTS, ADC_RANGE_DEG, DT_S, choudhury_stiction, lsim_zoh

SERVO_NUM, SERVO_DEN = [150.0], [1.0, 25.0, 150.0]  # a 2nd-order servo, poles -10 and -15
S_DEG, J_DEG, NOISE_DEG, DELAY_STEPS = 3.0, 1.2, 0.4, 12
QUANTUM_DEG = 180.0 / (2400.0 - 544.0)  # writeMicroseconds over the default pulse range


def _slope_profile() -> np.ndarray:
    """Two steps (they pin the timing down: on a ramp a later servo tick and a longer delay
    look alike), then a 20 s slope down and up (the friction)."""
    parts = [np.full(1013, 92.0), np.full(2000, 60.0), np.full(2000, 92.0),
             np.linspace(92.0, 21.0, 20000, endpoint=False), np.full(4000, 21.0),
             np.linspace(21.0, 92.0, 20000, endpoint=False), np.full(4000, 92.0)]  # fmt: skip
    return np.concatenate(parts)


def _gripper_log(u: np.ndarray, seed: int) -> np.ndarray:
    """The measured angle of a gripper with known friction, sensor and delay."""
    held = u[(np.arange(u.size) // 20) * 20]  # the servo takes a command every 20 ms
    command = QUANTUM_DEG * np.floor(held / QUANTUM_DEG + 0.5)
    jaw_cmd = choudhury_stiction(command, S_DEG, J_DEG)
    jaw = u[0] + lsim_zoh(SERVO_NUM, SERVO_DEN, jaw_cmd - u[0])
    jaw = np.concatenate([np.full(DELAY_STEPS, jaw[0]), jaw[:-DELAY_STEPS]])
    rng = np.random.default_rng(seed)
    lsb = ADC_RANGE_DEG / ADC_COUNTS
    counts = np.clip(np.floor((jaw + rng.normal(0.0, NOISE_DEG, u.size)) / lsb + 0.5), 0, 1023)
    return counts * lsb


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    folder = tmp_path_factory.mktemp("greybox")
    u = _slope_profile()
    log = write_log(folder / "mine.csv", np.arange(u.size) * DT_S, desired_deg=u,
                    actual_deg=_gripper_log(u, seed=1))  # fmt: skip
    base = folder / "microseconds.yaml"  # the user's rig: writeMicroseconds at 50 Hz
    base.write_text(yaml.safe_dump({"name": "us", "extends": "actual",
                                    "command": {"quantization": "microseconds"}}))  # fmt: skip
    return folder, log, base


def test_known_friction_sensor_and_delay_are_recovered(identified, capsys):
    folder, log, base = identified
    plant, preset = folder / "mine_plant.yaml", folder / "mine.yaml"
    out = _greybox(log, base, plant, preset, capsys)
    f = out["friction"]
    assert f["S_deg"] == pytest.approx(S_DEG, rel=0.15)
    assert f["J_deg"] == pytest.approx(J_DEG, rel=0.15)
    assert f["S_range_deg"][0] <= S_DEG <= f["S_range_deg"][1] + 0.25
    assert out["sensor"]["noise_std_deg"] == pytest.approx(NOISE_DEG, rel=0.15)
    assert out["sensor"]["lsb_deg"] == pytest.approx(ADC_RANGE_DEG / ADC_COUNTS, rel=1e-3)
    assert out["delay_s"] == pytest.approx(DELAY_STEPS * DT_S, abs=2e-3)
    np.testing.assert_allclose(out["plant"]["den"], SERVO_DEN, rtol=0.1)
    noise = np.hypot(NOISE_DEG, ADC_RANGE_DEG / ADC_COUNTS / np.sqrt(12))
    assert out["residual_rms_deg"] < 1.1 * noise  # everything but the noise is explained
    # the files the tuners take
    d = load_disturbance(preset)
    assert d.friction.S_deg == pytest.approx(f["S_deg"], abs=1e-3)
    # the estimate is continuous; the preset holds it in whole physics steps, as the core does
    assert d.command.quantization == "microseconds"
    assert d.sensor.delay_s == pytest.approx(round(out["delay_s"] / DT_S) * DT_S)
    assert load_plant(plant).order in (1, 2)


def _greybox(log, base, plant, preset, capsys):
    status, out, err = run(["greybox", str(log), "--base", str(base), "--save-plant", str(plant),
                            "--save-disturbance", str(preset), "--json"], capsys)  # fmt: skip
    assert status == 0, err
    import json

    return json.loads(out)


def test_a_step_record_says_the_friction_is_not_pinned_down(tmp_path, capsys):
    from gripper_env.sim import simulate

    traj = simulate("test2", "step", gains=None, disturbance="actual", seeds=3)
    log = write_log(tmp_path / "step.csv", traj.t, desired_deg=traj.r[0], actual_deg=traj.y[0])
    status, out, err = run(["greybox", str(log)], capsys)
    assert status == 0
    assert "hardly excited by this record" in err and "slope60" in err
    assert "not pinned down" in out


def test_bad_input_is_one_line(tmp_path, capsys):
    status, out, err = run(["greybox", str(tmp_path / "none.csv")], capsys)
    assert status == 2 and out == "" and len(err.strip().splitlines()) == 1
    u = np.repeat([92.0, 50.0], 150)
    traj_log = write_log(tmp_path / "x.csv", np.arange(300) * DT_S, desired_deg=u, actual_deg=u)
    status, _, err = run(["greybox", str(traj_log), "--base", "nope"], capsys)
    assert status == 2 and "nope" in err and len(err.strip().splitlines()) == 1


def test_an_interval_the_data_cannot_pin_prints_not_identified():
    """Issue 45, item 7: greybox printed ``a1 10.7 [-0.0006659, 10.82]`` for a coefficient of
    the nearly cancelling slow pair; an interval that spans zero, or is wider than the estimate,
    or is not finite now reads "not identified" (its numbers stay in the JSON)."""
    from gripper_env.sysid.greybox import coefficient_identified, coefficients_text

    intervals = {"a1": (-0.0006659, 10.82), "a0": (0.0671, 0.0702), "b1": (20.1, 21.3),
                 "b0": (0.001, float("inf"))}  # fmt: skip
    text = coefficients_text(["a1", "a0", "b1", "b0"], [10.7, 0.0686, 20.7, 0.0029], intervals)
    assert text == (
        "a1 10.7 not identified, a0 0.0686 [0.0671, 0.0702], b1 20.7 [20.1, 21.3], "
        "b0 0.0029 not identified"
    )
    assert not coefficient_identified(-2.0, -5.0, 0.5)  # spans zero
    assert not coefficient_identified(1.0, 0.2, 1.3)  # wider than the estimate
    assert coefficient_identified(-1.0, -1.4, -0.5)
