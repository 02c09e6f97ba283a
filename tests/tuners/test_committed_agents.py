"""Every committed agent loads alone, rebuilds its environment and reproduces its held-out runs
(issue 22: trained agents that load and run)."""

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from tests.tuners.conftest import REPO

pytestmark = pytest.mark.slow  # the end-to-end tier (pytest -m slow)

STUDIES = sorted((REPO / "results" / "rl").glob("controller-*/study.json"))


def _cases():
    for study_path in STUDIES:
        study = json.loads(study_path.read_text())
        plant = next(iter(study["per_plant"]))  # the first plant it was evaluated on
        for entry in study["seeds"]:
            agent = study_path.parent / f"seed-{entry['seed']}" / "best"
            costs = [r["cost"] for r in entry["plants"][plant]["runs"]]
            yield pytest.param(agent, plant, costs, id=f"{study_path.parent.name}-{entry['seed']}")


def test_there_are_committed_agents():
    assert STUDIES, "results/rl/controller-*/study.json: the benchmark's RL controllers"
    assert len(list(_cases())) >= 14  # 3 seeds per plant, 5 across identifications


@pytest.mark.parametrize("agent_dir, plant, costs", list(_cases()))
def test_a_committed_agent_reproduces_its_held_out_cost(agent_dir: Path, plant, costs):
    from tuners import cli
    from tuners.rl.agents import agent_kwargs, load_agent
    from tuners.rl.command import build_parser
    from tuners.rl.controller import evaluate_policy

    agent = load_agent(agent_dir)
    inputs = cli.resolve(build_parser().parse_args(["export", "--plant", plant]))
    seeds = inputs.settings.seeds.seeds()
    _, runs, _, _ = evaluate_policy(agent, inputs, agent_kwargs(agent), seeds, plant=plant)
    assert [r["cost"] for r in runs] == pytest.approx(costs, rel=1e-9)
    assert np.all([r["stable"] for r in runs])
