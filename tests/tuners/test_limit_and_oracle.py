"""The limit (a linear program) and the oracle (an MPC) against independent truth: the
simulation core replaying the limit's commands, the limit bounding every controller, the oracle
reaching the limit where it knows everything."""

import numpy as np
import pytest

from gripper_env.evaluation.metrics import compute_metrics
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import step_profile
from gripper_env.sim import simulate
from tuners.benchmark.limit import least_iae
from tuners.benchmark.oracle import OracleSettings, run_oracle
from tuners.probe import probe_disturbance

SHORT = step_profile(hold_s=0.3, grip_s=1.5, ungrip_s=1.5)  # 3.3 s
TEST2 = load_plant("test2")
ACTUAL, IDEAL = load_disturbance("actual"), load_disturbance("ideal")
HOLD = probe_disturbance(ACTUAL, IDEAL)  # the transfer function with the 20 ms hold, 0-180 deg


def _iae(traj) -> float:
    return float(np.sum(np.abs(traj.y_true[0] - SHORT.values_deg)) * SHORT.dt_s)


@pytest.fixture(scope="module")
def limit():
    return least_iae(TEST2, SHORT, ACTUAL)


def test_the_limits_commands_replayed_through_the_core_give_its_iae(limit):
    traj = simulate("test2", limit.command_profile(len(SHORT)), None, HOLD)
    assert _iae(traj) == pytest.approx(limit.iae, rel=1e-6)
    assert limit.commands_deg.min() >= 0.0 - 1e-9 and limit.commands_deg.max() <= 180.0 + 1e-9
    assert len(limit.commands_deg) == round(3.3 / 0.020)


def test_no_controller_beats_the_limit(limit):
    options = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")
    gains = [[1.0, 9.0, -0.001, 100.0], [3.43, 67.5, -0.0087, 100.0], [2.4, 39.0, 0.0, 100.0]]
    pids = simulate("test2", SHORT, gains, HOLD, pid_options=options)
    open_loop = simulate("test2", SHORT, None, HOLD)
    for traj in (pids, open_loop):
        iae = compute_metrics(traj, "true").run["iae"]
        assert np.all(iae >= limit.iae - 1e-9)
    # and the limit is well below them: it knows the profile ahead
    assert limit.iae < 0.6 * compute_metrics(open_loop, "true").run["iae"][0]


def test_an_unbounded_command_range_is_refused():
    with pytest.raises(ValueError, match="bounded command range"):
        least_iae(TEST2, SHORT, IDEAL)


def test_the_oracle_that_knows_everything_reaches_the_limit(limit):
    """On the frictionless loop it models exactly, with the profile ahead, the MPC's receding
    horizon gives (nearly) the limit: an independent check of both."""
    traj = run_oracle(TEST2, SHORT, HOLD, np.array([0]), randomize=False,
                      settings=OracleSettings(preview=True))  # fmt: skip
    assert _iae(traj) == pytest.approx(limit.iae, rel=0.02)


def test_the_oracle_on_the_actual_gripper_settles_and_tracks():
    traj = run_oracle(TEST2, SHORT, ACTUAL, np.array([100000, 100001]),
                      settings=OracleSettings(preview=False))  # fmt: skip
    m = compute_metrics(traj, "true")
    assert m.stable.all() and np.all(m.run["iae"] < 20.0)
    assert np.all(np.abs(traj.u) <= 180.0 + 1e-9) and np.all(traj.u >= -1e-9)
