"""Time stamps as real logs carry them (issue 13, defects 1 and 2).

1. Stamps with float jitter are a uniform grid: the samples are taken as recorded, never
   resampled with the held input shifted by a sample.
2. A logger's +/-0.2 ms jitter on a 1 ms clock is accepted (snapped), the tolerance is a flag,
   and every refusal names an option that exists.
"""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.sysid import tfest
from gripper_env.sysid.data import prepare_data

from .cli_support import options_named, run, run_json, write_log
from .signals import DT_S, adc, lsim_zoh, rich_input

NUM, DEN = [20.0, 200.0], [1.0, 22.0, 200.0]


@pytest.fixture(scope="module")
def record():
    rng = np.random.default_rng(21)
    u = rich_input(20.0, rng)
    return u, adc(92.0 + lsim_zoh(NUM, DEN, u - 92.0), rng)


def test_float_jitter_is_the_grid(record):
    """Stamps with float jitter of up to 4e-8 s (rounding residues, as in a published 1 ms
    positioning-servo dataset) give exactly the model of the exact grid, with every held input
    sample where it was. Defect 1: their median interval is 0.99998 ms, and main resampled on
    that grid, which shifts every held input sample by one."""
    u, y = record
    k = np.arange(u.size)
    t_exact = 10.0 + k * DT_S
    t_float = t_exact + 4e-8 * ((k * 0.6180339887) % 1.0)
    assert np.median(np.diff(t_float)) < DT_S - 1e-8
    data = prepare_data(t_float, u, y)
    np.testing.assert_array_equal(data.u, u - u[0])
    assert data.dt_s == pytest.approx(DT_S, rel=1e-9)
    exact, jittered = tfest(t_exact, u, y), tfest(t_float, u, y)
    np.testing.assert_allclose(jittered.den, exact.den, rtol=1e-9)
    np.testing.assert_allclose(jittered.num, exact.num, rtol=1e-9)


def test_logger_jitter_is_accepted(record, tmp_path, capsys):
    """+/-0.2 ms of jitter on 1 ms stamps: the command line fits it (defect 2: main refused it
    with exit 2), as well as the exact grid does."""
    u, y = record
    rng = np.random.default_rng(5)
    t = np.arange(u.size) * DT_S + rng.uniform(-2e-4, 2e-4, u.size)
    log = write_log(tmp_path / "jitter.csv", t, desired_deg=u, actual_deg=y)
    out = run_json([str(log)], capsys)
    np.testing.assert_allclose(out["den"], DEN, rtol=0.02)
    assert out["time_base"] == "snapped" and 0.1 < out["jitter"] < 0.3


def test_jitter_tolerance_is_a_flag(record, tmp_path, capsys):
    u, y = record
    rng = np.random.default_rng(5)
    t = np.arange(u.size) * DT_S + rng.uniform(-2e-4, 2e-4, u.size)
    log = write_log(tmp_path / "jitter.csv", t, desired_deg=u, actual_deg=y)
    status, _, err = run([str(log), "--max-jitter", "0.1", "--delay", "0"], capsys)
    assert status == 0 and "resampled" in err and "--max-jitter" in err
    status, _, err = run([str(log), "--max-jitter", "0.7"], capsys)
    assert status == 2 and "--max-jitter" in err


@pytest.mark.parametrize(
    "case",
    ["gap", "bad jitter", "bad gap", "missing column"],
)
def test_every_refusal_names_an_option_that_exists(case, record, tmp_path, capsys):
    """Each time-base error is one line whose advice names real options (defect 2: main advised
    raising ``max_jitter``, which the command line did not have)."""
    u, y = record
    t = np.arange(u.size) * DT_S
    argv: list[str] = []
    if case == "gap":
        t[3000:] += 0.05  # 50 samples lost
    elif case == "bad jitter":
        argv = ["--max-jitter", "-1"]
    elif case == "bad gap":
        argv = ["--max-gap", "0.5"]
    log = write_log(tmp_path / "log.csv", t, desired_deg=u, actual_deg=y)
    if case == "missing column":
        argv = ["--u-column", "command_deg"]
    status, out, err = run([str(log), *argv], capsys)
    assert status == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err
    named = options_named(lines[0]) | ({"--u-column"} if case == "missing column" else set())
    status, help_text, _ = run(["tf", "--help"], capsys)
    assert named and named <= options_named(help_text), named


def test_irregular_stamps_hold_the_input_without_a_shift():
    """Resampling averages the held input over each new interval: on stamps that are in fact
    uniform it gives the input back exactly; on irregular ones, the same area of input."""
    from gripper_env.sysid.data import held_average

    rng = np.random.default_rng(2)
    u = np.repeat(rng.uniform(21, 92, 40), 50)
    t = np.arange(u.size) * DT_S
    np.testing.assert_allclose(held_average(t, u, t, DT_S), u, rtol=0, atol=1e-9)
    t_irr = np.cumsum(rng.uniform(0.5, 1.5, u.size)) * DT_S
    grid = t_irr[0] + DT_S * np.arange(int((t_irr[-1] - t_irr[0]) / DT_S))
    avg = held_average(t_irr, u, grid, DT_S)
    area_held = np.sum(u[:-1] * np.diff(t_irr))
    assert np.sum(avg) * DT_S == pytest.approx(area_held, rel=2e-3)
