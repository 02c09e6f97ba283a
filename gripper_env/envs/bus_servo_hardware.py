"""``gripper_env/GripperBusServoHardware-v0``: ``GripperBusServo-v0`` on a servo on its bus.

The host sends the agent's goal to a :class:`~gripper_env.hardware.bus.gripper.BusGripper` every
control period, paced by ``time.perf_counter``, and reads the jaw's position back during the
period. Spaces, goals, reward and observation are the simulated environment's
(:mod:`gripper_env.envs.bus_settings`), so a policy trained in simulation runs here unchanged.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from gripper_env.envs.bus_settings import (
    DEFAULT_HOLD_S,
    DEFAULT_RESIDUAL_DEG,
    bus_reward,
    check_bus_action,
    draw_bus_reference,
    parse_bus_settings,
    trip_reward,
    write_observation,
)
from gripper_env.envs.servo_hardware import MissedDeadlineWarning, SettleWarning
from gripper_env.envs.spaces import OBS_BOUND
from gripper_env.hardware.bus.gripper import BusGripper, Restored
from gripper_env.hardware.bus.link import BusError
from gripper_env.io.config import ConfigError, validate
from gripper_env.model.bus_calibration import JawCalibration, read_jaw_file
from gripper_env.model.bus_servo import BusServoModel

__all__ = ["GripperBusServoHardwareEnv"]

_NAME = "GripperBusServoHardware-v0"
_TRIPS = ("overload", "overheat")


class GripperBusServoHardwareEnv(gym.Env[np.ndarray, np.ndarray]):
    """Send a real bus servo's jaw its goals to follow a reference, host in the loop.

    ## Description

    ``gripper_env/GripperBusServo-v0`` with the simulated servo replaced by one on a bus: a
    :class:`~gripper_env.hardware.bus.gripper.BusGripper` (a Feetech STS3215 or a Dynamixel
    XL330 / XL430 behind a USB adapter, or the virtual servos of
    :class:`~gripper_env.hardware.bus.server.VirtualBus`). ``reset()`` writes the registers
    (with the torque off, each read back), turns the torque on and brings the jaw to the
    reference's start. Every step sends the agent's goal (clamped to the jaw's range, in whole
    encoder ticks) and reads the present position ``reads_per_period`` times, evenly spread
    over the control period (20 ms by default), the last at its end; the schedule is kept with
    ``time.perf_counter``. Spaces, goal map and observation are ``GripperBusServo-v0``'s
    (shared code): a policy trained in simulation runs here unchanged.

    Real time: the host has one control period per step. A step that arrives after the end of
    the period it was meant for is a *missed deadline*: counted in ``info["missed_deadlines"]``
    (this episode), its lateness in ``info["late_ms"]``, a
    :class:`~gripper_env.envs.servo_hardware.MissedDeadlineWarning` on the first miss of an
    episode and every ``warn_every``-th after; the schedule restarts from the late step.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``, as ``GripperBusServo-v0``: ``goal = j + w * a`` over the
    jaw's range ``model.jaw.limits_deg`` (``j``, ``w`` its centre and half-width), or ``r +
    residual_deg * a`` with ``residual="reference"``; clamped to the jaw's range (the
    :class:`BusGripper` clamps too). Actions are clipped to [-1, 1]; NaN or infinite actions
    raise ``ValueError`` before anything is sent.

    ## Observation Space

    ``Box(-10, 10, (6,), float32)``, as ``GripperBusServo-v0``: position, reference, error,
    error rate, error integral (normalised by the jaw's range), previous action; ``y`` is the
    present position read at the end of the period.

    ## Rewards

    ``GripperBusServo-v0``'s tracking, overshoot and chatter terms (shared code), over the
    period's position reads, each standing for the ticks since the one before. There is no
    force term: a bus servo measures no grip force (and the tracking terms follow the reference
    itself: the environment knows of no object). A step on which the servo reports an overload,
    overheating or another alert ends the episode with ``-(100 + n_left)``, ``n_left`` the steps
    the reference had left, as in simulation.

    ## Starting State

    ``reset()`` opens the port on first use (or after a bus error): the servo of ``servo_id``
    must answer (a broadcast ping lists the others, nothing is sent to them; a missing one is an
    error that lists them), its calibration is checked against ``jaw`` and every register the
    environment writes is snapshot. It clears a latched trip (a Dynamixel is rebooted; an STS
    clears it when its torque goes off), writes the registers (an STS3215's with ``Lock`` = 1:
    not saved to its flash) and reads them back, turns the torque on, sends the reference's
    first value as the goal and waits until the jaw rests within ``settle_tol_deg`` of it (or
    ``settle_timeout_s`` passed: then a
    :class:`~gripper_env.envs.servo_hardware.SettleWarning` and ``info["settled"] = False``).
    The random reference is drawn from the generator of ``reset(seed=...)``; the measurements
    are not reproducible (the spec is registered ``nondeterministic``).

    ## Episode End

    Truncation at the end of the reference and by the ``TimeLimit`` of 1000 steps registered
    with the id. Termination when the servo reports a hardware alert (overload, overheating, or
    another of its error bits): reward ``-(100 + n_left)``, ``info["errors"]`` names them
    (``info["trip"]`` the overload or overheating), the torque is turned off; the next
    ``reset()`` clears it. A bus failure (no reply, a corrupt reply, a register
    that does not read back) raises its :class:`~gripper_env.hardware.bus.link.BusError`, with
    the torque turned off first (as far as the servo still listens); the next ``reset()``
    starts afresh.

    ``close()`` (also on leaving a ``with`` block) restores every register the environment wrote
    as it was found (the torque too: off if it was off) and reads them back
    (``env.unwrapped.restored``), then closes the port; an exception or a ``KeyboardInterrupt`` in
    ``reset`` or ``step`` turns the torque off first.

    ## Arguments

    ```python
    import gymnasium as gym
    from gripper_env.hardware.bus.server import VirtualBus
    from gripper_env.hardware.bus.unit import ServoUnit

    with VirtualBus("sts3215", physics=ServoUnit("sts3215")) as bus:  # or a real adapter
        env = gym.make(
            "gripper_env:gripper_env/GripperBusServoHardware-v0",
            port=bus.path,             # required: "/dev/ttyUSB0", "COM3", or a virtual bus
            servo_id=1,                # required: the servo's ID on the bus (never guessed)
            jaw={"closed_ticks": 1707, "open_ticks": 2958},  # the jaw's ends (ticks), or the
                                       # file of python -m tuners.bus.calibrate
            model="sts3215",           # as GripperBusServo-v0 (family, model file, or model)
            registers=None,            # as GripperBusServo-v0 (factory, a name, a file...)
            reference="random",        # as GripperBusServo-v0
            control_period_s=0.020,    # agent step (s), a whole number of 1 ms ticks
        )
        with env:
            obs, info = env.reset(seed=0)
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    ```

    ``jaw`` is the owner's jaw calibration (a file of ``python -m tuners.bus.calibrate``, a
    :class:`~gripper_env.model.bus_calibration.JawCalibration`, or a dict of ``closed_ticks`` and
    ``open_ticks``, the servo's own calibration then read at ``reset()``); it may be left out
    only when the model (an identified model file, a registers file's) carries one. The goals'
    range is the calibrated jaw's, inside the servo's own position limits: the shipped models'
    angles are never a real servo's. Also ``episode_s``, ``hold_s``, ``residual``,
    ``residual_deg``, ``overshoot_weight``, ``chatter_weight`` (as ``GripperBusServo-v0``),
    ``baudrate`` (default the family's factory rate), ``reads_per_period`` (4),
    ``settle_tol_deg`` (3), ``settle_timeout_s`` (3), ``warn_every`` (50). The port is not
    touched before the first ``reset()``; a bad argument fails at construction with a message
    that names it.

    ## Version History

    * v0: initial version.
    """

    # gymnasium declares metadata per instance (Env.metadata); this is the class default
    metadata: dict[str, Any] = {"render_modes": [], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        port: str | os.PathLike[str] | None = None,
        *,
        servo_id: int | None = None,
        jaw: Any = None,
        model: Any = None,
        registers: Any = None,
        baudrate: int | None = None,
        reference: Any = "random",
        episode_s: float = 10.0,
        hold_s: Any = DEFAULT_HOLD_S,
        control_period_s: float = 0.020,
        residual: str | None = None,
        residual_deg: float = DEFAULT_RESIDUAL_DEG,
        overshoot_weight: float = 1.0,
        chatter_weight: float = 0.1,
        reads_per_period: int = 4,
        settle_tol_deg: float = 3.0,
        settle_timeout_s: float = 3.0,
        warn_every: int = 50,
        render_mode: str | None = None,
    ) -> None:
        self.port = _check_port(port)
        if render_mode is not None:
            raise ConfigError(
                f"{_NAME}: argument 'render_mode': no rendering on hardware (a plot would cost "
                f"the real-time loop its deadlines), got {render_mode!r}"
            )
        if servo_id is None:
            raise ConfigError(
                f"{_NAME}: argument 'servo_id' is required: the gripper servo's ID on the bus "
                "(never guessed: an SO-101's ID 1 is the shoulder, with the gripper's model)"
            )
        _check_integer("servo_id", servo_id, 0, 252)
        episode = {
            "registers": registers,
            "control_period_s": control_period_s,
            "reference": reference,
            "episode_s": episode_s,
            "hold_s": hold_s,
            "residual": residual,
            "residual_deg": residual_deg,
            "overshoot_weight": overshoot_weight,
            "chatter_weight": chatter_weight,
        }
        first = parse_bus_settings(_NAME, model=model, **episode)
        calibration = _parse_jaw(jaw, first.model, int(servo_id))
        self.settings = s = parse_bus_settings(
            _NAME, model=first.model.calibrated(calibration), **episode
        )
        if baudrate is not None:
            _check_integer("baudrate", baudrate, 1, None)
        _check_integer("reads_per_period", reads_per_period, 1, s.n_sub)
        _check_integer("warn_every", warn_every, 1, None)
        for arg, value in (("settle_tol_deg", settle_tol_deg), ("settle_timeout_s",
                                                                 settle_timeout_s)):  # fmt: skip
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not (ok and math.isfinite(value) and value > 0):
                raise ConfigError(f"{_NAME}: argument {arg!r}: expected a number > 0, got "
                                  f"{value!r}")  # fmt: skip
        self.render_mode = None
        self.servo_id = int(servo_id)
        self.baudrate = None if baudrate is None else int(baudrate)
        self.reads_per_period = int(reads_per_period)
        self.settle_tol_deg = float(settle_tol_deg)
        self.settle_timeout_s = float(settle_timeout_s)
        self.warn_every = int(warn_every)
        self.metadata = {**self.metadata, "render_fps": 1.0 / s.control_period_s}
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = gym.spaces.Box(-OBS_BOUND, OBS_BOUND, (6,), np.float32)
        # the ticks of the period each read stands for: read j ends at tick edges[j]
        self._edges = np.round(np.linspace(0, s.n_sub, self.reads_per_period + 1)).astype(int)
        self.gripper: BusGripper | None = None
        self.calibration = calibration
        #: What the last close() read back (a :class:`~gripper_env.hardware.bus.gripper.
        #: Restored`), None before.
        self.restored: Restored | None = None
        self._stale = True  # the next reset writes the registers again
        self._done = True
        self._obs = np.zeros(6, dtype=np.float32)
        self._ref = np.zeros(1)
        self._ref_name = ""
        self._len = 0
        self._t = 0
        self._t0 = 0.0  # perf_counter at the start of the current period
        self._goal_deg = 0.0
        self._e_prev = self._integral = self._direction = 0.0
        self.missed_deadlines = 0  # this episode
        self.missed_deadlines_total = 0

    # ---- Gymnasium interface -------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._ref_name, ref = draw_bus_reference(self.settings, self.np_random)
        self._done = True
        try:
            return self._reset(np.ascontiguousarray(ref, dtype=np.float64))
        except BaseException as exc:
            self._failed(exc)
            raise

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done or self.gripper is None:
            raise RuntimeError(f"{_NAME}: call reset() before step() (the episode has ended)")
        a = check_bus_action(_NAME, action)
        try:
            return self._step(a)
        except BaseException as exc:
            self._failed(exc)
            raise

    def close(self) -> None:
        """Restore every register the environment wrote as it was found, the torque too (read
        back into :attr:`restored`), and close the port (idempotent)."""
        self._done = True
        gripper, self.gripper = self.gripper, None
        self._stale = True
        if gripper is not None:
            try:
                self.restored = gripper.restore()
                if not self.restored.ok:
                    warnings.warn(f"{_NAME}: {self.restored.describe()}", RuntimeWarning,
                                  stacklevel=2)  # fmt: skip
            finally:
                gripper.close()

    # ---- internals -----------------------------------------------------------------------------

    def _connect(self) -> BusGripper:
        gripper = self.gripper
        if gripper is None:
            gripper = self.gripper = BusGripper(
                self.port,
                self.settings.model,
                self.servo_id,
                baudrate=self.baudrate,
                calibration=self.calibration,
                raise_on_alert=False,  # an alert ends the episode (step), not the session
            )
            self._stale = True
        return gripper

    def _reset(self, ref: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        s = self.settings
        g = self._connect()
        g.link.ping(self.servo_id)
        errors = _errors(g)
        if errors and g.link.spec.protocol != "feetech":
            g.link.reboot(self.servo_id)  # a Dynamixel keeps a trip until a REBOOT
            _wait_for(g, self.settle_timeout_s)
            self._stale = True
        if self._stale or errors:
            back = g.write_registers(s.registers)  # torque off (clears an STS's trip), read back
            if back != s.registers:
                raise ConfigError(
                    f"{_NAME}: the servo holds {back.label()} after writing {s.registers.label()}"
                )
            self._stale = False
        g.torque(True)
        lo, hi = s.jaw_range_deg
        r0 = min(max(float(ref[0]), lo), hi)
        self._goal_deg = g.goal_deg(r0)
        settled, y0 = self._settle(g, self._goal_deg)
        self._ref = ref
        self._len = len(ref) // s.n_sub * s.n_sub
        self._t = 0
        self._direction = 0.0
        self.missed_deadlines = 0
        self._e_prev, self._integral = write_observation(
            s, self._obs, y0, ref[0], 0.0, 0.0, s.resting_action(self._goal_deg), first=True
        )
        self._done = False
        self._t0 = time.perf_counter()
        info = {
            "reference": self._ref_name,
            "model": s.model.name,
            "registers": s.registers.label(),
            "settled": settled,
            "position_deg": y0,
            "goal_deg": self._goal_deg,
            "missed_deadlines": 0,
            "port": self.port,
        }
        return self._obs.copy(), info

    def _settle(self, g: BusGripper, target_deg: float) -> tuple[bool, float]:
        """Wait until the jaw rests near ``target_deg`` (or the timeout); (settled, position)."""
        deadline = time.perf_counter() + self.settle_timeout_s
        prev = g.position_deg()
        while True:
            time.sleep(self.settings.control_period_s)
            y = g.position_deg()
            if abs(y - target_deg) <= self.settle_tol_deg and abs(y - prev) <= 0.5:
                return True, y
            if time.perf_counter() > deadline:
                warnings.warn(
                    f"{_NAME}: the jaw did not settle at {target_deg:g} deg within "
                    f"{self.settle_timeout_s:g} s (it is at {y:.1f} deg); starting anyway",
                    SettleWarning,
                    stacklevel=4,
                )
                return False, y
            prev = y

    def _step(self, a: float) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        g = self.gripper
        assert g is not None
        s = self.settings
        period = s.control_period_s
        now = time.perf_counter()
        late_s = now - (self._t0 + period)
        if late_s > 0:
            self._missed(late_s)
            self._t0 = now  # the schedule restarts from the late step
        t, last = self._t, len(self._ref) - 1
        goal = g.goal_deg(s.goal_deg(a, float(self._ref[min(t, last)])))
        change = abs(goal - self._goal_deg)
        self._goal_deg = goal
        m = self.reads_per_period
        reads = np.empty(m)
        for j in range(m):
            _sleep_until(self._t0 + period * (j + 1) / m)
            reads[j] = g.position_deg()
        self._t0 += period
        alert = g.link.alerts.get(self.servo_id, 0)
        errors = _errors(g) if alert else []
        y = np.repeat(reads, np.diff(self._edges)).astype(np.float64)
        reward, self._direction = bus_reward(s, self._ref, self._ref, t, y, self._direction, change)
        terminated = bool(errors)
        self._t = t_new = t + s.n_sub
        if terminated:
            reward = trip_reward(s, self._len - t_new)
            g.relax()
        truncated = not terminated and t_new >= self._len
        self._e_prev, self._integral = write_observation(
            s, self._obs, float(reads[-1]), self._ref[min(t_new, last)], self._e_prev,
            self._integral, a,
        )  # fmt: skip
        self._done = terminated or truncated
        info: dict[str, Any] = {
            "position_deg": float(reads[-1]),
            "goal_deg": goal,
            "missed_deadlines": self.missed_deadlines,
            "late_ms": max(late_s, 0.0) * 1000.0,
            "errors": errors,
        }
        if terminated:
            warnings.warn(f"{_NAME}: episode terminated: the servo reports {', '.join(errors)}; "
                          "the torque is off", RuntimeWarning, stacklevel=3)  # fmt: skip
            info["trip"] = next((e for e in errors if e in _TRIPS), errors[0])
        return self._obs.copy(), reward, terminated, truncated, info

    def _missed(self, late_s: float) -> None:
        self.missed_deadlines += 1
        self.missed_deadlines_total += 1
        n = self.missed_deadlines
        if n == 1 or n % self.warn_every == 0:
            warnings.warn(
                f"{_NAME}: step {self._t // self.settings.n_sub + 1} arrived "
                f"{late_s * 1000:.1f} ms after the end of its "
                f"{self.settings.control_period_s * 1000:g} ms control period ({n} missed "
                "deadlines this episode): the agent or the host is too slow, the previous goal "
                "was held longer",
                MissedDeadlineWarning,
                stacklevel=4,
            )

    def _failed(self, exc: BaseException) -> None:
        """An error in reset or step: the torque off (as far as the servo still listens); the
        next reset writes the registers again."""
        self._done = True
        self._stale = True
        if self.gripper is not None:
            relaxed = self.gripper.relax()
            if isinstance(exc, BusError | ConfigError | OSError):
                exc.add_note(
                    f"{_NAME}: the episode is over; the torque "
                    + ("is off" if relaxed else "could not be turned off (no reply)")
                    + "; reset() starts again, close() turns the torque off and closes the port"
                )


def _parse_jaw(jaw: Any, model: BusServoModel, servo_id: int) -> JawCalibration:
    """The jaw calibration: ``jaw`` (a file, a calibration, or a dict of ``closed_ticks`` and
    ``open_ticks``), else the model's own."""
    if jaw is None:
        if model.calibration is None:
            raise ConfigError(
                f"{_NAME}: argument 'jaw' is required: the jaw's closed and open positions on "
                "this servo (a file of python -m tuners.bus.calibrate, or {'closed_ticks': N, "
                "'open_ticks': N}); the shipped model's angles are the virtual servo's"
            )
        cal = model.calibration
    elif isinstance(jaw, JawCalibration):
        cal = jaw
    elif isinstance(jaw, dict):
        data = {"family": model.family, "servo_id": servo_id, "source": "given", **jaw}
        cal = validate(JawCalibration, data, f"{_NAME}: argument 'jaw'")
    elif isinstance(jaw, str | os.PathLike):
        try:
            cal = read_jaw_file(jaw)
        except ConfigError as exc:
            raise ConfigError(f"{_NAME}: argument 'jaw': {exc}") from None
    else:
        raise ConfigError(
            f"{_NAME}: argument 'jaw': expected a calibration file, a JawCalibration or a dict "
            f"of closed_ticks and open_ticks, got {jaw!r}"
        )
    if cal.family != model.family:
        raise ConfigError(f"{_NAME}: argument 'jaw': a calibration of a {cal.family}, the model "
                          f"is a {model.family}")  # fmt: skip
    if cal.servo_id is not None and cal.servo_id != servo_id:
        raise ConfigError(f"{_NAME}: argument 'jaw': taken on servo {cal.servo_id}, not "
                          f"servo_id {servo_id}")  # fmt: skip
    return cal


def _check_port(port: Any) -> str:
    if port is None or (isinstance(port, str) and not port):
        raise ConfigError(
            f"{_NAME}: argument 'port' is required: the bus adapter's serial port (e.g. "
            "port='/dev/ttyUSB0'), or the path of a virtual bus "
            "(gripper_env.hardware.bus.server.VirtualBus(...).path)"
        )
    if not isinstance(port, str | os.PathLike):
        raise ConfigError(f"{_NAME}: argument 'port': expected a path, got {port!r}")
    return os.fspath(port)


def _check_integer(arg: str, value: Any, low: int, high: int | None) -> None:
    ok = isinstance(value, int | np.integer) and not isinstance(value, bool)
    if not (ok and value >= low and (high is None or value <= high)):
        bounds = f"{low}..{high}" if high is not None else f">= {low}"
        raise ConfigError(f"{_NAME}: argument {arg!r}: expected an integer {bounds}, got "
                          f"{value!r}")  # fmt: skip


def _errors(g: BusGripper) -> list[str]:
    """The names of the error bits the servo reports."""
    errors = g.status()["errors"]
    assert isinstance(errors, list)
    return [str(e) for e in errors]


def _sleep_until(deadline: float) -> None:
    """Sleep until ``time.perf_counter()`` reaches ``deadline``."""
    while (left := deadline - time.perf_counter()) > 0:
        time.sleep(left)


def _wait_for(g: BusGripper, timeout_s: float) -> None:
    """Wait until a rebooted servo answers a ping again (or the timeout)."""
    deadline = time.perf_counter() + timeout_s
    while True:
        time.sleep(0.05)
        try:
            g.link.ping(g.servo_id)
            return
        except BusError:
            if time.perf_counter() > deadline:
                raise
