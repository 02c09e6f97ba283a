import numpy as np
import pytest

from gripper_env.paper import PID_GAINS as PAPER_GAINS
from gripper_env.pid import PIDGains, PIDOptions
from gripper_env.simulation import simulate
from gripper_env.stability import closed_loop, stability_report


@pytest.mark.parametrize("name", ["untuned_tf", "tuned_tf", "untuned_hw", "tuned_hw"])
@pytest.mark.parametrize("sign", [1, -1])
def test_pole_verdict_agrees_with_simulation_on_test4(name, sign):
    """Independent check: poles outside the unit circle <=> the ideal simulation diverges."""
    gains = PAPER_GAINS[name]
    report = stability_report("test4", PIDGains(*gains), sign)
    # a long run so that slow instabilities (|z| ~ 1.006) reach the divergence bound
    ref = np.concatenate([np.full(1000, 92.0), np.full(10_000, 21.0)])
    traj = simulate(
        "test4", ref, gains=[gains], disturbance="ideal", pid_options=PIDOptions(sign=sign)
    )
    growth = np.abs(traj.y_true[0, -1] - 21.0) if traj.stable[0] else np.inf
    assert report.stable == (growth < 1.0)


def test_paper_facts():
    # Table 3's TF gains are stable on test2 with e = r - y; the hardware gains only with e = y - r
    assert stability_report("test2", PIDGains(*PAPER_GAINS["tuned_tf"])).stable
    assert stability_report("test2", PIDGains(*PAPER_GAINS["untuned_tf"])).stable
    for hw in ("untuned_hw", "tuned_hw"):
        assert not stability_report("test2", PIDGains(*PAPER_GAINS[hw]), sign=1).stable
        assert stability_report("test2", PIDGains(*PAPER_GAINS[hw]), sign=-1).stable
    # the untuned gains have a small phase margin (the ~40 % overshoot)
    pm = stability_report("test2", PIDGains(*PAPER_GAINS["untuned_tf"])).phase_margin_deg
    assert 10 < pm < 35


def test_closed_loop_dc_gain_is_one_with_integral_action():
    cl = closed_loop("test3", PIDGains(1.0, 9.0, -0.001))
    assert float(np.real(cl(1.0))) == pytest.approx(1.0, rel=1e-9)


def test_report_is_serialisable():
    d = stability_report("test2", PIDGains(1.0, 9.0, -0.001)).as_dict()
    assert set(d) >= {
        "stable",
        "max_pole_magnitude",
        "poles",
        "gain_margin_db",
        "phase_margin_deg",
        "sign",
    }
    with pytest.raises(ValueError, match="sign"):
        stability_report("test2", PIDGains(1.0, 9.0, -0.001), sign=0)
