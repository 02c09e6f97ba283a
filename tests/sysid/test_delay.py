"""Input delay (issue 13, defect 3): estimated, exact, reported.

A 15 ms input delay (a hobby servo behind its 20 ms refresh) bent a 2nd-order model's poles
from -11 +/- 8.9j to about -9.7 +/- 13.8j, without a word. The delay is now estimated (MATLAB's
``InputDelay``), sampled exactly when it is not a whole number of samples, and reported in the
JSON, the plant file and the plot.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import yaml
from scipy import signal

from gripper_env.sysid import tfest

from .cli_support import run_json, write_log
from .signals import DT_S, adc, lsim_zoh, rich_input

NUM, DEN = [20.0, 200.0], [1.0, 22.0, 200.0]
DELAY_SAMPLES = 15
TRUE_POLES = np.sort_complex(np.roots(DEN))


@pytest.fixture(scope="module")
def delayed():
    rng = np.random.default_rng(31)
    u = rich_input(20.0, rng)
    u_late = np.concatenate([np.full(DELAY_SAMPLES, u[0]), u[:-DELAY_SAMPLES]])
    return u, adc(92.0 + lsim_zoh(NUM, DEN, u_late - 92.0), rng)


def test_cli_estimates_the_delay_and_keeps_the_poles(delayed, tmp_path, capsys):
    u, y = delayed
    log = write_log(tmp_path / "servo.csv", np.arange(u.size) * DT_S, desired_deg=u, actual_deg=y)
    plant, png = tmp_path / "servo.yaml", tmp_path / "servo.png"
    out = run_json([str(log), "--save-plant", str(plant), "--plot", str(png)], capsys)
    assert out.get("input_delay_s") == pytest.approx(DELAY_SAMPLES * DT_S, abs=0.5e-3)
    poles = np.sort_complex(np.array([complex(*p) for p in out["poles"]]))
    np.testing.assert_allclose(poles, TRUE_POLES, rtol=0.03)
    # reported in the plant file (a comment and the description) and the plot
    text = plant.read_text()
    assert text.startswith("# input delay 15 ms")
    assert "input delay 15 ms" in yaml.safe_load(text)["description"]
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_a_fixed_delay_that_is_too_short_is_flagged(delayed):
    from gripper_env.sysid import IdentificationWarning

    u, y = delayed
    with pytest.warns(IdentificationWarning, match="longer input delay"):
        est = tfest(DT_S, u, y, input_delay_s=0.0)
    assert not est.delay_estimated and est.input_delay_s == 0.0
    assert any("longer input delay" in w for w in est.warnings)


def test_no_delay_is_estimated_as_none():
    rng = np.random.default_rng(8)
    u = rich_input(10.0, rng)
    y = adc(92.0 + lsim_zoh(NUM, DEN, u - 92.0), rng)
    est = tfest(DT_S, u, y, input_delay_s="estimate")
    assert est.delay_estimated and est.input_delay_s < 0.3e-3


@pytest.mark.parametrize("delay_s", [0.0023, 0.0157])
def test_fractional_delay_is_sampled_exactly(delay_s):
    """The response to a held input delayed by any amount, against scipy on a 100x finer grid
    where the delay is a whole number of fine steps (independent of the library's sampling)."""
    from gripper_env.sysid.zoh import zoh_response

    rng = np.random.default_rng(4)
    u = np.repeat(rng.uniform(-30, 30, 20), 100)
    fine = 100
    shift = round(delay_s / DT_S * fine)
    u_fine = np.repeat(u, fine)
    u_fine = np.concatenate([np.full(shift, u[0]), u_fine[:-shift]])
    a, b, c, d = control.ssdata(control.ss(control.tf(NUM, DEN)))
    t_fine = np.arange(u_fine.size) * DT_S / fine
    ref = signal.lsim(signal.StateSpace(a, b, c, d), u_fine, t_fine, interp=False)[1][::fine]
    got = zoh_response(NUM, DEN, u, DT_S, delay_s=delay_s)
    assert np.max(np.abs(got - ref)) <= 1e-8 * np.max(np.abs(ref))
