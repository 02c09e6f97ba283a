"""The one state-space form and ZOH sampling of a transfer function
(``gripper_env.model.state_space``),
used by the plants (the simulation core) and by identification."""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg

from gripper_env.model.plants import load_plant
from gripper_env.model.state_space import discretise, expm, observer_form, zoh_matrices


@pytest.mark.parametrize("name", ["test1", "test2", "test3", "test4"])
def test_plant_matrices_are_the_shared_ones(name):
    plant = load_plant(name)
    shared = zoh_matrices(plant.num, plant.den, plant.dt_s)
    assert all(np.array_equal(a, b) for a, b in zip(plant.zoh_matrices(), shared, strict=True))
    a, b, d = plant.observable_form()
    a2, b2, c2, d2 = observer_form(plant.num, plant.den)
    assert np.array_equal(a, a2) and np.array_equal(b, b2) and d == d2 and c2[0] == 1.0


@pytest.mark.parametrize("name", ["test1", "test2", "test4"])
def test_zoh_matches_python_control(name):
    plant = load_plant(name)
    ad, bd, d = zoh_matrices(plant.num, plant.den, 1e-3)
    ref = control.c2d(control.ss(control.tf(list(plant.num), list(plant.den))), 1e-3, "zoh")
    # same discrete transfer function: compare the impulse responses
    n = 200
    x, got = np.zeros(ad.shape[0]), []
    for k in range(n):
        got.append(x[0] + (d if k == 0 else 0.0))
        x = ad @ x + bd * (1.0 if k == 0 else 0.0)
    want = control.impulse_response(ref, np.arange(n) * 1e-3).outputs * 1e-3
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


def test_expm_and_fractional_delay():
    rng = np.random.default_rng(0)
    m = rng.standard_normal((4, 4))
    np.testing.assert_allclose(expm(m), scipy.linalg.expm(m), rtol=1e-12)
    a, b, _, _ = observer_form([20.0, 200.0], [1.0, 22.0, 200.0])
    phi, g0, g1 = discretise(a, b, 1e-3, "zoh", 0.0)
    assert not g1.any()
    phi_f, g0_f, g1_f = discretise(a, b, 1e-3, "zoh", 0.4)
    np.testing.assert_allclose(phi_f, phi, rtol=1e-12)
    np.testing.assert_allclose(g0_f + g1_f, g0, rtol=1e-12)  # a held step: the same area
    with pytest.raises(ValueError, match="delay_fraction"):
        discretise(a, b, 1e-3, "zoh", 1.0)
