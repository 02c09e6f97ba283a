"""ARX and OE baselines on a known discrete system."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from gripper_env.sysid.discrete import arx, oe

from .signals import fit_pct

B = [0.0, 0.1, 0.05]  # z^-1 powers, one sample delay
A = [1.0, -1.5, 0.7]
DT = 0.01


@pytest.fixture(scope="module")
def record():
    rng = np.random.default_rng(11)
    u = 56.0 + np.repeat(rng.uniform(-35, 35, 400), 50)
    u[:100] = 56.0
    y0 = 40.0 + signal.lfilter(B, A, u - 56.0)
    return u, y0, y0 + rng.normal(0.0, 0.5, u.size)


def test_arx_is_exact_without_noise(record):
    u, y0, _ = record
    est = arx(DT, u, y0, na=2, nb=2, nk=1)
    np.testing.assert_allclose(est.params, [-1.5, 0.7, 0.1, 0.05], atol=1e-9)
    assert est.fit_pct > 99.999 and est.stable
    assert est.model.dt == DT
    np.testing.assert_allclose(est.model.num[0][0], [0.1, 0.05], atol=1e-9)
    np.testing.assert_allclose(est.model.den[0][0], [1.0, -1.5, 0.7], atol=1e-9)


def test_oe_is_consistent_where_arx_is_biased(record):
    u, y0, y = record
    est_oe = oe(DT, u, y, nb=2, nf=2, nk=1)
    est_arx = arx(DT, u, y, na=2, nb=2, nk=1)
    truth = np.array([0.1, 0.05, -1.5, 0.7])
    np.testing.assert_allclose(est_oe.params, truth, rtol=0.02)
    assert np.max(np.abs((est_oe.params - truth) / est_oe.params_std)) < 5.0
    arx_as_oe = np.concatenate([est_arx.params[2:], est_arx.params[:2]])
    assert np.linalg.norm(arx_as_oe - truth) > 5 * np.linalg.norm(est_oe.params - truth)
    assert est_oe.fit_pct > est_arx.fit_pct
    assert est_oe.fit_pct == pytest.approx(fit_pct(y, est_oe.simulate(u)), abs=1e-6)
    assert fit_pct(y0, est_oe.simulate(u)) > 99.0
    assert est_oe.stable and est_oe.converged


def test_orders_and_delay(record):
    u, y0, _ = record
    est = arx(DT, u, y0, na=2, nb=3, nk=0)  # over-parameterised, includes a direct term
    np.testing.assert_allclose(est.params, [-1.5, 0.7, 0.0, 0.1, 0.05], atol=1e-8)
    assert est.param_names == ("a1", "a2", "b1", "b2", "b3")
