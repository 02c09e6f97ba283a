"""The PID's grasp mode (gripper_env.model.pid) against hand-worked cases."""

import math

import numpy as np
import pytest

from gripper_env.model.pid import (
    GRASP_FILTER,
    PID,
    GraspOptions,
    PIDGains,
    PIDOptions,
    grasp_hold,
)

DT = 1e-3
#: A dwell of 10 samples, so the hand-worked cases stay short.
SHORT = GraspOptions(squeeze_deg=1.0, push_deg=5.0, short_deg=0.5, still_deg=1.0, dwell_s=0.01)


def _pid(gains: PIDGains, grasp: GraspOptions | None = SHORT, **options) -> PID:
    return PID(gains, dt_s=DT, options=PIDOptions(grasp=grasp, **options))


def test_a_blocked_jaw_is_held_squeeze_past_the_contact_after_the_dwell():
    """P = 1, at rest at 50 deg, reference 40, the jaw blocked at 50: u = 1 * (40 - 50) + 50 =
    40, 10 deg past the jaw towards the reference, the jaw still. Samples 0..8 count, sample 9
    is the tenth blocked one: from it the command is 50 - 1 = 49 and stays."""
    pid = _pid(PIDGains(1.0, 0.0, 0.0))
    pid.reset(u0=50.0, y0=50.0)
    u = [pid.step(40.0, 50.0) for _ in range(20)]
    assert u[:9] == [40.0] * 9
    assert u[9:] == [49.0] * 11
    assert pid.grasping == -1 and pid.contact_deg == 50.0


def test_the_integrator_is_frozen_while_holding():
    pid = _pid(PIDGains(1.0, 20.0, 0.0))
    pid.reset(u0=50.0, y0=50.0)
    for _ in range(12):
        pid.step(40.0, 50.0)
    assert pid.grasping == -1
    xi = pid.state[0]
    for _ in range(500):
        assert pid.step(40.0, 50.0) == 49.0
    assert pid.state[0] == xi
    # frozen where it stood before the sample that detected the contact: 50 + 9 samples of
    # dt * I * e = 50 - 9 * 1e-3 * 20 * 10
    assert xi == pytest.approx(50.0 - 9 * 0.2)


def test_opening_lets_go_and_the_pid_resumes_from_the_held_command():
    """The reference back over the contact (60 > 50): the integrator restarts at the held
    command, clipped to the contact (the reference lies on the open side), and the same sample is
    the PID's: u = 1 * (60 - 50) + 50."""
    pid = _pid(PIDGains(1.0, 20.0, 0.0))
    pid.reset(u0=50.0, y0=50.0)
    for _ in range(12):
        pid.step(40.0, 50.0)
    assert pid.grasping == -1
    assert pid.step(60.0, 50.0) == pytest.approx(60.0)
    assert pid.grasping == 0
    assert pid.state[0] == pytest.approx(50.0 + DT * 20.0 * 10.0)


def test_the_object_giving_way_lets_go():
    pid = _pid(PIDGains(1.0, 0.0, 0.0))
    pid.reset(u0=50.0, y0=50.0)
    for _ in range(12):
        pid.step(40.0, 50.0)
    # the jaw moves on to 47: the filtered measurement passes 49 (1 deg past the contact) after
    # n samples with 3 * (1 - (7/8)^n) > 1, n = 4
    held = []
    for _ in range(6):
        pid.step(40.0, 47.0)
        held.append(pid.grasping)
    assert held == [-1, -1, -1, 0, 0, 0]
    assert 3 * (1 - (1 - GRASP_FILTER) ** 3) < 1.0 < 3 * (1 - (1 - GRASP_FILTER) ** 4)


def test_the_hold_never_goes_past_the_reference_nor_the_limits():
    assert grasp_hold(50.0, -1.0, 40.0, 1.0, 0.0, 180.0) == 49.0
    assert grasp_hold(50.0, -1.0, 49.6, 1.0, 0.0, 180.0) == pytest.approx(49.6)
    assert grasp_hold(50.0, -1.0, 55.0, 1.0, 0.0, 180.0) == 50.0  # reference on the open side
    assert grasp_hold(50.0, 1.0, 60.0, 1.0, 0.0, 180.0) == 51.0  # blocked opening
    assert grasp_hold(50.0, -1.0, 40.0, 1.0, 49.5, 180.0) == 49.5
    # held at 49.5 deg, 0.5 past the contact: the reference moved to 49.5 while holding
    pid = _pid(PIDGains(1.0, 0.0, 0.0))
    pid.reset(u0=50.0, y0=50.0)
    for _ in range(12):
        pid.step(40.0, 50.0)
    assert pid.step(49.5, 50.0) == 49.5 and pid.grasping == -1


def test_a_moving_jaw_is_not_blocked():
    """The command 10 deg past a jaw closing at 15 deg/s: it moves 1.5 deg per default dwell
    (0.1 s), more than still_deg; at 5 deg/s (0.5 deg) it reads as blocked."""
    for speed, blocked in ((15.0, False), (5.0, True)):
        pid = _pid(PIDGains(0.0, 0.0, 0.0), grasp=GraspOptions())
        pid.reset(u0=30.0, y0=50.0)
        y = 50.0 - speed * DT * np.arange(400)
        held = [(pid.step(20.0, yk), pid.grasping)[1] for yk in y]
        assert (min(held) == -1) is blocked, speed


def test_the_command_must_push_past_push_deg_and_the_jaw_be_short_of_the_reference():
    for u0, r, blocked in (
        (46.0, 40.0, False),  # command 4 deg past the jaw: pushing, but below push_deg
        (44.0, 40.0, True),  # 6 deg past
        (44.0, 49.6, False),  # 6 deg past, but the jaw only 0.4 deg short of the reference
        (44.0, 55.0, False),  # the reference on the other side: not pushing towards it
    ):
        pid = _pid(PIDGains(0.0, 0.0, 0.0))
        pid.reset(u0=u0, y0=50.0)
        for _ in range(50):
            pid.step(r, 50.0)
        assert (pid.grasping == -1) is blocked, (u0, r)


def test_noise_on_the_measurement_does_not_keep_the_mode_from_holding():
    """ADC noise of 0.5 deg, 0.26-deg counts: the filtered measurement stays within still_deg of
    the contact, held within one dwell of the default mode and at the contact's mean."""
    rng = np.random.default_rng(0)
    pid = _pid(PIDGains(1.0, 9.0, -0.001), grasp=GraspOptions(), output_limits=(0.0, 180.0))
    pid.reset(u0=40.0, y0=40.0)
    lsb = 270 / 1023
    u, held = [], []
    for _ in range(1000):
        y = np.floor((40.0 + rng.normal(0.0, 0.5)) / lsb + 0.5) * lsb
        u.append(pid.step(38.0, y))
        held.append(pid.grasping)
    # the integrator takes the command 5 deg past in (5 - 2) / (9 * 2) s, then the dwell
    first = held.index(-1)
    assert 150 + 100 <= first < 400 and set(held[first:]) == {-1}
    assert abs(pid.contact_deg - 40.0) < 0.4
    assert set(u[first:]) == {pid.contact_deg - 1.0}


def test_the_sign_convention_does_not_change_the_mode():
    """The paper's hardware gains with e = y - r are the same loop as their negatives with
    e = r - y: the mode reads the command and the jaw, not the error."""
    a = _pid(PIDGains(-0.5, -3.6, 0.000186), sign=-1)
    b = _pid(PIDGains(0.5, 3.6, -0.000186))
    a.reset(u0=50.0, y0=50.0)
    b.reset(u0=50.0, y0=50.0)
    r = np.r_[np.full(3000, 40.0), np.full(200, 60.0)]
    ua = [a.step(rk, 50.0) for rk in r]
    ub = [b.step(rk, 50.0) for rk in r]
    np.testing.assert_allclose(ua, ub, rtol=1e-12)
    assert ua[2999] == 49.0


def test_off_it_is_the_plain_pid_and_on_it_changes_nothing_while_the_jaw_moves_freely():
    rng = np.random.default_rng(1)
    r = np.where((np.arange(3000) // 1000) % 2 == 0, 92.0, 21.0)
    y = np.empty_like(r)
    level = 92.0
    plain = _pid(PIDGains(1.0, 9.0, -0.001), grasp=None, output_limits=(0.0, 180.0))
    with_mode = _pid(PIDGains(1.0, 9.0, -0.001), grasp=GraspOptions(), output_limits=(0.0, 180.0))
    plain.reset(92.0, 92.0)
    with_mode.reset(92.0, 92.0)
    u_plain, u_mode = [], []
    for k in range(len(r)):
        y[k] = level
        u_plain.append(plain.step(r[k], y[k]))
        u_mode.append(with_mode.step(r[k], y[k]))
        level += 0.02 * (u_plain[-1] - level) + rng.normal(0.0, 0.2)  # a first-order servo
    assert u_plain == u_mode
    assert with_mode.grasping == 0


def test_bad_grasp_options_are_refused_by_name():
    with pytest.raises(ValueError, match="squeeze_deg"):
        GraspOptions(squeeze_deg=0.0)
    with pytest.raises(ValueError, match="below push_deg"):
        GraspOptions(squeeze_deg=5.0, push_deg=5.0)
    with pytest.raises(ValueError, match="dwell_s"):
        GraspOptions(dwell_s=math.inf)
    with pytest.raises(ValueError, match="dwell_s must be at most"):
        GraspOptions(dwell_s=100.0)
    with pytest.raises(ValueError, match="grasp must be GraspOptions"):
        PIDOptions(grasp={"squeeze_deg": 1.0})  # type: ignore[arg-type]
    assert GraspOptions().dwell_samples(1e-3) == 100
    assert PIDOptions().grasp == GraspOptions()  # on by default
