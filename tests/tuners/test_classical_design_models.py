"""A robust textbook row tries every identification and their nominal as its design model and
keeps the admitted design of least tuning cost (issue 42): the choice, the record, the refusal
that names every model, and the nominal plant."""

import math
from types import SimpleNamespace

import pytest

from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import load_plant
from tuners.classical import tuner as T
from tuners.settings import ClassicalSettings, load_settings

PLANTS = ["test2", "test3", "test4"]


@pytest.fixture
def fake_scans(monkeypatch):
    """Each design model's knob scan replaced by a given outcome: a tuning cost, or refused."""
    outcomes = {}
    seen = []

    def constrained_design(method, plant, disturbance, settings, scorer, n):
        seen.append(plant.name)
        cost = outcomes[plant.name]
        if cost is None:
            raise ValueError(f"{method}: infeasible: no setting of tau_c_factor in [0.5, 8] meets "
                             "the admission rule (...); binding constraint 'ms' at the nearest "
                             f"setting: Ms 3 > 1.6 on {plant.name}")  # fmt: skip
        gains = PIDGains(cost / 100, cost, 0.0, n)  # the cost marks the model's gains
        return gains, {"knob": {"name": "tau_c_factor", "value": cost / 10},
                       "best_value_tuning": cost, "episodes": 10}  # fmt: skip

    constraints = SimpleNamespace(ms_max=1.6, gm_min_db=6.0,
                                  limits=lambda search: {"stop_clearance_deg": 1.0})  # fmt: skip
    task = SimpleNamespace(plants=[load_plant(p) for p in PLANTS], search=True,
                           objective=SimpleNamespace(constraints=constraints))  # fmt: skip
    monkeypatch.setattr(T, "constrained_design", constrained_design)
    monkeypatch.setattr(T, "make_scorer", lambda inputs, opt, plants: SimpleNamespace(task=task))
    inputs = SimpleNamespace(plant=load_plant("test2"), disturbance=load_disturbance("actual"),
                             settings=SimpleNamespace(pid=SimpleNamespace(N=100.0)))  # fmt: skip
    return outcomes, seen, inputs


def test_the_admitted_design_of_least_tuning_cost_is_kept(fake_scans):
    outcomes, seen, inputs = fake_scans
    outcomes.update(test2=None, test3=25.0, test4=30.0, nominal=27.0)
    tuner = T.ClassicalTuner("simc", plants=PLANTS)
    assert tuner.design_models == ("test2", "test3", "test4", "nominal")
    gains, tuning = T.tune_rule("simc", inputs, load_settings(ClassicalSettings), plants=PLANTS,
                                design_models=tuner.design_models)  # fmt: skip
    assert seen == ["test2", "test3", "test4", "nominal"]
    assert tuning["design_model"] == "test3" and gains.I == 25.0
    assert tuning["tuned_on"] == PLANTS and tuning["episodes"] == 30  # three scans of 10
    tried = tuning["design_models"]
    assert tried["test2"] == {"admitted": False,
                              "reason": "binding constraint 'ms' at the nearest setting: Ms 3 > "
                                        "1.6 on test2"}  # fmt: skip
    assert [tried[m]["tuning_cost"] for m in ("test3", "test4", "nominal")] == [25.0, 30.0, 27.0]


def test_a_rule_admitted_on_no_design_model_names_each_ones_reason(fake_scans):
    outcomes, _, inputs = fake_scans
    outcomes.update(test2=None, test3=None, test4=None, nominal=None)
    with pytest.raises(ValueError) as exc:
        T.tune_rule("simc", inputs, load_settings(ClassicalSettings), plants=PLANTS,
                    design_models=("test2", "test3", "test4", "nominal"))  # fmt: skip
    text = str(exc.value)
    assert text.startswith("simc: infeasible:") and "\n" not in text
    for model in [*PLANTS, "nominal"]:
        assert f"designed on {model}: binding constraint 'ms'" in text


def test_a_per_plant_row_designs_on_its_plant_only():
    assert T.ClassicalTuner("simc").design_models == ()
    with pytest.raises(ValueError, match="test1"):
        T.ClassicalTuner("simc", plants=PLANTS, design_models=["test1"])


def test_the_nominal_is_the_centre_of_the_sets_fopdt_models():
    """The nominal's own FOPDT: the mean gain and the geometric-mean time constant of the
    identifications' (read off its step response on the 1 ms grid: within a sample)."""
    from tuners.fopdt import fit_fopdt

    dist = load_disturbance("actual")
    settings = load_settings(ClassicalSettings)
    models = [fit_fopdt(load_plant(p), dist, settings) for p in PLANTS]
    nominal = T.nominal_plant([load_plant(p) for p in PLANTS], dist, settings)
    mine = fit_fopdt(nominal, dist, settings)
    tau = math.exp(sum(math.log(m.tau_s) for m in models) / 3)
    assert min(m.tau_s for m in models) < tau < max(m.tau_s for m in models)
    assert mine.tau_s == pytest.approx(tau, abs=1.5e-3)
    assert mine.k == pytest.approx(sum(m.k for m in models) / 3, rel=1e-3)
    assert nominal.name == "nominal" and nominal.order == 1
