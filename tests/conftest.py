"""Shared fixtures: the paper's numbers as independent truth."""

import os

import matplotlib
import pytest

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

from gripper_env.paper import PLANTS as PAPER_PLANTS


@pytest.fixture(params=sorted(PAPER_PLANTS))
def paper_plant_name(request):
    return request.param
