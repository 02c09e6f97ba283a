"""Closed-loop data (issue 13, defect 5).

A plant of gain 4 under PI control with a coloured load disturbance: the output-error fit from
the command to the output gives a gain far below 4 (the controller cancels the disturbance, so
the fit sees the command move and the output stay). With the loop's reference the plant comes
back; without it, the data are flagged as a feedback loop.

The loop is simulated here independently of the library: python-control's ZOH model of the
plant, the PI law written out, the output measured before each command acts.
"""

from __future__ import annotations

import dataclasses

import control
import numpy as np
import pytest
from scipy import signal

from gripper_env.sysid import tfest
from tuners.sysid.tf import text_report

from .cli_support import run, run_json, write_log

DT = 0.01  # a 100 Hz log
NUM, DEN = [64.0], [1.0, 10.0, 16.0]  # gain 4, poles -2 and -8 rad/s
KP, KI = 0.5, 3.0


def closed_loop_record(seconds: float, seed: int) -> dict[str, np.ndarray]:
    a, b, c, _ = (np.asarray(m) for m in control.ssdata(control.ss(control.c2d(
        control.tf(NUM, DEN), DT, "zoh"))))  # fmt: skip
    n = round(seconds / DT)
    rng = np.random.default_rng(seed)
    r = np.zeros(n)
    k = 0
    while k < n:
        m = int(rng.uniform(1.0, 3.0) / DT)
        r[k : k + m] = 50.0 + rng.uniform(-1, 1)
        k += m
    pole = np.exp(-0.3 * DT)  # a slow load disturbance at the plant's input
    load = signal.lfilter([1 - pole], [1, -pole], rng.normal(0, 8.0, n))
    x, xi = np.zeros(a.shape[0]), 50.0 / 4.0  # at rest at 50 deg
    x[:] = np.linalg.solve(np.eye(a.shape[0]) - a, b[:, 0] * xi)
    u, y = np.zeros(n), np.zeros(n)
    for k in range(n):
        y[k] = c[0] @ x + 0.02 * rng.normal()
        err = r[k] - y[k]
        xi += KI * err * DT
        u[k] = KP * err + xi
        x = a @ x + b[:, 0] * (u[k] + load[k])
    return {"reference_deg": r, "command_deg": u, "position_deg": y}


@pytest.fixture(scope="module")
def loop_log(tmp_path_factory):
    rec = closed_loop_record(300.0, seed=0)
    path = tmp_path_factory.mktemp("loop") / "deploy_response.csv"
    return write_log(path, np.arange(rec["reference_deg"].size) * DT, **rec)


COLUMNS = ["--u-column", "command_deg", "--y-column", "position_deg", "--poles", "2",
           "--zeros", "0"]  # fmt: skip


def _gain(out: dict) -> float:
    return out["num"][-1] / out["den"][-1]


def test_the_reference_makes_closed_loop_data_usable(loop_log, capsys):
    out = run_json([str(loop_log), *COLUMNS, "--reference", "reference_deg"], capsys)
    assert _gain(out) == pytest.approx(4.0, rel=0.15)
    np.testing.assert_allclose(out["den"], DEN, rtol=0.15)
    loop = out["closed_loop"]
    assert loop["controller_fit_pct"] > 99.9  # the log's command is the PI's output
    # the controller it found is the PI (discrete: the integrator's step is in the P term)
    w = np.array([0.5, 5.0, 20.0])
    found = np.polyval(loop["controller_num"], 1j * w) / np.polyval(loop["controller_den"], 1j * w)
    np.testing.assert_allclose(found, KP + KI * DT + KI / (1j * w), rtol=0.02)


def test_closed_loop_data_without_reference_are_flagged(loop_log, capsys):
    status, out, err = run([str(loop_log), *COLUMNS, "--json"], capsys)
    assert status == 0
    assert "fed back from the output" in err and "--reference" in err
    import json

    assert _gain(json.loads(out)) < 2.0  # the bias the warning is about


def test_open_loop_data_are_not_flagged(tmp_path, capsys):
    from gripper_env.sim import simulate

    traj = simulate("test2", "slope20", gains=None, disturbance="actual", seeds=2)
    log = write_log(tmp_path / "open.csv", traj.t, desired_deg=traj.r[0], actual_deg=traj.y[0])
    status, _, err = run([str(log), "--delay", "0", "--allow-nonconverged"], capsys)
    assert status == 0 and "fed back" not in err


def test_the_text_report_quotes_the_closed_loop_fits():
    # the text report of a closed-loop estimate (it used to ask for a field the estimate lacks)
    t = np.arange(1000) * DT
    u = np.where(t >= 1.0, 10.0, 0.0)
    y = signal.lfilter([1 - np.exp(-5 * DT)], [1, -np.exp(-5 * DT)], u)  # 5 rad/s lag, gain 1
    est = tfest(DT, u, y, 1, 0, input_delay_s=0.0, check_feedback=False)
    loop = {"controller_num": [0.5, 3.0], "controller_den": [1.0, 0.0],
            "controller_fit_pct": 99.96, "loop_fit_pct": 97.46}  # fmt: skip
    text = text_report(dataclasses.replace(est, closed_loop=loop), None)
    assert "the fitted controller explains 100.0 % of the input" in text
    assert "the simulated loop fits 97.5 % of the output" in text
    assert "closed loop" not in text_report(est, None)
