"""``gripper_env/GripperPIDTune-v0``: the agent is the tuner; one step = one whole episode."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from gripper_env.envs.episode import Episode, draw_episode
from gripper_env.envs.plant_slots import PlantSlots
from gripper_env.envs.rendering import (
    RENDER_MODES,
    EpisodePlot,
    command_ylim_deg,
    envelope,
    ylim_deg,
)
from gripper_env.envs.settings import Settings, parse_settings
from gripper_env.envs.spaces import (
    OBS_BOUND,
    action_to_gains,
    check_actions,
    disturbance_features,
    reference_features,
)
from gripper_env.evaluation.metrics import Metrics
from gripper_env.evaluation.objective import Objective, load_objective
from gripper_env.evaluation.scoring import robustness, score_trajectory
from gripper_env.io.config import ConfigError
from gripper_env.sim import Trajectory

__all__ = [
    "DEFAULT_RELATIVE",
    "REWARDS",
    "EpisodeRenderer",
    "EpisodeResults",
    "GripperPIDTuneEnv",
    "exact_log_reward",
    "run_episodes",
]

#: Largest number of whole episodes the core advances in one call (memory: 4 x rows x samples).
MAX_ROWS_PER_CALL = 128
#: The rewards an episode can return (``reward=``): minus the penalised cost (the default), or
#: the RL PID tuner's ``-log`` of the exact penalty (:func:`exact_log_reward`, the default of
#: ``GripperPIDTuneRelative-v0``).
REWARDS = ("penalised", "log-exact-penalty")
#: ``GripperPIDTuneRelative-v0``'s defaults: the RL PID tuner's working formulation
#: (:mod:`tuners.rl.tune`): log-gains one and a half decades around a deployable design, the
#: PID's output limited to the servo's 0-180 deg with clamping anti-windup (the benchmark's
#: evaluation settings) and the ``-log`` exact-penalty reward. The design is the AMIGO PI rule
#: with its robustness knob set under the constraints on test2, test3 and test4 at once
#: (``results/test2/classical-amigo-pi-robust.json``): the one gain set the benchmark admits on
#: every identification, so the zero action is deployable on each. 1.5 decades and 0.02 s of D
#: reach the benchmark's per-plant Optuna optima (test2's P 3.43, I 67.5, D -0.0087: 0.86 and 1.10
#: decades, -0.43 of the D span).
DEFAULT_RELATIVE: dict[str, Any] = {
    "gain_scaling": "relative",
    "gain_center": (0.4731, 5.415, 0.0),
    "gain_decades": 1.5,
    "gain_max": (1.0, 1.0, 0.02),
    "pid_options": {"output_limits": (0.0, 180.0), "anti_windup": "clamping"},
    "reward": "log-exact-penalty",
}
#: The floor of the exact penalty under the log (an episode cannot cost less than 0).
_LOG_FLOOR = 1e-6


def exact_log_reward(penalised: np.ndarray, feasible: np.ndarray, jump: float) -> np.ndarray:
    """The RL PID tuner's reward, ``-log(cost + jump * violation)``, from the penalised costs.

    :meth:`~gripper_env.evaluation.objective.Objective.penalised` adds ``jump * (1 +
    violation)`` to an infeasible gain set's cost: a cliff of ``jump`` at the constraints'
    boundary, where the best gains lie (Optuna's best have ``Ms`` 1.52-1.57 against the limit
    1.6). A Gaussian policy maximising the expected reward across that cliff keeps its mean away
    from the boundary. The exact penalty (the cliff taken off, growing with the violation;
    larger than the constraint's multiplier, so its minimum is the constrained one) lets the
    policy sit on the boundary, and the log keeps an unstable loop's 10,000 from swamping the
    differences between the gains that matter (costs 10-20).

    Parameters
    ----------
    penalised : ndarray
        ``objective.penalised(cost, violation)`` per episode.
    feasible : ndarray of bool
        Whether each episode's gains met the constraints.
    jump : float
        ``objective.infeasible_penalty``.
    """
    exact = np.asarray(penalised, dtype=float) - np.where(np.asarray(feasible, bool), 0.0, jump)
    return -np.log(np.maximum(exact, _LOG_FLOOR))


@dataclass
class EpisodeResults:
    """Outcome of :func:`run_episodes` (one entry per episode)."""

    gains: np.ndarray  # (B, 4): P, I, D, N
    costs: np.ndarray  # (B,)
    infos: list[dict[str, Any]]
    trajectories: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # (r, y, u) per episode


def run_episodes(
    settings: Settings,
    slots: dict[int, PlantSlots],
    episodes: Sequence[Episode],
    actions: np.ndarray,
    objective: Objective,
    keep_trajectories: bool = False,
) -> EpisodeResults:
    """Run whole grip/un-grip episodes under PID gains and score them with the shared objective.

    The physics of up to :data:`MAX_ROWS_PER_CALL` episodes runs in one call of the simulation
    core (:class:`~gripper_env.sim.BatchSimulator`), exactly as
    :func:`~gripper_env.sim.simulate` runs it; the metrics are
    :func:`~gripper_env.evaluation.metrics.compute_metrics` and the cost is :meth:`Objective.cost`
    with the
    reference's duration, as for every tuner.

    Parameters
    ----------
    settings : Settings
        The environment's validated arguments.
    slots : dict of int to PlantSlots
        Simulators by batch size, reused between calls (filled as needed).
    episodes : sequence of Episode
        Plant, disturbance, reference and noise seed of each episode.
    actions : ndarray, shape (B, 3)
        Actions in [-1, 1] (clipped), mapped to gains by
        :func:`~gripper_env.envs.spaces.action_to_gains`.
    objective : Objective
        The shared tuning objective.
    keep_trajectories : bool
        Return ``(r, y, u)`` of each episode (for rendering).
    """
    n = len(episodes)
    gains = np.empty((n, 4))
    gains[:, :3] = action_to_gains(
        actions, settings.gain_max, settings.gain_scaling, settings.gain_center,
        settings.gain_decades,
    )  # fmt: skip
    gains[:, 3] = settings.derivative_filter
    costs = np.empty(n)
    infos: list[dict[str, Any]] = []
    trajectories = []
    for start in range(0, n, MAX_ROWS_PER_CALL):
        rows = range(start, min(n, start + MAX_ROWS_PER_CALL))
        if len(rows) not in slots:
            slots[len(rows)] = PlantSlots(settings, len(rows))
        c, i, t = _run_chunk(
            settings, slots[len(rows)], [episodes[r] for r in rows], gains[start : rows.stop],
            objective, keep_trajectories,
        )  # fmt: skip
        costs[start : rows.stop] = c
        infos.extend(i)
        trajectories.extend(t)
    return EpisodeResults(gains, costs, infos, trajectories)


def _run_chunk(
    settings: Settings,
    slots: PlantSlots,
    episodes: list[Episode],
    gains: np.ndarray,
    objective: Objective,
    keep: bool,
) -> tuple[np.ndarray, list[dict[str, Any]], list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    n = len(episodes)
    sim = slots.sim
    for b, ep in enumerate(episodes):
        slots.install(b, ep.plant_index)
    sim.configure(gains, [ep.disturbance for ep in episodes], settings.pid_options)
    refs = [ep.reference for ep in episodes]
    shared = all(r is refs[0] for r in refs)
    n_t = max(len(r) for r in refs)
    if shared:
        ref = refs[0].values_deg
    else:
        ref = np.empty((n, n_t))
        for b, r in enumerate(refs):
            ref[b, : len(r)] = r.values_deg
            ref[b, len(r) :] = r.values_deg[-1]
    y0 = np.array([r.values_deg[0] for r in refs])
    seeds = np.array([ep.noise_seed for ep in episodes], dtype=np.int64)
    sim.reset(y0, seeds, initial="rest")
    out = sim.advance(n_t, ref)
    whole = sim.trajectory(refs[0], out)  # sliced per episode below if needed
    # the one scoring path: metrics on the objective's signal and settling band, then the cost
    if shared:
        metrics, costs = score_trajectory(whole, objective, settings.disturbance)
        rows = [(0, b) for b in range(n)]
        parts = [metrics]
    else:
        parts, cost_list, rows = [], [], []
        for b, r in enumerate(refs):
            one = _episode_slice(whole, b, r)
            m, c = score_trajectory(one, objective, settings.disturbance)
            parts.append(m)
            cost_list.append(c[0])
            rows.append((b, 0))
        costs = np.asarray(cost_list)
    # robustness of each episode's gains on its plant and loop (servo refresh and delay)
    violation = np.empty(n)
    margins = []
    lim = objective.constraints
    for b, ep in enumerate(episodes):
        rb = robustness(
            settings.plants[ep.plant_index],
            ep.disturbance,
            gains[b : b + 1],
            settings.pid_options.sign,
        )
        violation[b] = rb.violation(lim.ms_max, lim.gm_min_db)[0]
        margins.append(rb.row(0))
    penalised = objective.penalised(costs, violation)
    infos = [
        _info(parts[mi], i, objective, gains[b], costs[b], penalised[b], margins[b],
              refs[b].duration_s)
        for b, (mi, i) in enumerate(rows)
    ]  # fmt: skip
    trajectories = []
    if keep:
        r_out, u_out, y_out, _ = out
        for b, r in enumerate(refs):
            n_r = len(r)
            trajectories.append(
                (r_out[b, :n_r].copy(), y_out[b, :n_r].copy(), u_out[b, :n_r].copy())
            )
    return penalised, infos, trajectories


def _episode_slice(whole: Trajectory, b: int, ref: Any) -> Trajectory:
    """Run ``b`` of a batch trimmed to its own reference's length."""
    m = len(ref)
    one = slice(b, b + 1)
    return Trajectory(
        t=ref.t_s,
        r=whole.r[one, :m],
        u=whole.u[one, :m],
        y=whole.y[one, :m],
        y_true=whole.y_true[one, :m],
        stable=whole.stable[one],
        saturated_s=whole.saturated_s[one],
        reference=ref,
        closed_loop=True,
        contact_s=_run_of(whole.contact_s, one),
        stall_s=_run_of(whole.stall_s, one),
        force_proxy=_run_of(whole.force_proxy, one),
        servo_effort_deg=_run_of(whole.servo_effort_deg, one),
    )


def _run_of(values: np.ndarray | None, one: slice) -> np.ndarray | None:
    """The rows ``one`` of an optional per-run array."""
    return None if values is None else values[one]


def _info(
    metrics: Metrics,
    i: int,
    objective: Objective,
    gains: np.ndarray,
    cost: float,
    penalised: float,
    margins: dict[str, Any],
    dur: float,
) -> dict[str, Any]:
    terms = objective.terms(metrics, dur)
    info = _defined(metrics.as_dict(i))
    info["cost"] = float(cost)
    info["penalised_cost"] = float(penalised)
    info["feasible"] = bool(penalised == cost)
    info["robustness"] = margins
    info["cost_terms"] = {k: float(v[i]) for k, v in terms.items()}
    info["gains"] = {"P": float(gains[0]), "I": float(gains[1]), "D": float(gains[2]),
                     "N": float(gains[3])}  # fmt: skip
    return info


def _defined(d: dict[str, Any]) -> dict[str, Any]:
    """NaN (a metric without a segment to measure, e.g. no un-grip move) -> None."""
    return {
        k: _defined(v) if isinstance(v, dict) else (None if isinstance(v, float) and v != v else v)
        for k, v in d.items()
    }


class GripperPIDTuneEnv(gym.Env[np.ndarray, np.ndarray]):
    """Choose the PID gains of the gripper for a whole grip/un-grip episode.

    ## Description

    A one-step (contextual bandit) environment: the observation describes the task (the plant,
    the actual-gripper blocks, the reference profile), the action is a set of PID gains, and the
    environment runs the whole episode (20 s of 1 ms physics for the default step profile)
    through the simulation core with the Simulink-style PID of :mod:`gripper_env.model.pid`. The
    reward
    is minus the cost of the shared tuning objective (``configs/objective.yaml``,
    :meth:`gripper_env.evaluation.objective.Objective.cost`), the same cost that the Optuna tuner
    minimises,
    and ``info`` holds every metric. With the defaults (one plant, the ``step`` reference,
    ``randomize=False``) every episode has the same observation and only the sensor noise
    changes: a bandit per plant. With several plants, ``randomize`` and ``reference="random"``
    the context varies and one policy learns to tune many grippers (a contextual bandit).

    ## Action Space

    ``Box(-1, 1, (3,), float32)``, the gains through the signed logarithmic map of
    :func:`gripper_env.envs.spaces.action_to_gains`,
    ``g = sign(a) * g_max * (10**(3 |a|) - 1) / 999`` (``gain_scaling="linear"``:
    ``g = a * g_max``); the paper's tuned gains (1, 9, -0.001) are about (0.668, 0.752, -0.347).
    ``gain_scaling="relative"`` maps log-gains around a design ``gain_center=(P0, I0, D0)``:
    ``P = P0 10**(d a_P)``, ``I = I0 10**(d a_I)``, ``D = D0 + a_D g_max[2]`` with
    ``d = gain_decades``; the zero action is that design.

    | Num | Action | Min | Max | Gain at -1 / +1 (default ``gain_max``)          |
    |-----|--------|-----|-----|-------------------------------------------------|
    | 0   | P      | -1  | 1   | -10 / +10 deg of command per deg of error       |
    | 1   | I      | -1  | 1   | -50 / +50 1/s                                   |
    | 2   | D      | -1  | 1   | -0.1 / +0.1 s (derivative filter ``N = 100``/s) |

    Negative gains are legal; the error sign convention is ``pid_options["sign"]`` (+1:
    ``e = r - y``). Actions outside [-1, 1] are clipped; NaN or infinite actions raise
    ``ValueError``.

    ## Observation Space

    ``Box(-10, 10, (18,), float32)``, the context (:data:`gripper_env.envs.spaces.CONTEXT_NAMES`):

    | Num   | Observation | Features                                                         |
    |-------|-------------|------------------------------------------------------------------|
    | 0-5   | plant       | log10 of fastest and slowest pole / 3, damping of the slowest,   |
    |       |             | unit-step response at 0.1 s and 1 s, ``G(0) - 1``                |
    | 6-13  | disturbance | stiction S and J / 5 deg, backlash / 2 deg, noise (deg), command |
    |       |             | quantum (deg), servo refresh / 20 ms, delay / 20 ms, ADC LSB     |
    | 14-17 | reference   | moves / 10, mean move / jaw range, mean move time / 10 s,        |
    |       |             | duration / 100 s                                                 |

    ## Rewards

    ``reward = -objective.penalised(cost, violation)``, through the one scoring path
    (:func:`gripper_env.evaluation.scoring.score_trajectory`), the same as every tuner's: ``cost``
    is the
    shared objective's weighted sum of IAE, visible overshoot, settling time, stall, saturation and
    servo effort on the objective's signal (the true jaw angle), capped at ``max_cost`` (1000) for
    stable runs and ``unstable_cost`` (10000) for a diverged run; gains that miss the robustness
    constraints (``Ms <= 1.6``, 6 dB gain margin on the loop as it runs, with the servo's 20 ms
    command hold) cost ``infeasible_penalty`` (100) more, graded by how far they miss. Typical
    rewards: about -10 to -30 for good gains on test2-test4, below -100 for infeasible ones.
    ``info`` holds the metrics (``grip``, ``ungrip``, ``iae``, ``stall_s``, ...,
    ``stable``), ``cost``, ``penalised_cost``, ``feasible``, ``robustness`` (margins),
    ``cost_terms`` and ``gains``.

    ``reward="log-exact-penalty"`` (``GripperPIDTuneRelative-v0``'s default) returns instead
    ``-log(cost + infeasible_penalty * violation)`` (:func:`exact_log_reward`): the RL PID
    tuner's training reward, the constraints as an exact penalty without the cliff at their
    boundary, in log scale (about -2.3 to -3.4 for good gains, -9.2 for a diverged run).

    ## Starting State

    Each ``reset`` draws the episode from the seeded generator: the plant (if several), the
    actual-gripper parameters (``randomize``), the reference (``"random"``) and the seed of the
    sensor noise. Same seed, identical episode and reward.

    ## Episode End

    Every episode terminates after its one step (``terminated=True``, ``truncated=False``). The
    id is registered without a ``TimeLimit`` (one of 1 step would truncate the step that
    terminates); a step after the end raises until ``reset()``.

    ## Arguments

    ```python
    import gymnasium as gym
    env = gym.make(
        "gripper_env:gripper_env/GripperPIDTune-v0",
        plant=["test1", "test2", "test3", "test4"],  # one drawn per episode
        disturbance="actual", reference="step", randomize=True,
        gain_max=(10.0, 50.0, 0.1), gain_scaling="log", derivative_filter=100.0,
        pid_options={"anti_windup": "clamping", "sign": 1},
        objective=None,  # configs/objective.yaml, or another file or dict
        render_mode=None,
    )
    ```

    Also ``episode_s`` (length of random references, s), ``gain_center`` and ``gain_decades``
    (the ``relative`` gain map), ``reward`` (``"penalised"``, the default, or
    ``"log-exact-penalty"``).

    ``gripper_env/GripperPIDTuneRelative-v0`` is this environment with the RL PID tuner's
    working formulation as its defaults (:data:`DEFAULT_RELATIVE`): the ``relative`` gain map,
    1.5 decades around the AMIGO PI design the benchmark admits on every identification (P
    0.4731, I 5.415, D 0 +/- 0.02 s), the output limited to 0-180 deg with clamping, and the
    ``log-exact-penalty`` reward. Every argument works the same.

    ## Version History

    * v0: initial version: the signed ``log`` gain map and the penalised cost as the reward;
      ``reward`` added without changing the default. Its metrics' oscillation check measures the
      tracking error since the RL benchmark's change (a random profile's ramp still running in
      the check's window was taken for an oscillation: such episodes cost ``unstable_cost``).
    """

    # gymnasium declares metadata per instance (Env.metadata); this is the class default
    metadata: dict[str, Any] = {"render_modes": list(RENDER_MODES), "render_fps": 1}  # noqa: RUF012
    _name = "GripperPIDTune-v0"

    def __init__(
        self,
        *,
        plant: Any = "test2",
        disturbance: Any = "actual",
        reference: Any = "step",
        randomize: bool | Mapping[str, Any] = False,
        render_mode: str | None = None,
        episode_s: float = 20.0,
        pid_options: Any = None,
        gain_max: Any = (10.0, 50.0, 0.1),
        gain_scaling: str = "log",
        gain_center: Any = None,
        gain_decades: float = 1.0,
        derivative_filter: float = 100.0,
        objective: str | os.PathLike[str] | Mapping[str, Any] | Objective | None = None,
        reward: str = "penalised",
    ) -> None:
        if reward not in REWARDS:
            raise ConfigError(f"{self._name}: argument 'reward': expected one of {REWARDS}, "
                              f"got {reward!r}")  # fmt: skip
        self.reward = reward
        self.settings = parse_settings(
            self._name, plant=plant, disturbance=disturbance, reference=reference,
            randomize=randomize, render_mode=render_mode, episode_s=episode_s,
            pid_options=pid_options, gain_max=gain_max, gain_scaling=gain_scaling,
            gain_center=gain_center, gain_decades=gain_decades,
            derivative_filter=derivative_filter,
        )  # fmt: skip
        try:
            self.objective = load_objective(objective)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{self._name}: argument 'objective': {exc}") from None
        self.render_mode = render_mode
        self.slots = {1: PlantSlots(self.settings, 1)}
        n_ctx = 6 + 8 + 4
        self.action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)
        self.observation_space = gym.spaces.Box(-OBS_BOUND, OBS_BOUND, (n_ctx,), np.float32)
        self._ref_features = (
            reference_features(self.settings.reference, self.settings.jaw_range_deg)
            if self.settings.reference is not None
            else None
        )
        self._episode: Episode | None = None
        self._obs = np.zeros(n_ctx, dtype=np.float32)
        self._done = True
        self._renderer = (
            None if render_mode is None else EpisodeRenderer(self.settings, render_mode)
        )

    def context(self, episode: Episode) -> np.ndarray:
        """The observation of an episode (float32)."""
        ref_f = (
            self._ref_features
            if self._ref_features is not None
            else reference_features(episode.reference, self.settings.jaw_range_deg)
        )
        ctx = np.concatenate(
            [
                self.slots[1].features[episode.plant_index],
                disturbance_features(episode.disturbance),
                ref_f,
            ]
        )
        return np.clip(ctx, -OBS_BOUND, OBS_BOUND).astype(np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._episode = draw_episode(self.settings, self.np_random)
        self._obs = self.context(self._episode)
        self._done = False
        if self._renderer is not None:
            self._renderer.start(self._episode)
        return self._obs.copy(), self.episode_info(self._episode)

    def episode_info(self, episode: Episode) -> dict[str, Any]:
        """The reset ``info`` of an episode: plant and reference names, noise seed."""
        return {
            "plant": self.settings.plants[episode.plant_index].name,
            "reference": episode.reference.name,
            "noise_seed": episode.noise_seed,
        }

    def rewards(self, res: EpisodeResults) -> np.ndarray:
        """The rewards of episodes run by :func:`run_episodes` (``reward=``)."""
        if self.reward == "penalised":
            return -res.costs
        feasible = np.array([info["feasible"] for info in res.infos], dtype=bool)
        return exact_log_reward(res.costs, feasible, self.objective.infeasible_penalty)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done or self._episode is None:
            raise RuntimeError(f"{self._name}: call reset() before step() (the episode has ended)")
        act = check_actions(action, (3,))[None, :]
        keep = self._renderer is not None
        res = run_episodes(self.settings, self.slots, [self._episode], act, self.objective, keep)
        self._done = True
        info = res.infos[0]
        if self._renderer is not None:
            self._renderer.finish(res.trajectories[0], info)
        return self._obs.copy(), float(self.rewards(res)[0]), True, False, info

    def render(self) -> np.ndarray | None:
        """Plot the last episode's reference, position and command (``rgb_array``: an image)."""
        if self._renderer is None:
            gym.logger.warn(f"{self._name}: render() without a render_mode; pass render_mode=...")
            return None
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()


class EpisodeRenderer:
    """Frames of ``GripperPIDTune-v0`` episodes: the reference to follow after ``reset``, the
    whole run (reference, position, PID output) after the step.

    Parameters
    ----------
    settings : Settings
        The environment's validated arguments.
    mode : {"rgb_array", "human"}
        The render mode.
    """

    def __init__(self, settings: Settings, mode: str) -> None:
        self.settings, self.mode = settings, mode
        self.plot: EpisodePlot | None = None
        self.episode: Episode | None = None
        self.run: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.title = ""

    def start(self, episode: Episode) -> None:
        """A new episode, not run yet."""
        self.episode, self.run = episode, None
        self.title = f"{self.settings.plants[episode.plant_index].name}, {episode.reference.name}"

    def finish(self, trajectory: tuple[np.ndarray, np.ndarray, np.ndarray], info: dict) -> None:
        """The episode ran: its ``(r, y, u)`` and its ``info`` (gains and cost for the title)."""
        assert self.episode is not None
        self.run = trajectory
        g = info["gains"]
        self.title = (
            f"{self.settings.plants[self.episode.plant_index].name}: P={g['P']:.3g} "
            f"I={g['I']:.3g} D={g['D']:.3g}, cost {info['cost']:.4g}"
        )
        if self.mode == "human":
            self.render()

    def render(self) -> np.ndarray | None:
        """``rgb_array``: the frame; ``human``: draw it in the window."""
        if self.episode is None:
            raise RuntimeError("GripperPIDTune-v0: call reset() before render()")
        reference = self.episode.reference.values_deg
        if self.run is None:
            runs = {"reference": reference}
        else:
            r, y, u = self.run
            runs = {"reference": r, "position": y, "command": u}
        dt = self.settings.dt_s
        n_sub = max(1, round(0.020 / dt))  # two points per 20 ms
        series = {}
        for name, values in runs.items():
            t_s, series[name] = envelope(values, n_sub, dt)
        if self.plot is None:
            self.plot = EpisodePlot(human=self.mode == "human")
        ylim = ylim_deg(self.settings.jaw_range_deg, reference)
        span = self.settings.command_range_deg
        # a new title: a full draw; the command axis holds the whole run's PID output
        self.plot.start(self.title, len(reference) * dt, ylim, span,
                        command_ylim_deg(span, runs.get("command")))  # fmt: skip
        if self.mode == "rgb_array":
            return self.plot.rgb(t_s, series)
        self.plot.show(t_s, series)
        return None

    def close(self) -> None:
        if self.plot is not None:
            self.plot.close()
            self.plot = None

    def __getstate__(self) -> dict[str, Any]:  # a copy starts without a figure
        state = self.__dict__.copy()
        state["plot"] = None
        return state
