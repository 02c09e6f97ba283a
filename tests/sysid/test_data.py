"""Input checks: each bad record is refused with a message that names the problem."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from gripper_env.sysid import NonUniformSamplingWarning, fit_percent, tfest
from gripper_env.sysid.data import prepare_data
from gripper_env.sysid.discrete import arx

from .signals import DT_S, lsim_zoh

NUM, DEN = [20.0, 200.0], [1.0, 22.0, 200.0]


@pytest.fixture(scope="module")
def record():
    u = np.repeat([92.0, 21.0, 60.0, 92.0, 40.0], 400)
    y = 92.0 + lsim_zoh(NUM, DEN, u - 92.0)
    return u, y


@pytest.mark.parametrize(
    ("u", "y", "message"),
    [
        ([], [], "u is empty"),
        ([1.0, 2.0], [], "y is empty"),
        (["a", "b"], [1.0, 2.0], "u must be numeric"),
        ([1.0, np.nan, 2.0], [1.0, 2.0, 3.0], r"u contains a non-finite value \(nan\) at index 1"),
        ([1.0, 2.0, 3.0], [1.0, np.inf, 3.0], "y contains a non-finite value"),
        ([1.0, 2.0, 3.0], [1.0, 2.0], r"different lengths \(3 and 2 samples\)"),
        ([1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0], "too short for the model order: 4 samples"),
        (np.full(100, 5.0), np.arange(100.0), "u is constant"),
        (np.arange(100.0), np.full(100, 7.0), "y is constant"),
        (np.ones((10, 10)), np.ones((10, 10)), "must be 1-D"),
    ],
)
def test_bad_records(u, y, message):
    with pytest.raises(ValueError, match=message):
        tfest(DT_S, u, y)


@pytest.mark.parametrize("dt", [0.0, -1e-3, np.nan, "fast"])
def test_bad_sample_interval(dt, record):
    u, y = record
    with pytest.raises(ValueError, match="dt_s must be"):
        tfest(dt, u, y)


def test_bad_orders(record):
    u, y = record
    with pytest.raises(ValueError, match="n_zeros must be between 0 and n_poles"):
        tfest(DT_S, u, y, n_poles=1, n_zeros=2)
    with pytest.raises(ValueError, match="n_poles must be >= 1"):
        tfest(DT_S, u, y, n_poles=0, n_zeros=0)
    with pytest.raises(ValueError, match="offset must be one of"):
        tfest(DT_S, u, y, offset="median")


def test_time_stamps(record):
    u, y = record
    t = np.arange(u.size) * DT_S + 3.0
    est = tfest(t, u, y)
    assert est.dt_s == pytest.approx(DT_S) and not est.resampled
    with pytest.raises(ValueError, match="strictly increasing"):
        tfest(np.concatenate([t[:10], t[9:-1]]), u, y)
    with pytest.raises(ValueError, match="t_s and u have different lengths"):
        tfest(t[:-1], u, y)
    gap = t.copy()
    gap[1000:] += 5 * DT_S  # a dropped stretch: refused, not papered over
    with pytest.raises(ValueError, match=r"gap in the time stamps.*--max-gap 6"):
        tfest(gap, u, y)
    est = tfest(gap, u, y, max_gap=6.0)  # or resampled across, when allowed
    assert est.resampled


def test_mild_jitter_is_snapped_without_a_warning(record):
    u, y = record
    rng = np.random.default_rng(3)
    t = np.arange(u.size) * DT_S + rng.uniform(-0.01, 0.01, u.size) * DT_S
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = tfest(t, u, y)
    assert est.time_base == "snapped" and not est.resampled
    np.testing.assert_allclose(est.den, DEN, rtol=1e-3)


def test_irregular_stamps_are_resampled_with_a_warning(record):
    u, y = record
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.4, 1.6, u.size)) * DT_S  # a logger without a clock
    with pytest.warns(NonUniformSamplingWarning, match="resampled"):
        data = prepare_data(t, u, y)
    assert data.resampled and data.dt_s == pytest.approx(DT_S, rel=0.02)


def test_uniform_data_do_not_warn(record):
    u, y = record
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tfest(np.arange(u.size) * DT_S, u, y)


@pytest.mark.parametrize("offset", ["initial", "mean", "none"])
def test_operating_point_is_restored(offset, record):
    u, y = record
    est = tfest(DT_S, u, y, offset=offset)
    np.testing.assert_allclose(est.den, DEN, rtol=1e-3)
    assert fit_percent(y, est.simulate(u)) > 99.9
    data = prepare_data(DT_S, u, y, offset=offset)
    if offset == "initial":
        assert (data.u_op, data.y_op) == (92.0, pytest.approx(92.0))
    elif offset == "mean":
        assert data.u_op == pytest.approx(np.mean(u))
    else:
        assert (data.u_op, data.y_op) == (0.0, 0.0)


def test_discrete_estimators_share_the_checks():
    with pytest.raises(ValueError, match="u is constant"):
        arx(DT_S, np.ones(100), np.arange(100.0))
    with pytest.raises(ValueError, match="na must be >= 1"):
        arx(DT_S, np.arange(100.0), np.arange(100.0) ** 2, na=0)
