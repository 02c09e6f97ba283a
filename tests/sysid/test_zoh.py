"""Exact sampling: the library's state-space simulation against scipy, sensitivities against
finite differences."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from scipy import signal

from gripper_env.model.state_space import expm, observer_form
from gripper_env.sysid.sensitivity import model_sensitivities
from gripper_env.sysid.zoh import filtered_derivatives, zoh_response

from .signals import PAPER_TFS, lsim_zoh

SYSTEMS = [
    ([20.0, 200.0], [1.0, 22.0, 200.0]),
    ([3.0], [1.0, 2.0]),
    ([1.0, 2.0, 3.0], [1.0, 4.0, 5.0]),  # biproper
    ([1.0, 0.0, 0.0], [1.0, 3.0, 3.0, 1.0]),  # triple pole
    *PAPER_TFS.values(),
]


@pytest.mark.parametrize(("num", "den"), SYSTEMS)
def test_zoh_response_matches_scipy(num, den):
    u = np.random.default_rng(0).standard_normal(4000)
    ref = lsim_zoh(num, den, u)
    got = zoh_response(num, den, u, 1e-3)
    assert np.max(np.abs(got - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_initial_state_is_observer_form():
    num, den = [20.0, 200.0], [1.0, 22.0, 200.0]
    x0 = np.array([1.5, -3.0])
    free = zoh_response(num, den, np.zeros(3000), 1e-3, x0)
    # Free response of (x0[0] s + x0[1]) / den is its impulse response.
    t = np.arange(3000) * 1e-3
    _, ref = signal.impulse((x0, den), T=t)
    assert free[0] == pytest.approx(x0[0])
    assert np.max(np.abs(free - ref)) < 1e-9
    _a, b, c, d = observer_form(num, den)
    assert d == 0.0 and c.tolist() == [1.0, 0.0] and b.tolist() == [20.0, 200.0]


def test_foh_filter_on_smooth_signal():
    t = np.arange(5000) * 1e-3
    w = np.sin(3.0 * t) + 0.3 * np.cos(11.0 * t)
    den = [1.0, 22.0, 200.0]
    got = filtered_derivatives(den, w, 1e-3, "foh")
    for i in range(3):
        num = [1.0] + [0.0] * i
        ref = signal.lsim((num, den), w, t, interp=True)[1]
        assert np.max(np.abs(got[:, i] - ref)) <= 1e-9 * np.max(np.abs(ref)) + 1e-12


def test_expm_matches_scipy():
    rng = np.random.default_rng(1)
    for _ in range(50):
        n = int(rng.integers(1, 10))
        m = rng.standard_normal((n, n)) * 10 ** rng.uniform(-4, 1.5)
        ref = scipy.linalg.expm(m)
        assert np.allclose(expm(m), ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("name", ["test1", "test2", "test4"])
def test_sensitivities_match_finite_differences(name):
    num, den = (np.asarray(c, float) for c in PAPER_TFS[name])
    num, den = num / den[0], den / den[0]
    rng = np.random.default_rng(2)
    u = np.repeat(rng.uniform(-30, 30, 40), 500)
    x0 = np.array([0.7, -0.02])
    dt = 1e-3
    sens = model_sensitivities(num, den, u, dt, x0, with_initial_state=True)
    assert np.allclose(sens.y_hat, zoh_response(num, den, u, dt, x0), rtol=1e-12, atol=1e-9)
    jac = np.column_stack([sens.d_a, sens.d_b, sens.d_x0])
    p = np.concatenate([den[1:], num, x0])

    def sim(q):
        return zoh_response(q[2:4], np.concatenate([[1.0], q[:2]]), u, dt, q[4:])

    for i in range(p.size):
        h = 1e-5 * max(abs(p[i]), 1e-3)
        e = np.zeros(p.size)
        e[i] = h
        fd = (sim(p + e) - sim(p - e)) / (2 * h)
        assert np.linalg.norm(jac[:, i] - fd) <= 1e-5 * np.linalg.norm(fd), i
