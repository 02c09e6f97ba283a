import numpy as np
import pytest

from gripper_env.io.config import ConfigError
from gripper_env.model.disturbances import (
    Disturbance,
    available_disturbances,
    describe,
    load_disturbance,
)


def test_presets_exist_and_are_what_they_say():
    assert {"ideal", "actual", "worn"} <= set(available_disturbances())
    ideal = load_disturbance("ideal")
    assert ideal.friction.model == "none" and ideal.sensor.adc_bits == 0
    assert ideal.mechanics.limits_deg is None and ideal.command.refresh_period_s == 0
    actual = load_disturbance("actual")
    assert actual.command.refresh_period_s == pytest.approx(0.020)
    assert actual.command.quantum_deg == 1.0
    assert actual.friction.model == "choudhury"
    # the stops lie beyond the paper's grip and un-grip angles, for every randomised draw
    closed, opened = actual.mechanics.limits_deg
    assert closed < 21.0 and opened > 92.0
    for seed in range(20):
        c, o = actual.sample(np.random.default_rng(seed)).mechanics.limits_deg
        assert 9.0 <= c <= 15.0 < 21.0 and 92.0 < 97.0 <= o <= 103.0
    obj = load_disturbance("grip-object")
    assert 21.0 < obj.mechanics.object_contact_deg < 92.0
    assert obj.randomize["friction.S_deg"] == actual.randomize["friction.S_deg"]  # merged
    assert actual.sensor.adc_bits == 10
    assert 0.2 <= actual.sensor.lsb_deg <= 0.3  # DESIGN.md: 0.2-0.3 deg per count
    worn = load_disturbance("worn")  # extends actual
    assert worn.friction.S_deg > actual.friction.S_deg
    assert worn.sensor.adc_bits == 10
    assert "choudhury" in describe(worn)


def test_microsecond_quantum():
    d = load_disturbance({"extends": "actual", "command": {"quantization": "microseconds"}})
    assert d.command.quantum_deg == pytest.approx(180 / 1856)


def test_randomisation_is_seeded_and_within_range():
    actual = load_disturbance("actual")
    a = actual.sample(np.random.default_rng(7))
    b = actual.sample(np.random.default_rng(7))
    c = actual.sample(np.random.default_rng(8))
    assert a == b and a != c
    lo, hi = actual.randomize["friction.S_deg"]
    draws = [actual.sample(np.random.default_rng(s)).friction.S_deg for s in range(50)]
    assert lo <= min(draws) and max(draws) <= hi
    assert a.randomize == {}


def test_unknown_preset_lists_available():
    with pytest.raises(ConfigError, match="unknown disturbance 'rusty'; available: actual"):
        load_disturbance("rusty")


def test_bad_values_name_the_key(tmp_path):
    path = tmp_path / "d.yaml"
    path.write_text("friction:\n  model: choudhury\n  S_deg: -1\n")
    with pytest.raises(ConfigError, match=r"d\.yaml: key 'friction\.S_deg'"):
        load_disturbance(path)
    path.write_text("friction:\n  modle: kano\n")
    with pytest.raises(ConfigError, match=r"friction\.modle"):
        load_disturbance(path)
    with pytest.raises(ConfigError, match=r"randomize: unknown parameter 'friction\.Q'"):
        load_disturbance({"randomize": {"friction.Q": [0, 1]}})
    with pytest.raises(ConfigError, match=r"friction\.model"):
        load_disturbance({"friction": {"model": "lugre-ish"}})


def test_overrides_compose():
    d = load_disturbance("actual").with_overrides({"mechanics": {"object_contact_deg": 40.0}})
    assert d.mechanics.object_contact_deg == 40.0
    assert d.friction == load_disturbance("actual").friction
    assert isinstance(d, Disturbance)


def test_randomising_one_entry_of_a_pair_and_bad_keys():
    d = load_disturbance({"extends": "ideal", "randomize": {"command.range_deg.1": [170, 175]}})
    lo, hi = d.sample(np.random.default_rng(0)).command.range_deg
    assert lo == -np.inf and 170 <= hi <= 175
    with pytest.raises(ConfigError, match="no entry 2"):
        load_disturbance({"extends": "actual", "randomize": {"mechanics.limits_deg.2": [1, 2]}})
    with pytest.raises(ConfigError, match="unknown parameter"):
        load_disturbance({"extends": "actual", "randomize": {"mechanics.nope": [1, 2]}})
