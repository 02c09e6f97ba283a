"""What the README's bus-servo recipe (record -> identify -> tune -> deploy) must deliver, checked
the same way wherever it runs: on a lone XL330 (``test_bus_recipe``) and on ID 6 of a six-servo
STS3215 arm (``test_bus_shared_bus``), one end-to-end run per family.

The virtual servo is not the family's shipped model but a perturbed one (the truth the
identification must find); it has an object in its jaws for the deploy's hold.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from gripper_env.evaluation.bus_servo import judge, loop_margins
from gripper_env.model.bus_servo import BusServoModel, RegisterSet, load_bus_servo

#: The three P settings the recipe records (P,I,D).
SETTINGS = {
    "sts3215": ["16,0,32", "32,0,32", "64,0,32"],
    "xl330": ["200,0,0", "400,0,0", "800,0,800"],
}


def perturbed_truth(family: str) -> BusServoModel:
    """The servo as it really is: the shipped model with its gains and motor off by 10-20 %."""
    prior = load_bus_servo(family)
    sc, ph = prior.scale, prior.physics
    return prior.with_updates(
        name=f"true-{family}",
        scale=sc.model_copy(update={"kp": sc.kp * 1.15, "kd": sc.kd * 0.85}),
        physics=ph.model_copy(update={"static": ph.static * 1.2, "tau_m_s": ph.tau_m_s * 1.1}),
    )


def check_identified(model_file: Path, truth: BusServoModel) -> None:
    """The identification found the truth's gain scale, with a stated uncertainty."""
    est = json.loads(model_file.read_text())
    assert est["values"]["kp"] == pytest.approx(truth.scale.kp, rel=0.15)
    assert 0 < est["uncertainty"]["kp"] < 0.2
    assert est["fit_pct"] > 90


def check_tuned(tuned: dict[str, Any], model_file: Path, truth: BusServoModel) -> None:
    """The tuned registers (``<name>_registers.json``, read) against the shipped sets on the
    identified model, and their margins on the truth."""
    score = tuned["score"]
    assert score["feasible"]
    # on the identified model: better than every shipped set (factory, LeRobot) that holds on
    # the cost and on the dead band; a shipped set that trips the servo's own protection (the
    # factory's limit under LeRobot's Overload_Torque 25 %) is no rival, only refused
    model = load_bus_servo(str(model_file))
    regs_set = RegisterSet(**tuned["registers"])
    for name, base in tuned["baselines"].items():
        if not base["feasible"]:
            assert base["violations"], name
            continue
        assert score["cost"] < base["cost"], name
        assert score["tracking"]["settled_error_deg"] <= base["tracking"][
            "settled_error_deg"] + 1e-9, name  # fmt: skip
    # ... and on tracking, given the same torque limit: the factory's 100 % limit slews the
    # large steps faster (and trips the overload on the hold); a fit that leaves later loop
    # delays open makes the tuned set cautious enough to lose to that on some runs
    shipped = [b.model_copy(update={"torque_limit": regs_set.torque_limit})
               for b in model.baselines().values()]  # fmt: skip
    for name, same in zip(model.baselines(), judge(model, shipped), strict=True):
        assert score["tracking"]["iae_per_deg_s"] < same.tracking.iae_per_deg_s, name
    # ... and on the servo as it really is (the truth the fit only estimates): the margins
    # near the design's (Ms <= 1.6 on the fitted model's corners and alternatives). Under a
    # full test run's load the pty's timing biases this short fit (3 records, 20
    # generations): Ms 1.62 on the truth was seen, 1.75 before the fit kept its later-delay
    # alternatives, and 1.96 before the recorder dropped slow readings.
    on_truth = loop_margins(truth, regs_set)
    assert on_truth.stable and on_truth.ms <= 1.7 and on_truth.gm_db >= 6.0, on_truth
    factory = tuned["baselines"]["factory"]
    assert not score["hold"]["overload"] and factory["hold"]["overload"]


def check_deployed(report: dict[str, Any], registers: dict[str, int], object_deg: float) -> None:
    """The deploy's report: what the servo read back is what was tuned, the fit of the hold's
    response, and a hold stopped by the object, untripped."""
    assert report["read_back"] == registers
    assert report["fit_pct"] > 90, report
    assert report["hold"]["tripped"] is False
    assert report["hold"]["position_deg"] > object_deg - 3  # stopped by the object
