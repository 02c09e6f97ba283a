import control
import numpy as np
import pytest
import yaml

from gripper_env.io.config import ConfigError
from gripper_env.model.plants import Plant, available_plants, load_plant
from gripper_env.paper import PLANTS as PAPER_PLANTS


def test_paper_plants_are_exactly_as_printed(paper_plant_name):
    num, den, fit = PAPER_PLANTS[paper_plant_name]
    plant = load_plant(paper_plant_name)
    assert list(plant.num) == num
    assert list(plant.den) == den  # test2 keeps its leading 2
    assert plant.fit_pct == fit
    assert plant.dt_s == 1e-3
    assert plant.jaw_range_deg == (21.0, 92.0)
    assert plant.description


def test_available_plants_lists_the_four():
    assert set(available_plants()) >= {"test1", "test2", "test3", "test4"}


def test_tf_and_zoh_match_python_control(paper_plant_name):
    plant = load_plant(paper_plant_name)
    num, den, _ = PAPER_PLANTS[paper_plant_name]
    ref = control.tf(num, den)
    w = np.logspace(-3, 2, 20)
    np.testing.assert_allclose(plant.tf(1j * w), ref(1j * w), rtol=1e-12)
    # our observable-form ZOH matrices give the same discrete TF as control.c2d
    a, b, d = plant.zoh_matrices()
    ss = control.ss(a, b.reshape(-1, 1), np.eye(1, len(b)), d, 1e-3)
    z = np.exp(1j * w * 1e-3 * 50)
    # (evaluating a TF with poles near z = 1 loses digits: 1e-6 is what double precision allows)
    np.testing.assert_allclose(ss(z), control.c2d(ref, 1e-3, "zoh")(z), rtol=1e-6)
    assert plant.discretize().dt == 1e-3


def test_known_facts_about_the_plants():
    t1 = load_plant("test1")
    np.testing.assert_allclose(sorted(t1.poles.imag), [-0.04575, 0.04575], atol=1e-4)
    np.testing.assert_allclose(t1.poles.real, -0.05555, atol=1e-5)
    gains = [load_plant(n).dc_gain for n in ("test2", "test3", "test4")]
    np.testing.assert_allclose(gains, [0.925, 1.005, 0.98], atol=1e-3)
    fast = [min(load_plant(n).poles.real) for n in ("test2", "test3", "test4")]
    np.testing.assert_allclose(fast, [-10.34, -20.94, -96.14], atol=0.01)


def test_rest_state_holds_the_output(paper_plant_name):
    plant = load_plant(paper_plant_name)
    a, b, d = plant.observable_form()
    x0, u0 = plant.rest_state(92.0, exact=True)
    np.testing.assert_allclose(a @ x0 + b * u0, 0.0, atol=1e-9)
    assert x0[0] + d * u0 == pytest.approx(92.0)
    x0, u0 = plant.rest_state(92.0)
    assert u0 == 92.0 and x0[0] == pytest.approx(92.0)
    # quasi-rest: only the slowest state may move, and slowly
    deriv = a @ x0 + b * u0
    assert abs(deriv[0]) < 1e-9


def test_user_plant_from_yaml(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump({"name": "mine", "num": [10.0], "den": [1.0, 10.0]}))
    plant = load_plant(path)
    assert plant.name == "mine" and plant.order == 1
    assert plant.dc_gain == 1.0
    assert load_plant(str(path)).num == (10.0,)


def test_unknown_plant_lists_available():
    with pytest.raises(ConfigError, match=r"unknown plant 'test9'; available: .*test1.*test4"):
        load_plant("test9")


@pytest.mark.parametrize(
    ("num", "den", "message"),
    [
        ([1.0, 2.0, 3.0], [1.0, 2.0], "improper"),
        ([], [1.0, 2.0], "at least one coefficient"),
        ([1.0], [], "at least one coefficient"),
        ([float("nan")], [1.0, 2.0], "finite"),
        ([1.0], [1.0, float("inf")], "finite"),
        ([1.0], [0.0, 0.0], "all coefficients are zero"),
        ([1.0], [5.0], "at least one pole"),
    ],
)
def test_bad_coefficients_are_refused(tmp_path, num, den, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump({"name": "bad", "num": num, "den": den}))
    with pytest.raises(ConfigError, match=message) as info:
        load_plant(path)
    assert str(path) in str(info.value)
    with pytest.raises(ConfigError, match=message):
        Plant.from_coefficients(num, den)


def test_malformed_yaml_names_the_file_and_key(tmp_path):
    path = tmp_path / "typo.yaml"
    path.write_text("name: x\nnum: [1]\nden: [1, 2]\nfit_percent: 3\n")
    with pytest.raises(ConfigError, match=r"typo\.yaml: key 'fit_percent'"):
        load_plant(path)
    path.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_plant(path)
    with pytest.raises(ConfigError, match="does not exist"):
        load_plant(tmp_path / "missing.yaml")
