"""``gripper_env/GripperServoRobust-v0``: one controller for every identification, with its
stability margin as a constraint whose cost is in ``info`` (a safe-RL environment)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.servo import GripperServoEnv
from gripper_env.evaluation.objective import load_objective
from gripper_env.io.config import ConfigError
from gripper_env.model.plants import Plant, load_plant

__all__ = [
    "MARGIN_SUFFIX",
    "GripperServoRobustEnv",
    "SwingCost",
    "margin_floor_db",
    "raised_plant",
]

#: A plant whose gain is raised by the margin floor is named ``<plant>@+<dB>dB``.
MARGIN_SUFFIX = "dB"


def margin_floor_db(ms_max: float | None = None) -> float:
    """The gain margin (dB) that ``Ms <= ms_max`` guarantees a linear loop,
    ``20 log10(Ms / (Ms - 1))``: 8.52 dB for the objective's 1.6 (``configs/objective.yaml``,
    the default). A learned controller's measured gain margin must reach it."""
    ms = load_objective().constraints.ms_max if ms_max is None else float(ms_max)
    return 20.0 * math.log10(ms / (ms - 1.0))


def raised_plant(plant: Plant, gain_db: float) -> Plant:
    """``plant`` with its gain multiplied by ``10**(gain_db / 20)`` (the numerator scaled)."""
    k = 10.0 ** (gain_db / 20.0)
    return dataclasses.replace(
        plant,
        name=f"{plant.name}@+{gain_db:.3g}{MARGIN_SUFFIX}",
        num=tuple(k * c for c in plant.num),
    )


@dataclasses.dataclass(frozen=True)
class SwingCost:
    """The per-step constraint cost of a loop that swings, as :mod:`tuners.probe` judges one:
    over a hold of the reference, the true jaw angle still goes back and forth.

    A step (control period) costs 1 when the reference has held still for ``settle_s`` before
    the last ``window_s`` of periods and all through them, and over the true jaw angles at the
    ends of those periods the jaw has swung by more than ``swing_deg``: their peak-to-peak range
    beyond their net change, ``max y - min y - |y_n - y_0|``. A loop that oscillates on its own
    pays every step of every long hold; one that settles, even slowly (a cautious loop still
    creeping to the target), pays nothing: its approach is monotone.

    Attributes
    ----------
    swing_deg : float
        How far back (deg) counts as a swing. The environment takes the preset's friction band
        (the widest stiction band its randomisation draws plus backlash: 3.5 deg on ``actual``),
        as the objective's settling band does: stick-slip hunting within it is friction, not a
        loop short of margin, and a swing beyond it is what the probe's oscillation looks like
        on the actual gripper.
    settle_s : float
        How long the reference must have held still (s) before the window starts.
    window_s : float
        Over how long the swing is measured (s).
    """

    swing_deg: float = 3.5
    settle_s: float = 1.0
    window_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("swing_deg", "settle_s", "window_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"GripperServoRobust-v0: argument {name!r}: expected a "
                                  f"positive number, got {value!r}")  # fmt: skip

    def periods(self, control_period_s: float) -> int:
        """The window in control periods."""
        return max(2, round(self.window_s / control_period_s))

    def cost(
        self, positions_deg: Sequence[float], reference_deg: np.ndarray, t_end: int, dt_s: float,
        control_period_s: float,
    ) -> float:  # fmt: skip
        """The cost of the period ending at physics step ``t_end``.

        Parameters
        ----------
        positions_deg : sequence of float
            The true jaw angle at the end of every period so far, this one last (deg).
        reference_deg : ndarray
            The episode's reference, one sample per physics step (deg).
        t_end : int
            Physics steps from the episode's start to this period's end.
        dt_s, control_period_s : float
            Physics step and control period (s).
        """
        n = self.periods(control_period_s)
        settle = round((self.settle_s + self.window_s) / dt_s)
        if len(positions_deg) < n or t_end < settle:
            return 0.0
        last = len(reference_deg) - 1
        held = reference_deg[min(t_end - settle, last) : min(t_end, last + 1)]
        if held.size == 0 or float(np.ptp(held)) > 0.0:
            return 0.0
        window = np.asarray(positions_deg[-n:], dtype=float)
        if not np.all(np.isfinite(window)):
            return 1.0
        swing = float(np.ptp(window)) - abs(float(window[-1] - window[0]))
        return 1.0 if swing > self.swing_deg else 0.0


class GripperServoRobustEnv(GripperServoEnv):
    """One controller for every identification of the gripper, judged with its stability
    margin as a constraint: ``GripperServo-v0`` with a cost in ``info`` (a constrained MDP).

    ## Description

    The paper identified the gripper four times, and the fast time constants of test2, test3
    and test4 differ ninefold: a deployable controller must work on each. Every episode draws
    one of ``plant`` (hidden from the agent: the observation is ``GripperServo-v0``'s), the
    actual gripper's friction, stops and noise (``randomize``) and a random grip/un-grip
    profile of ``episode_s``. Half the episodes are *margin episodes*: the drawn plant's gain is
    raised by ``margin_db`` (8.52 dB by default, the gain margin that the objective's
    ``Ms <= 1.6`` guarantees a linear loop). A controller whose loop still settles there has at
    least that measured gain margin (:mod:`tuners.probe` measures it by the same criterion on
    the frictionless loop); one that swings pays the cost.

    ## Action and Observation Spaces

    ``GripperServo-v0``'s (``residual`` and every other argument work the same).

    ## Rewards and Costs

    The reward is ``GripperServo-v0``'s (tracking, overshoot, chatter). ``info["cost"]`` is the
    step's constraint cost, ``cost_swing + cost_stop`` (the safety-gymnasium convention: a
    constrained-RL algorithm keeps its episode sum under a budget):

    * ``cost_swing`` (:class:`SwingCost`): 1 when the reference has held still for 2 s and the
      true jaw angle has swung, over the last 1 s, by more than the preset's friction band
      (3.5 deg on ``actual``), beyond its net change;
    * ``cost_stop``: 1 when the jaw touched a mechanical stop during the step (the benchmark
      refuses any touch).

    ``info["margin_episode"]`` says whether the episode's gain is raised, ``info["plant"]`` at
    reset which plant was drawn (a raised one is named ``test2@+8.52dB``).

    ## Episode End

    Truncation at the end of the profile (500 steps for the default 10 s), and by the
    ``TimeLimit`` of 500 steps registered with the id; termination only if the loop diverges.

    ## Arguments

    ```python
    import gymnasium as gym
    env = gym.make(
        "gripper_env:gripper_env/GripperServoRobust-v0",
        plant=("test2", "test3", "test4"),  # the identifications, one drawn per episode
        margin_db=None,      # the margin episodes' gain rise (dB); None: 8.52, 0: none
        reference="random", episode_s=10.0, randomize=True, disturbance="actual",
        swing_deg=None, settle_s=1.0, window_s=1.0,  # the swing cost (SwingCost; None: the
                                                     # preset's friction band)
    )
    ```

    ## Version History

    * v0: initial version.
    """

    _name = "GripperServoRobust-v0"

    def __init__(
        self,
        *,
        plant: Any = ("test2", "test3", "test4"),
        margin_db: float | None = None,
        reference: Any = "random",
        episode_s: float = 10.0,
        randomize: Any = True,
        swing_deg: float | None = None,
        settle_s: float = 1.0,
        window_s: float = 1.0,
        **kwargs: Any,
    ) -> None:
        floor = margin_floor_db() if margin_db is None else margin_db
        if not (isinstance(floor, int | float) and math.isfinite(floor) and floor >= 0):
            raise ConfigError(f"{self._name}: argument 'margin_db': expected a gain rise in dB "
                              f">= 0 or None, got {margin_db!r}")  # fmt: skip
        names = [plant] if isinstance(plant, str | Plant) else list(plant)
        try:
            nominal = [load_plant(p) for p in names]
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{self._name}: argument 'plant': {exc}") from None
        plants = nominal + ([raised_plant(p, floor) for p in nominal] if floor > 0 else [])
        self.margin_db = float(floor)
        self.n_nominal = len(nominal)
        super().__init__(plant=plants, reference=reference, episode_s=episode_s,
                         randomize=randomize, **kwargs)  # fmt: skip
        band = self.settings.disturbance.friction_band_deg
        self.swing = SwingCost(max(band, 1.0) if swing_deg is None else swing_deg, settle_s,
                               window_s)  # fmt: skip
        self._positions: list[float] = []
        self._contact = 0.0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = super().reset(seed=seed, options=options)
        self._positions = []
        self._contact = float(self._batch.sim.contact_steps[0])
        info["margin_episode"] = self.margin_episode
        return obs, info

    @property
    def margin_episode(self) -> bool:
        """Whether the current episode's plant gain is raised by the margin floor."""
        ep = self._batch.episodes[0]
        return ep is not None and ep.plant_index >= self.n_nominal

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = super().step(action)
        sim, batch = self._batch.sim, self._batch
        self._positions.append(float(sim.position_deg[0]) if not terminated else math.nan)
        contact = float(sim.contact_steps[0])
        stop = 1.0 if contact > self._contact else 0.0
        self._contact = contact
        ep = batch.episodes[0]
        assert ep is not None
        swing = self.swing.cost(
            self._positions, ep.reference.values_deg, int(batch.env[0, K.E_T]),
            self.settings.dt_s, self.settings.control_period_s,
        )  # fmt: skip
        info = {
            **info,
            "cost": swing + stop,
            "cost_swing": swing,
            "cost_stop": stop,
            "margin_episode": self.margin_episode,
        }
        return obs, reward, terminated, truncated, info
