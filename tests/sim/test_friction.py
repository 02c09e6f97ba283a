import numpy as np
import pytest

from gripper_env.sim.friction import (
    F_DIR,
    F_STUCK,
    F_XSS,
    FRICTION_MODELS,
    backlash_step,
    friction_state,
    stiction_step,
)

CHOUDHURY = FRICTION_MODELS["choudhury"]
KANO = FRICTION_MODELS["kano"]


def drive(model, x, s, j):
    st = friction_state(x[0])
    return np.array([stiction_step(model, xi, s, j, st) for xi in x])


def test_choudhury_from_rest_needs_s_then_follows_with_offset():
    s, j = 3.0, 1.0
    x = np.arange(0, 10.01, 0.5)  # ramp up in 0.5 deg steps
    y = drive(CHOUDHURY, x, s, j)
    # stuck until the input has moved more than S = 3 from where it started
    assert np.all(y[x <= 3.0] == 0.0)
    # then it slips and follows x - (S - J)/2
    moving = x > 3.0
    np.testing.assert_allclose(y[moving], x[moving] - (s - j) / 2)


def test_choudhury_stops_then_needs_j_ahead_and_s_back():
    s, j = 3.0, 1.0
    st = friction_state(0.0)
    for xi in np.arange(0.5, 6.01, 0.5):
        out = stiction_step(CHOUDHURY, xi, s, j, st)
    assert out == pytest.approx(5.0)  # 6 - (S-J)/2
    # the input stops: output holds
    assert stiction_step(CHOUDHURY, 6.0, s, j, st) == pytest.approx(5.0)
    # same direction, less than J: still stuck
    assert stiction_step(CHOUDHURY, 6.9, s, j, st) == pytest.approx(5.0)
    # past J: slips to x - (S-J)/2
    assert stiction_step(CHOUDHURY, 7.2, s, j, st) == pytest.approx(6.2)
    # reversal: holds until the input came back more than S
    for xi in (7.0, 6.0, 5.0, 4.3):
        assert stiction_step(CHOUDHURY, xi, s, j, st) == pytest.approx(6.2)
    assert stiction_step(CHOUDHURY, 4.0, s, j, st) == pytest.approx(4.0 + (s - j) / 2)


@pytest.mark.parametrize(("s", "j"), [(2.0, 2.0), (2.0, 3.0)])
def test_slip_jump_sign(s, j):
    x = np.concatenate([np.zeros(5), np.arange(0.25, 8.0, 0.25)])
    y = drive(CHOUDHURY, x, s, j)
    tail = y[-1] - x[-1]
    assert tail == pytest.approx(-(s - j) / 2)  # J = S: no offset; J > S: overshoot (ahead)


def test_kano_equals_choudhury_after_a_motion_and_differs_from_rest():
    s, j = 3.0, 1.0
    # a big first move makes both slip; from then on they agree
    ramp = np.concatenate([[0.0], np.arange(5.0, 10.0, 0.5)])
    after = np.concatenate([ramp, [9.5, 9.5, 9.0, 8.0, 7.0, 6.0, 5.0, 6.0, 8.0, 11.0]])
    np.testing.assert_allclose(drive(KANO, after, s, j), drive(CHOUDHURY, after, s, j))
    # from rest they differ: Kano slips when |x - y| > (S + J)/2, Choudhury after S
    assert drive(KANO, [0.0, 2.5], s, j)[-1] == pytest.approx(1.5)
    assert drive(CHOUDHURY, [0.0, 2.5], s, j)[-1] == 0.0


def test_none_model_passes_through():
    x = np.sin(np.linspace(0, 10, 100))
    np.testing.assert_array_equal(drive(FRICTION_MODELS["none"], x, 5.0, 1.0), x)


def test_backlash_play_operator():
    y = 0.0
    outs = []
    for x in [0.5, 1.0, 2.0, 1.5, 1.0, 0.0, -1.0]:
        y = backlash_step(x, 1.0, y)
        outs.append(y)
    np.testing.assert_allclose(outs, [0.0, 0.5, 1.5, 1.5, 1.5, 0.5, -0.5])


def _full_stiction(model, x, s, j, out, x_prev, x_ss, direction, stuck):
    """Every branch evaluated on every sample (no held-input shortcut): the reference."""

    def sign(v):
        return float(np.sign(v))

    v = sign(x - x_prev)
    offset = 0.5 * (s - j)
    if stuck == 0.0:
        if v == direction:
            out = x - direction * offset
        else:
            stuck, x_ss = 1.0, x_prev
    if stuck == 1.0:
        if model == CHOUDHURY:
            travel = x - x_ss
            tdir = sign(travel)
            if tdir != 0.0 and abs(travel) > (j if tdir == direction else s):
                stuck, direction, out = 0.0, tdir, x - tdir * offset
        elif abs(x - out) > 0.5 * (s + j):
            direction = sign(x - out)
            stuck, out = 0.0, x - direction * offset
    return out, x_ss, direction, stuck


@pytest.mark.parametrize("model", [CHOUDHURY, KANO])
def test_held_inputs_give_what_full_evaluation_gives(model):
    # servo-like inputs: whole-degree commands, each held for a random number of samples
    rng = np.random.default_rng(7)
    x = np.repeat(np.round(np.cumsum(rng.normal(0, 2.0, 400))), rng.integers(1, 25, 400))
    s, j = 2.5, 1.5
    st = friction_state(x[0])
    ref = (x[0], x[0], 0.0, 1.0)  # out, x_ss, direction, stuck
    x_prev = x[0]
    slips = 0
    for xi in x:
        got = stiction_step(model, xi, s, j, st)
        ref = _full_stiction(model, xi, s, j, ref[0], x_prev, *ref[1:])
        x_prev = xi
        assert got == ref[0]
        assert (st[F_XSS], st[F_DIR], st[F_STUCK]) == ref[1:]
        slips += ref[3] == 0.0
    assert slips > 50  # the inputs did move the jaw, many times
