"""tfest on known plants driven by a rich input through the real measurement chain
(0.3 deg Gaussian noise, then a 10-bit ADC over 0..270 deg)."""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.sysid import tfest

from .signals import DT_S, adc, fit_pct, lsim_zoh, rich_input

PLANTS = {
    # name: (num, den, record length s)
    "fast": ([20.0, 200.0], [1.0, 22.0, 200.0], 30.0),
    "slow": ([2.0, 4.0], [1.0, 3.0, 4.0], 60.0),
}


@pytest.fixture(scope="module", params=sorted(PLANTS))
def identified(request):
    num, den, duration = PLANTS[request.param]
    rng = np.random.default_rng(20240 + len(request.param))
    u = rich_input(duration, rng)
    y_clean = 92.0 + lsim_zoh(num, den, u - 92.0)
    y = adc(y_clean, rng)
    return num, den, u, y, y_clean, tfest(DT_S, u, y, n_poles=2, n_zeros=1)


def test_coefficients_within_2_percent(identified):
    num, den, _, _, _, est = identified
    assert est.den[0] == 1.0
    np.testing.assert_allclose(est.den, den, rtol=0.02)
    np.testing.assert_allclose(est.num, num, rtol=0.02)


def test_fit_and_stability(identified):
    _, _, u, y, y_clean, est = identified
    assert est.stable
    assert est.fit_pct >= 95.0
    # The reported fit is the one of the reported residuals and of simulate().
    assert est.fit_pct == pytest.approx(fit_pct(y, y - est.residuals), abs=1e-9)
    assert est.fit_pct == pytest.approx(fit_pct(y, est.simulate(u)), abs=1e-6)
    rest = est.rest_state(float(np.mean(y[:500])), float(u[0]))  # at rest for 0.5 s
    assert est.fit_pct_rest == pytest.approx(fit_pct(y, est.simulate(u, rest)), abs=1e-6)
    # Against the noise-free output the model is far better than against the noisy data.
    assert fit_pct(y_clean, est.simulate(u)) > 99.5
    # Residuals are the measurement noise (0.3 deg plus quantisation, ~0.31 deg RMS).
    assert 0.29 < np.sqrt(np.mean(est.residuals**2)) < 0.33


def test_standard_errors_cover_truth(identified):
    num, den, _, _, _, est = identified
    truth = np.concatenate([den[1:], num])
    z = (est.params - truth) / est.params_std
    assert np.all(np.isfinite(est.params_std)) and np.all(est.params_std > 0)
    assert np.max(np.abs(z)) < 5.0, z


def test_paper_form_and_dict(identified):
    _, _, _, _, _, est = identified
    text = est.paper_form()
    assert text.startswith("(") and " s + " in text and "/ (s^2 + " in text
    d = est.to_dict()
    assert d["num"] == pytest.approx(list(est.num)) and d["den"][0] == 1.0
    assert set(d["params_std"]) == {"a1", "a0", "b1", "b0"}
