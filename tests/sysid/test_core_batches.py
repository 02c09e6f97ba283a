"""The grey-box fit's fast friction outputs equal the core's (an invariant of the servo model).

:class:`gripper_env.sysid.core_batches.TickRuns` runs the core two steps per refresh tick instead
of twenty: friction acts on the latched command, which changes only on ticks, and a held command
makes a sliding jaw stick on the next step. Its outputs must be the full-rate core's at the ticks,
exactly, whatever the quantisation, friction model, backlash or phase.
"""

from __future__ import annotations

import numpy as np
import pytest

from gripper_env.model.disturbances import load_disturbance
from gripper_env.sysid.core_batches import CoreRuns, TickRuns, tick_index


def _commands() -> list[np.ndarray]:
    parts = [np.full(1013, 92.0), np.full(2000, 60.0), np.linspace(60.0, 85.0, 6000),
             np.linspace(85.0, 70.0, 3000)]  # fmt: skip
    ramps = np.concatenate(parts)
    rng = np.random.default_rng(0)
    walk = 60.0 + np.cumsum(rng.normal(0.0, 0.05, 8000))
    walk[:100] = walk[100]  # at rest until the first ticks
    return [ramps, walk]


@pytest.mark.parametrize("quantization", ["degree", "microseconds", "none"])
def test_two_steps_per_tick_are_the_core_at_its_ticks(quantization):
    pairs = [(3.1, 0.3), (2.0, 0.6), (0.0, 0.0), (5.0, 3.0), (0.3, 0.8)]
    base = load_disturbance({"name": "b", "extends": "actual",
                             "command": {"quantization": quantization},
                             "friction": {"backlash_deg": 0.3}})  # fmt: skip
    for u in _commands():
        core = CoreRuns(u, u, 1e-3, base)
        for phase in (0, 7, 19):
            idx = tick_index(core.n, core.refresh, phase)
            ticks = TickRuns(core, phase)
            for model in ("choudhury", "kano"):
                full = core.friction_outputs(pairs, model, phase)[:, idx]
                np.testing.assert_array_equal(ticks.friction_outputs(pairs, model), full)
