"""``gripper_env/GripperBusServo-v0``: the agent is the host and sends a bus servo its goals."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from gripper_env.envs.bus_settings import (
    DEFAULT_HOLD_S,
    DEFAULT_RESIDUAL_DEG,
    BusSettings,
    bus_reward,
    check_bus_action,
    draw_bus_reference,
    parse_bus_settings,
    tracked_reference,
    trip_reward,
    write_observation,
)
from gripper_env.envs.rendering import RENDER_MODES, EpisodeRenderer, ylim_deg
from gripper_env.envs.spaces import OBS_BOUND
from gripper_env.sim import bus_servo as core

__all__ = ["TRIP_NAMES", "GripperBusServoEnv"]

_NAME = "GripperBusServo-v0"
#: The servo's trip codes (the run's ``trip``: the first protection that fired) by name.
TRIP_NAMES = core.TRIP_NAMES


class GripperBusServoEnv(gym.Env[np.ndarray, np.ndarray]):
    """Send a bus servo's jaw its goals to follow a reference (and grasp an object).

    ## Description

    A gripper on a serial bus servo (Feetech STS3215, Dynamixel XL330 or XL430:
    :class:`~gripper_env.model.bus_servo.BusServoModel`). The servo closes its own position loop
    at 1 kHz on its encoder (4096 ticks per turn), a PID in register units with an output
    limit, a goal profile, friction, a loop delay, an overload timer and a thermal cut-out
    (:mod:`gripper_env.sim.bus_servo`, the simulation core's bus-servo block). Its registers
    (P, I, D, torque limit, acceleration, velocity, dead band) are fixed for every episode by
    ``registers``. The agent is the host: every control period (20 ms by default) it writes the
    goal position, which reaches the loop after the bus's delay (2 ms for the shipped models)
    and is held until the next one, while the servo runs 20 ticks of 1 ms underneath.

    The reference is drawn per episode by default: the jaw's open position, then steps to random
    targets in the jaw's range, each held 0.5 to 1.5 s (seeded by ``reset(seed=...)``);
    ``reference="tracking"`` and ``"grasp"`` are the register tuners' scenarios
    (:mod:`gripper_env.evaluation.bus_servo`). With ``object_deg`` (and always with ``"grasp"``)
    an object meets the closing jaw at that angle; while the reference asks to close past it,
    the reward wants at least 20 % of the stall force on it, and an overload trips the servo.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``:

    | Num | Action | Min | Max | Meaning                                                    |
    |-----|--------|-----|-----|------------------------------------------------------------|
    | 0   | goal   | -1  | 1   | ``goal = j + w * a`` over the jaw's range (deg)            |

    ``j`` and ``w`` are the centre and half-width of the jaw's range ``model.jaw.limits_deg``
    (205 and 55 deg for the shipped models: -1 is the closed stop at 150 deg, +1 the open one
    at 260 deg). With ``residual="reference"`` the goal is ``r + residual_deg * a`` (``r`` the
    reference of the observation; the zero action sends the reference itself), clamped to the
    jaw's range. The goal is sent in whole encoder ticks (0.088 deg). Actions outside [-1, 1]
    are clipped to it; NaN or infinite actions raise ``ValueError``.

    ## Observation Space

    ``Box(-10, 10, (6,), float32)``, ``GripperServo-v0``'s layout; every entry is clipped to
    [-10, 10]. ``y`` is the encoder's reading (deg) at the end of the period, ``r`` the reference
    for the next period:

    | Num | Observation     | Formula                                                   |
    |-----|-----------------|-----------------------------------------------------------|
    | 0   | position        | ``(y - j) / w``                                           |
    | 1   | reference       | ``(r - j) / w``                                           |
    | 2   | error           | ``e = (r - y) / w``                                       |
    | 3   | error rate      | ``(e - e_prev) * 0.02 s / T_c`` (change per 20 ms)        |
    | 4   | error integral  | ``sum(e * T_c)`` (s), held within [-10, 10]               |
    | 5   | previous action | the last (clipped) action; at reset the resting goal's    |
    |     |                 | action (0 with ``residual``)                              |

    ## Rewards

    Per step, over the period's 1 ms ticks ``k`` (reference ``r_k``, encoder reading ``y_k``
    after the tick, direction ``d_k`` = +1/-1 of the latest reference move, 0 before any, goal
    ``g_t`` sent this period):

    ``reward = -( mean_k |r_k - y_k| / w
    + overshoot_weight * mean_k max(0, d_k (y_k - r_k)) / w
    + chatter_weight * min(10, |g_t - g_{t-1}| / w)
    + force_weight * mean_k [r_k <= o] max(0, 1 - F_k / (0.2 F_stall)) )``

    i.e. ``GripperServo-v0``'s tracking, overshoot and chatter terms (the chatter is the goal's
    change) and, with an object at ``o`` deg, the shortfall of the grip force ``F_k`` from 20 %
    of the stall force while the reference asks to close on or past the object (the tuners'
    hold requirement). With an object, the tracking terms compare the jaw with ``max(r_k, o)``:
    the reference held at the object, where the jaw stops. Defaults ``overshoot_weight = 1``,
    ``chatter_weight = 0.1``, ``force_weight = 1``.

    The step on which the servo's overload (or thermal) protection trips ends the episode with
    ``reward = -(100 + n_left)``, ``n_left`` the steps the reference had left: ending early does
    not pay a policy whose steps cost less than 1 each.

    Scale, over the 10 s random reference (20 seeds): sending the reference itself
    (``residual="reference"``, zero action) returns about -50 with the STS3215's factory
    registers (-34 XL330, -50 XL430); uniformly random actions about -550 (they slam the jaw
    between goals until the overload trips; -370 on the XL330, which rarely trips). Over
    ``"grasp"``, a goal 4 deg past the object holds it with 37 % of the stall force for about
    -19; the closed stop as the goal trips the overload at about 2 s, about -520.

    ## Starting State

    The jaw rests at the reference's first value (the open position, 240 deg, for the named
    references) with the goal there, the loop settled, cold, not tripped. The random reference
    is drawn from the generator of ``reset(seed=...)``; the servo itself is deterministic.

    ## Episode End

    Termination when the servo trips (overload: the duty at or above its overload level for its
    protection time, 2 s; or overheat), reward ``-(100 + n_left)``, ``info["trip"]`` names it.
    Truncation at
    the end of the reference (500 steps of 20 ms for the 10 s random reference, 210 for
    ``"tracking"``, 510 for ``"grasp"``) and by the ``TimeLimit`` registered with the id: 500
    steps, the default episode (``gym.make(..., reference="grasp", max_episode_steps=510)`` for
    the whole grasp).

    ## Arguments

    ```python
    import gymnasium as gym
    env = gym.make(
        "gripper_env:gripper_env/GripperBusServo-v0",
        model="sts3215",          # "xl330", "xl430", a model YAML/JSON file or a BusServoModel
        registers=None,           # the factory's; "lerobot", a RegisterSet, a dict, or the
                                  # registers .json of python -m tuners.bus.tune (its model too)
        reference="random",       # "tracking", "grasp", or a goal per 1 ms tick (deg)
        episode_s=10.0,           # random reference's length; grasp's hold (s)
        hold_s=(0.5, 1.5),        # random reference's hold per target (s)
        object_deg=None,          # an object at this angle (deg); "grasp" puts the model's
        control_period_s=0.020,   # agent step (s), a whole number of 1 ms ticks
        residual=None,            # "reference": the action corrects the reference
        residual_deg=20.0,        # correction at |a| = 1 (deg)
        render_mode=None,         # "rgb_array" or "human"
    )
    ```

    Also ``overshoot_weight``, ``chatter_weight``, ``force_weight``. A bad argument fails at
    construction with a one-line message that names it and its value.
    ``info`` of a step: ``position_deg``, ``goal_deg`` (as sent), ``force_n`` (at the
    fingertip), ``temperature_c``, ``trip``.

    ## Version History

    * v0: initial version.
    """

    # gymnasium declares metadata per instance (Env.metadata); this is the class default
    metadata: dict[str, Any] = {"render_modes": list(RENDER_MODES), "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        *,
        model: Any = None,
        registers: Any = None,
        reference: Any = "random",
        episode_s: float = 10.0,
        hold_s: Any = DEFAULT_HOLD_S,
        object_deg: float | None = None,
        control_period_s: float = 0.020,
        residual: str | None = None,
        residual_deg: float = DEFAULT_RESIDUAL_DEG,
        overshoot_weight: float = 1.0,
        chatter_weight: float = 0.1,
        force_weight: float = 1.0,
        render_mode: str | None = None,
    ) -> None:
        self.settings = s = parse_bus_settings(
            _NAME,
            model=model,
            registers=registers,
            control_period_s=control_period_s,
            reference=reference,
            episode_s=episode_s,
            hold_s=hold_s,
            object_deg=object_deg,
            residual=residual,
            residual_deg=residual_deg,
            overshoot_weight=overshoot_weight,
            chatter_weight=chatter_weight,
            force_weight=force_weight,
            render_mode=render_mode,
        )
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": 1.0 / s.control_period_s}
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = gym.spaces.Box(-OBS_BOUND, OBS_BOUND, (6,), np.float32)
        m = s.model
        self._dpt = m.deg_per_tick
        self._stall_n = m.stall_force_n()
        params = core.bus_params(m, with_object=s.object_deg is not None)
        if s.object_deg is not None:
            params[core.PB_OBJ] = s.object_deg
        self._params = params[None]
        self._regs = core.bus_registers(m, s.registers)[None]
        self._state = core.bus_state(m)[None].copy()
        self._pending = np.zeros(s.lag_ticks)  # goals (ticks) written but not yet at the loop
        self._obs = np.zeros(6, dtype=np.float32)
        self._ref = self._tracked = np.zeros(1)
        self._ref_name = ""
        self._len = 0
        self._t = 0
        self._goal = 0.0  # the last goal sent (ticks)
        self._e_prev = self._integral = self._direction = 0.0
        self._done = True
        self._renderer = None if render_mode is None else _Renderer(s, render_mode)

    # ---- Gymnasium interface -------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        s = self.settings
        self._ref_name, ref = draw_bus_reference(s, self.np_random)
        self._ref = np.ascontiguousarray(ref, dtype=np.float64)
        self._tracked = tracked_reference(s, self._ref)
        self._len = len(self._ref) // s.n_sub * s.n_sub
        lo, hi = s.jaw_range_deg
        start = min(max(float(self._ref[0]), lo), hi)  # the jaw rests at the reference's start
        self._state[0] = core.bus_state(s.model, start)
        self._goal = float(self._state[0, core.SB_SP])
        self._pending[:] = self._goal
        self._t = 0
        self._direction = 0.0
        y0 = self._reading()
        self._e_prev, self._integral = write_observation(
            s, self._obs, y0, self._ref[0], 0.0, 0.0, s.resting_action(self._goal * self._dpt),
            first=True,
        )  # fmt: skip
        self._done = False
        if self._renderer is not None:
            self._renderer.start(self._ref_name, self._ref, self._len, y0, self._goal * self._dpt)
            if self.render_mode == "human":
                self._renderer.render()
        info = {
            "reference": self._ref_name,
            "model": s.model.name,
            "registers": s.registers.label(),
            "object_deg": s.object_deg,
            "position_deg": y0,
        }
        return self._obs.copy(), info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError(f"{_NAME}: call reset() before step() (the episode has ended)")
        a = check_bus_action(_NAME, action)
        s, n, t = self.settings, self.settings.n_sub, self._t
        last = len(self._ref) - 1
        goal = float(round(s.goal_deg(a, float(self._ref[min(t, last)])) / self._dpt))
        change = abs(goal - self._goal) * self._dpt
        self._goal = goal
        # the bus's delay: the loop sees the goals written lag ticks ago
        lag = len(self._pending)
        seq = np.concatenate([self._pending, np.full(n, goal)])
        self._pending[:] = seq[n : n + lag]
        run = core.run_bus(self._params, self._regs, self._state, seq[None, :n])
        y_end = self._reading()
        # the encoder after each tick (run.position is its reading at the tick's start)
        y = np.empty(n)
        y[:-1] = run.position[0, 1:] * self._dpt
        y[-1] = y_end
        reward, self._direction = bus_reward(
            s, self._ref, self._tracked, t, y, self._direction, change, run.force[0]
        )
        trip = int(run.trip[0, -1])
        terminated = trip != core.TRIP_NONE
        self._t = t_new = t + n
        if terminated:
            reward = trip_reward(s, self._len - t_new)
        truncated = not terminated and t_new >= self._len
        self._e_prev, self._integral = write_observation(
            s, self._obs, y_end, self._ref[min(t_new, last)], self._e_prev, self._integral, a
        )
        self._done = terminated or truncated
        if self._renderer is not None:
            ref = self._ref[np.minimum(np.arange(t, t + n), last)]
            self._renderer.record(ref, y, seq[:n] * self._dpt)
            if self.render_mode == "human":
                self._renderer.render()
        info = {
            "position_deg": y_end,
            "goal_deg": goal * self._dpt,
            "force_n": float(run.force[0, -1]) * self._stall_n,
            "temperature_c": float(run.temperature[0, -1]),
            "trip": TRIP_NAMES.get(trip, str(trip)),
        }
        return self._obs.copy(), reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """``rgb_array``: the episode so far as an (H, W, 3) uint8 plot; ``human``: draw it."""
        if self._renderer is None:
            gym.logger.warn(f"{_NAME}: render() without a render_mode; pass render_mode=...")
            return None
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()

    # ---- internals -----------------------------------------------------------------------------

    def _reading(self) -> float:
        """The encoder's reading now (deg), as the servo reports its present position."""
        return math.floor(self._state[0, core.SB_TH] / self._dpt + 0.5) * self._dpt


class _Renderer(EpisodeRenderer):
    """The episode's reference, jaw angle and goal against time (:class:`EpisodePlot`)."""

    def __init__(self, s: BusSettings, mode: str) -> None:
        super().__init__(_NAME, mode, core.DT)
        self.s = s

    def start(self, name: str, ref: np.ndarray, n_ticks: int, y0: float, goal0: float) -> None:
        s = self.s
        self.recorder.start(n_ticks // s.n_sub, float(ref[0]), y0, goal0)
        title = f"{_NAME}: {s.model.name}, {name} reference, {s.registers.label()}"
        self._start_plot(title, n_ticks * core.DT, ylim_deg(s.jaw_range_deg, ref[:n_ticks]),
                         s.jaw_range_deg)  # fmt: skip

    def record(self, ref: np.ndarray, y: np.ndarray, goal: np.ndarray) -> None:
        self.recorder.record(ref, y, goal)
