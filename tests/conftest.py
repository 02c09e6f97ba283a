"""Shared fixtures: the paper's numbers as independent truth."""

import os

import matplotlib
import pytest

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

# Table 1 / Figure 7 of the paper, exactly as printed.
PAPER_PLANTS = {
    "test1": ([0.006099, 0.00517], [1.0, 0.1111, 0.005179], 96.42),
    "test2": ([20.7, 0.002852], [2.0, 20.68, 0.003084], 95.33),
    "test3": ([21.2, 0.177], [1.0, 20.95, 0.1761], 95.90),
    "test4": ([95.09, 1.225], [1.0, 96.15, 1.25], 95.88),
}

# Table 3 of the paper.
PAPER_GAINS = {
    "untuned_tf": (-0.4, 7.0, -0.045),
    "tuned_tf": (1.0, 9.0, -0.001),
    "untuned_hw": (-0.3, -5.0, -0.0005),
    "tuned_hw": (-0.5, -3.6, 0.000186),
}


@pytest.fixture(params=sorted(PAPER_PLANTS))
def paper_plant_name(request):
    return request.param
