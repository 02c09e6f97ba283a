"""``gripper_env/GripperServoHardware-v0``: ``GripperServo-v0`` on the real gripper (host in loop).

The board (``firmware/gripper``, or the virtual board of :mod:`gripper_env.hardware.virtual`)
runs in open loop; every step sends the agent's servo command as the SETPOINT of the next 20 ms
control period and waits for that period's telemetry. Spaces, normalisation and reward are the
simulated environment's (:mod:`gripper_env.envs.spaces`, :func:`~gripper_env.envs.kernels.
period_reward`, :func:`~gripper_env.envs.kernels.tracking_observation`), so a policy trained in
simulation runs here unchanged.
"""

from __future__ import annotations

import os
import time
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.control_batch import DIVERGED_PENALTY, VARIATION_CAP
from gripper_env.envs.episode import draw_episode
from gripper_env.envs.link_settings import check_link_arguments, check_port
from gripper_env.envs.settings import check_reward_weights, parse_settings
from gripper_env.envs.spaces import OBS_BOUND, RATE_TIME_S, check_actions
from gripper_env.hardware.host.calibration import (
    Calibration,
    board_calibration,
    load_calibration,
)
from gripper_env.hardware.host.device import GripperDevice
from gripper_env.hardware.host.errors import DeviceError, DeviceFault, DeviceTimeout
from gripper_env.hardware.host.experiment import settle_jaw
from gripper_env.hardware.host.telemetry import TelemetryBlock
from gripper_env.hardware.protocol import Mode
from gripper_env.io.config import ConfigError
from gripper_env.model.references import Reference

__all__ = ["GripperServoHardwareEnv", "MissedDeadlineWarning", "SettleWarning"]

_NAME = "GripperServoHardware-v0"


class MissedDeadlineWarning(RuntimeWarning):
    """A step arrived after the end of the control period it was meant for."""


class SettleWarning(RuntimeWarning):
    """At reset the jaw did not settle at the reference's start in time."""


class GripperServoHardwareEnv(gym.Env[np.ndarray, np.ndarray]):
    """Drive the real gripper's hobby servo to follow a grip/un-grip reference.

    ## Description

    ``gripper_env/GripperServo-v0`` with the simulated gripper replaced by the board: a
    :class:`~gripper_env.hardware.host.device.GripperDevice` on a serial port (the Arduino Mega
    running ``firmware/gripper``, or a virtual board on a pseudo-terminal). The board runs in
    open loop (``Mode.OPEN_LOOP``): its 1 kHz tick drives the servo at the setpoint and
    reports the potentiometer. Every step the host sends the agent's command as the SETPOINT of
    the next control period (20 ms by default, the servo's 50 Hz refresh), waits until the board's
    telemetry covers that period (device time, so the virtual board works at any speed), and
    computes reward and observation from the period's samples, measured angles being the ADC
    counts through the calibration. Spaces, normalisation and reward formula are
    ``GripperServo-v0``'s (shared code): a policy trained in simulation runs here unchanged.

    Real time: the host has one control period per step. A fixed schedule of periods runs on
    the board's clock; a step that arrives after the end of the period it was meant for (the
    agent or the host was slower than the period, the previous command was held longer) is a
    *missed deadline*: counted in ``info["missed_deadlines"]`` (this episode), its lateness in
    ``info["late_ms"]``, a :class:`MissedDeadlineWarning` on the first miss of an episode and on
    every ``warn_every``-th after; the schedule then restarts from the late step. The host knows
    the device time to within a telemetry frame (``telemetry_batch`` ms), so lateness is measured
    to that resolution. The reference advances one control period per step, as in simulation.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``, as ``GripperServo-v0``:

    | Num | Action        | Min | Max | Meaning                                               |
    |-----|---------------|-----|-----|-------------------------------------------------------|
    | 0   | servo command | -1  | 1   | ``command = c + h * a`` over the command range (deg)  |

    ``c``, ``h``: centre and half-width of the command range (``[0, 180]`` deg by default, the
    ``actual`` preset's, what ``Servo.write`` accepts). Actions are clipped to [-1, 1] and the
    command to the jaw range [21, 92] deg (the board clamps too); NaN or infinite actions raise
    ``ValueError`` before anything is sent.

    ## Observation Space

    ``Box(-10, 10, (6,), float32)``, as ``GripperServo-v0`` (no context features: the real
    plant is not known). With ``j`` and ``w`` the centre and half-width of the jaw range (56.5
    and 35.5 deg), ``y`` the measured jaw angle at the end of the period (the last telemetry
    sample) and ``r`` the reference for the next period:

    | Num | Observation     | Formula                                                   |
    |-----|-----------------|-----------------------------------------------------------|
    | 0   | position        | ``(y - j) / w``                                           |
    | 1   | reference       | ``(r - j) / w``                                           |
    | 2   | error           | ``e = (r - y) / w``                                       |
    | 3   | error rate      | ``(e - e_prev) * 0.02 s / T_c`` (change per 20 ms frame)  |
    | 4   | error integral  | ``sum(e * T_c)`` (s), held within [-10, 10]               |
    | 5   | previous action | the last (clipped) action; at reset the resting command   |

    ## Rewards

    ``GripperServo-v0``'s (:func:`gripper_env.envs.kernels.period_reward`), over the period's
    telemetry samples ``k`` (1 ms apart) instead of physics steps:

    ``reward = -( mean_k |r_k - y_k| / w
    + overshoot_weight * mean_k max(0, d_k (y_k - r_k)) / w
    + chatter_weight * min(10, |u_t - u_{t-1}| / h) )``

    with ``u_t`` the command sent (deg, clamped to the jaw range). A step on which the board
    faulted scores ``-100``, like a diverged simulation (ending early must not pay).

    ## Starting State

    ``reset()`` opens the port and handshakes on first use (or after the board lost its
    session), configures the board (calibration, jaw range, 1 kHz telemetry), commands the
    reference's first value (92 deg, open, for the default step) in open loop and waits until
    the jaw has settled there (a 100 ms window's mean within ``settle_tol_deg`` and still) or
    ``settle_timeout_s`` passed (then a :class:`SettleWarning`, ``info["settled"] = False``).
    The previous-action entry is the command the jaw rests at. With ``reference="random"`` a new
    profile is drawn from the generator of ``reset(seed=...)``; the measurements themselves are
    not reproducible (the spec is registered ``nondeterministic``).

    ## Episode End

    Truncation at the end of the reference (1000 steps of 20 ms for the 20 s step) and by the
    ``TimeLimit`` of 1000 steps registered with the id. Termination when the board made a safe
    stop (fault: watchdog after 500 ms without a host frame, i.e. an agent pausing that long
    between steps; ESTOP; potentiometer at a rail): ``terminated=True``, reward -100,
    ``info["fault"]`` says which; the jaw is open and ``reset()`` acknowledges the fault and
    starts again. The agent can learn from such an ending, so it is an episode end, not an
    exception. Link failures are exceptions, since no episode can continue over them:
    :class:`~gripper_env.hardware.host.device.DeviceTimeout` (silent board),
    :class:`~gripper_env.hardware.host.device.DeviceReset` (the board restarted),
    :class:`~gripper_env.hardware.host.device.PortVanished` (cable pulled),
    :class:`~gripper_env.hardware.host.device.LinkError` (corrupted frames); after one, ``reset()``
    handshakes again.

    ``close()`` (also on leaving a ``with`` block, on any exception or ``KeyboardInterrupt``;
    a ``KeyboardInterrupt`` inside ``step`` or ``reset`` stops the board at once) leaves the
    board idle with the jaw in the safe open position and closes the port. If the host dies
    without closing, the board's watchdog does the same 500 ms later.

    ## Arguments

    ```python
    import gymnasium as gym
    from gripper_env.hardware.host.calibration import Calibration
    from gripper_env.hardware.virtual import VirtualDevice

    with VirtualDevice("test2", "actual", speed=1.0) as vd:  # or the real board's port
        env = gym.make(
            "gripper_env:gripper_env/GripperServoHardware-v0",
            port=vd.path,              # required: "/dev/ttyACM0", a pty, or a pyserial URL
            calibration=Calibration(*vd.rig.true_calibration),  # default: the board's own
            boot_wait_s=0.0,           # 2 s for a real Mega (opening the port resets it)
            reference="step",          # profile name, CSV path, or "random"
            control_period_s=0.020,    # agent step (s), a whole number of 1 ms ticks
        )
        with env:
            obs, info = env.reset(seed=0)
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    ```

    Also ``episode_s`` (length of random references, s), ``command_range_deg``,
    ``overshoot_weight``, ``chatter_weight`` (as ``GripperServo-v0``), ``timeout_s`` (wait for
    an answer, s), ``settle_tol_deg`` (2), ``settle_timeout_s`` (5), ``telemetry_batch``
    (samples per telemetry frame, 5), ``warn_every`` (50). The port is not touched before the
    first ``reset()``; a bad argument fails at construction with a message that names it.

    ## Version History

    * v0: initial version.
    """

    # gymnasium declares metadata per instance (Env.metadata); this is the class default
    metadata: dict[str, Any] = {"render_modes": [], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        port: str | os.PathLike[str] | None = None,
        *,
        calibration: Calibration | str | os.PathLike[str] | None = None,
        reference: Any = "step",
        episode_s: float = 20.0,
        control_period_s: float = 0.020,
        command_range_deg: Any = None,
        overshoot_weight: float = 1.0,
        chatter_weight: float = 0.1,
        boot_wait_s: float = 2.0,
        timeout_s: float = 0.5,
        settle_tol_deg: float = 2.0,
        settle_timeout_s: float = 5.0,
        telemetry_batch: int = 5,
        warn_every: int = 50,
        render_mode: str | None = None,
    ) -> None:
        port_path = check_port(_NAME, port, render_mode)
        self.settings = parse_settings(
            _NAME,
            reference=reference,
            episode_s=episode_s,
            control_period_s=control_period_s,
            command_range_deg=command_range_deg,
        )
        check_reward_weights(_NAME, overshoot_weight, chatter_weight)
        check_link_arguments(
            _NAME,
            boot_wait_s,
            timeout_s,
            settle_tol_deg,
            settle_timeout_s,
            telemetry_batch,
            warn_every,
        )
        # a calibration given (or $GRIPPER_CALIBRATION) is read now and checked against the
        # board when it is opened; without one, the board's own is found by its device id then
        given: Calibration | None = None
        if isinstance(calibration, Calibration):
            given = calibration
        elif calibration is not None or os.environ.get("GRIPPER_CALIBRATION"):
            try:
                given = load_calibration(calibration)
            except ValueError as exc:
                raise ConfigError(f"{_NAME}: argument 'calibration': {exc}") from None
        self._given_calibration = given
        self.calibration = given
        self.port = port_path
        self.render_mode = None
        self.boot_wait_s = float(boot_wait_s)
        self.timeout_s = float(timeout_s)
        self.settle_tol_deg = float(settle_tol_deg)
        self.settle_timeout_s = float(settle_timeout_s)
        self.telemetry_batch = telemetry_batch
        self.warn_every = warn_every
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        n_obs = K.observation_size(K.MODE_SERVO, 1, 0)
        self.observation_space = gym.spaces.Box(-OBS_BOUND, OBS_BOUND, (n_obs,), np.float32)
        s = self.settings
        (jlo, jhi), (clo, chi) = s.jaw_range_deg, s.command_range_deg
        self._jc, self._jh = 0.5 * (jlo + jhi), 0.5 * (jhi - jlo)
        self._cc, self._ch = 0.5 * (clo + chi), 0.5 * (chi - clo)
        self._weights = (float(overshoot_weight), float(chatter_weight), VARIATION_CAP)
        self._rate = RATE_TIME_S / s.control_period_s
        self._period_us = round(s.control_period_s * 1e6)
        self.device: GripperDevice | None = None
        self._stale = True  # the next reset handshakes and configures
        self._done = True
        self._obs = np.zeros(n_obs, dtype=np.float32)
        self._pending: list[TelemetryBlock] = []
        self._ref = np.zeros(0)
        self._ref_name = ""
        self._len = 0  # physics steps of the episode (whole periods of the reference)
        self._t = 0  # physics steps since reset
        self._t_obs_us = 0  # device time of the current observation (start of the next period)
        self._e_prev = self._integral = self._direction = 0.0
        self._u_prev = 0.0
        self.missed_deadlines = 0  # this episode
        self.missed_deadlines_total = 0
        _load_kernels()

    # ---- Gymnasium interface -------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        episode = draw_episode(self.settings, self.np_random)
        self._done = True
        try:
            return self._reset(episode.reference)
        except KeyboardInterrupt:
            self._stop_device()
            raise
        except DeviceError as exc:
            self._failed(exc)
            raise

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done or self.device is None:
            raise RuntimeError(f"{_NAME}: call reset() before step() (the episode has ended)")
        a = float(np.clip(check_actions(action, (1,))[0], -1.0, 1.0))
        lo, hi = self.settings.jaw_range_deg
        command = min(max(self._cc + self._ch * a, lo), hi)
        try:
            return self._step(a, command)
        except KeyboardInterrupt:
            self._done = True
            self._stop_device()
            raise
        except DeviceFault as exc:
            return self._fault(exc)
        except DeviceError as exc:
            self._failed(exc)
            raise

    def close(self) -> None:
        """Leave the board idle in the safe (open) position and close the port (idempotent)."""
        self._done = True
        self._stop_device()

    # ---- internals -----------------------------------------------------------------------------

    def _connect(self) -> GripperDevice:
        dev = self.device
        if dev is None or not dev.is_open:
            dev = self.device = GripperDevice(
                self.port,
                calibration=self.calibration,
                boot_wait_s=self.boot_wait_s,
                timeout_s=self.timeout_s,
            )
        elif self._stale:
            dev.handshake()
        if self._stale:
            device_id = dev.info.device_id if dev.info else None
            self.calibration = board_calibration(
                device_id, self.port, self._given_calibration, f"{_NAME}: argument 'calibration'"
            )
            dev.configure(
                calibration=self.calibration,
                jaw_deg=self.settings.jaw_range_deg,
                decimation=1,
                telemetry_batch=self.telemetry_batch,
            )
            self._stale = False
        return dev

    def _reset(self, reference: Reference) -> tuple[np.ndarray, dict[str, Any]]:
        dev = self._connect()
        s = self.settings
        lo, hi = s.jaw_range_deg
        r0 = float(reference.values_deg[0])
        u0 = min(max(r0, lo), hi)
        if dev.faults:
            dev.set_mode(Mode.IDLE)  # acknowledges a latched fault
        dev.set_setpoint(u0)
        dev.set_mode(Mode.OPEN_LOOP)
        settled, y0 = self._settle(dev, u0)
        dev.poll(0.0)
        last = dev.read_telemetry()
        self._pending = []
        if len(last):
            y0 = float(last.position_deg[-1])
        self._t_obs_us = dev.latest_time_us or 0
        self._ref = np.ascontiguousarray(reference.values_deg, dtype=np.float64)
        self._ref_name = reference.name
        self._len = (len(self._ref) // s.n_sub) * s.n_sub
        self._t = 0
        self._direction = 0.0
        self._u_prev = u0
        self.missed_deadlines = 0
        # no period yet: no error rate, no integral
        self._e_prev, self._integral = K.tracking_observation(
            y0, r0, 0.0, 0.0, 0, s.dt_s, self._jc, self._jh, 0.0, OBS_BOUND, self._obs
        )
        self._obs[5] = np.clip((u0 - self._cc) / self._ch, -1.0, 1.0)
        self._done = False
        info = {
            "reference": reference.name,
            "settled": settled,
            "position_deg": y0,
            "command_deg": u0,
            "missed_deadlines": 0,
            "port": self.port,
        }
        return self._obs.copy(), info

    def _settle(self, dev: GripperDevice, target_deg: float) -> tuple[bool, float]:
        """Wait until the jaw rests at ``target_deg`` (or the timeout); (settled, last angle)."""
        settled, y, mean = settle_jaw(dev, target_deg, self.settle_tol_deg, self.settle_timeout_s)
        if not settled:
            warnings.warn(
                f"{_NAME}: the jaw did not settle at {target_deg:g} deg within "
                f"{self.settle_timeout_s:g} s (it is at {mean:.1f} deg); starting anyway",
                SettleWarning,
                stacklevel=4,
            )
        return settled, y

    def _step(self, a: float, command: float) -> tuple[np.ndarray, float, bool, bool, dict]:
        dev = self.device
        assert dev is not None
        s = self.settings
        dev.poll(0.0)
        arrival = dev.latest_time_us or 0
        late_us = arrival - (self._t_obs_us + self._period_us)
        if late_us > 0:
            self._missed(late_us)
            self._t_obs_us = arrival  # the schedule restarts from the late step
        dev.set_setpoint(command)
        end_us = self._t_obs_us + self._period_us
        self._pending.append(dev.read_telemetry())
        wait_until = time.monotonic() + s.control_period_s + self.timeout_s
        while (dev.latest_time_us or 0) < end_us:
            if time.monotonic() > wait_until:
                raise DeviceTimeout(
                    f"no telemetry from {self.port} up to the end of the control period"
                    + dev.link_summary()
                )
            dev.poll(0.005)
            self._pending.append(dev.read_telemetry())
        block = TelemetryBlock.concatenate(self._pending)
        period = (block.t_us > self._t_obs_us) & (block.t_us <= end_us)
        after = block.t_us > end_us
        self._pending = [block.select(after)] if after.any() else []
        if not period.any():  # the period's frames were lost: use the next sample
            period = after & (np.cumsum(after) == 1)
        y = np.ascontiguousarray(block.position_deg[period], dtype=np.float64)
        t = self._t
        last = len(self._ref) - 1
        w_over, w_var, cap = self._weights
        reward, self._direction = K.period_reward(
            self._ref, t, last, y, self._direction, abs(command - self._u_prev),
            self._jh, self._ch, w_over, w_var, cap,
        )  # fmt: skip
        self._u_prev = command
        self._t = t_new = t + s.n_sub
        self._t_obs_us = end_us
        self._e_prev, self._integral = K.tracking_observation(
            float(y[-1]), self._ref[min(t_new, last)], self._e_prev, self._integral,
            s.n_sub, s.dt_s, self._jc, self._jh, self._rate, OBS_BOUND, self._obs,
        )  # fmt: skip
        self._obs[5] = a
        truncated = t_new >= self._len
        self._done = truncated
        info = {
            "missed_deadlines": self.missed_deadlines,
            "late_ms": max(late_us, 0) / 1000.0,
            "position_deg": float(y[-1]),
            "command_deg": command,
            "samples": len(y),
            "device_time_us": end_us,
        }
        return self._obs.copy(), float(reward), False, truncated, info

    def _missed(self, late_us: int) -> None:
        self.missed_deadlines += 1
        self.missed_deadlines_total += 1
        n = self.missed_deadlines
        if n == 1 or n % self.warn_every == 0:
            warnings.warn(
                f"{_NAME}: step {self._t // self.settings.n_sub + 1} arrived {late_us / 1000:.1f} "
                f"ms after the end of its {self._period_us / 1000:g} ms control period "
                f"({n} missed deadlines this episode): the agent or the host is too slow, the "
                "previous command was held longer",
                MissedDeadlineWarning,
                stacklevel=4,
            )

    def _fault(self, exc: DeviceFault) -> tuple[np.ndarray, float, bool, bool, dict]:
        """The board made a safe stop: end the episode (the next reset acknowledges it)."""
        self._done = True
        self._pending = []
        warnings.warn(f"{_NAME}: episode terminated: {exc}", RuntimeWarning, stacklevel=3)
        info = {
            "missed_deadlines": self.missed_deadlines,
            "late_ms": 0.0,
            "fault": str(exc),
            "faults": exc.faults,
        }
        return self._obs.copy(), -DIVERGED_PENALTY, True, False, info

    def _failed(self, exc: DeviceError) -> None:
        """A link failure: the episode is over, the next reset handshakes again."""
        self._done = True
        self._stale = True
        self._pending = []
        if self.device is not None:
            self.device.safe_stop()
        exc.add_note(f"{_NAME}: the episode is over; reset() handshakes again, close() stops")

    def _stop_device(self) -> None:
        dev, self.device = self.device, None
        self._stale = True
        if dev is not None:
            try:
                dev.safe_stop()
            finally:
                dev.close()


def _load_kernels() -> None:
    """Compile (or load from numba's cache) the shared reward and observation functions now: a
    first compilation inside a step would hold the host for longer than the board's watchdog."""
    ref = np.zeros(2)
    K.period_reward(ref, 0, 1, ref, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    K.tracking_observation(0.0, 0.0, 0.0, 0.0, 1, 1e-3, 0.0, 1.0, 1.0, 1.0, np.zeros(6, np.float32))
