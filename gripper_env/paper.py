"""The paper: its title (:data:`TITLE`) and its published numbers.

The constants here are the reference every reproduction and test compares against, transcribed
from the paper's Figure 7 and Tables 2-4 (test2's denominator keeps its leading 2).
``python -m tuners.paper`` (:mod:`tuners.paper.reproduce`) reproduces the tables and
figures into ``results/paper_reproduction.md``.
"""

from __future__ import annotations

__all__ = ["CITATION", "PID_GAINS", "PLANTS", "TABLE2_SD", "TABLE4_SD", "TITLE"]

#: The study this project starts from (CITATION.cff; the copy worked from names neither its
#: authors nor its venue).
TITLE = (
    "Model identification of a low-cost robot gripper by using MATLAB System Identification "
    "Toolbox (SIT)"
)
#: How reports cite it.
CITATION = f'"{TITLE}" (CITATION.cff)'


#: Figure 7 / Table 1: numerator, denominator (highest power of s first), best fit %.
PLANTS: dict[str, tuple[list[float], list[float], float]] = {
    "test1": ([0.006099, 0.00517], [1.0, 0.1111, 0.005179], 96.42),
    "test2": ([20.7, 0.002852], [2.0, 20.68, 0.003084], 95.33),
    "test3": ([21.2, 0.177], [1.0, 20.95, 0.1761], 95.90),
    "test4": ([95.09, 1.225], [1.0, 96.15, 1.25], 95.88),
}

#: Table 3: (P, I, D) of the untuned and tuned PID, on TF test2 and on the hardware.
PID_GAINS: dict[str, tuple[float, float, float]] = {
    "untuned_tf": (-0.4, 7.0, -0.045),
    "tuned_tf": (1.0, 9.0, -0.001),
    "untuned_hw": (-0.3, -5.0, -0.0005),
    "tuned_hw": (-0.5, -3.6, 0.000186),
}

#: Table 2: SD of the actual gripper's and of each TF's direct response.
TABLE2_SD: dict[str, float] = {
    "actual": 34.611,
    "test1": 26.891,
    "test2": 34.167,
    "test3": 34.000,
    "test4": 33.934,
}

#: Table 4: SD of the closed-loop response, (on TF test2, on the actual gripper).
TABLE4_SD: dict[str, tuple[float, float]] = {"untuned": (36.031, 36.760), "tuned": (33.339, 34.628)}
