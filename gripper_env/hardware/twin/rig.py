"""The simulated gripper behind a virtual or emulated board, and the firmware's Python twin wired
to it.

* :class:`VirtualRig`, the servo, jaw and potentiometer: the project's one simulation core
  (:class:`~gripper_env.sim.BatchSimulator`) in open loop, driven by the board's servo
  command one physics step per tick, whose measured angle is reported as 10-bit ADC counts;
* :class:`TwinBoard`, :class:`~gripper_env.hardware.twin.firmware.Firmware` (the Python twin of the
  sketch) ticked with the rig's reading, its servo command driving the rig: the board
  :class:`~gripper_env.hardware.virtual.VirtualDevice` runs by default.

The one difference from the board's timing: the firmware reads the measurement taken at the
end of the previous physics step (the simulation core measures before it applies a command), a
1 ms sensor delay that the closed loop hardly notices (the plants' fastest pole is 96 rad/s).
"""

from __future__ import annotations

import numpy as np

from gripper_env.hardware.safety import (
    ADC_MAX_COUNT,
    CAL_ANGLE_HI_DEG,
    CAL_ANGLE_LO_DEG,
)
from gripper_env.hardware.twin.firmware import Firmware
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import STATE_SIZE, pid_update
from gripper_env.model.plants import load_plant
from gripper_env.sim import BatchSimulator

__all__ = ["VIRTUAL_DEVICE_ID", "TwinBoard", "VirtualRig"]

VIRTUAL_DEVICE_ID = 0x56495254  # "VIRT"
_DEFAULT_ADC_RANGE_DEG = (0.0, 270.0)  # a 270-degree pot on the 10-bit ADC


class VirtualRig:
    """The servo, jaw and potentiometer behind the virtual board.

    Parameters
    ----------
    plant : str or path
        Plant name or YAML file (the servo's transfer function).
    disturbance : str or path
        Actual-gripper preset (command path, friction, stops, sensor noise and ADC).
    seed : int
        Noise seed.
    y0_deg : float
        Jaw angle at power-on (deg).
    pulse_train : bool
        The servo is driven by a real pulse train (the emulated firmware's): the preset's command
        quantisation and refresh are dropped, since the pulses carry their own resolution and
        50 Hz timing. The command range, friction, stops and sensor stay.
    """

    def __init__(
        self,
        plant: str = "test2",
        disturbance: str = "actual",
        seed: int = 0,
        y0_deg: float = 92.0,
        *,
        pulse_train: bool = False,
    ) -> None:
        self.plant = load_plant(plant)
        self.disturbance = load_disturbance(disturbance)
        self.pulse_train = pulse_train
        if pulse_train:
            self.disturbance = self.disturbance.with_overrides(
                {"command": {"quantization": "none", "refresh_period_s": 0.0}}
            )
        sensor = self.disturbance.sensor
        delay = max(1, round(sensor.delay_s / self.plant.dt_s))
        self.sim = BatchSimulator(self.plant, delay_capacity=delay)
        self.sim.configure(None, self.disturbance)
        self.sim.reset(y0_deg, seed)
        lo, hi = sensor.adc_range_deg if sensor.adc_bits else _DEFAULT_ADC_RANGE_DEG
        self.adc_lo_deg = lo
        self.deg_per_count = (hi - lo) / ADC_MAX_COUNT
        self._command = np.zeros(1)
        self._out = (np.empty((1, 1)), np.empty((1, 1)), np.empty((1, 1)), np.empty((1, 1)))
        # load the compiled kernels now, not at the first tick (a zero-step advance is a no-op)
        empty = (np.empty((1, 0)), np.empty((1, 0)), np.empty((1, 0)), np.empty((1, 0)))
        self.sim.advance(0, self._command, 0, empty)
        pid_update(0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 1e-3, 0.0, 1.0, 1, 1.0, 1.0, 0,
                   np.zeros(STATE_SIZE), 1, 1.0, 5.0, 0.5, 1.0, 100.0)  # fmt: skip
        self.adc = self.counts(y0_deg)
        self.position_deg = float(y0_deg)

    def counts(self, angle_deg: float) -> int:
        """ADC reading (0..1023) for a measured angle (deg)."""
        code = int(np.floor((angle_deg - self.adc_lo_deg) / self.deg_per_count + 0.5))
        return min(max(code, 0), ADC_MAX_COUNT)

    @property
    def true_calibration(self) -> tuple[float, float]:
        """ADC counts (fractional) at exactly 21 and 92 deg: what a perfect calibration finds."""
        return tuple(  # type: ignore[return-value]
            (a - self.adc_lo_deg) / self.deg_per_count for a in (CAL_ANGLE_LO_DEG, CAL_ANGLE_HI_DEG)
        )

    def step(self, command_deg: float | None) -> int:
        """Advance one physics step with the servo command (deg), ``None`` while the servo gets
        no pulses (limp: it holds where it is); return the new ADC reading."""
        self._command[0] = self.position_deg if command_deg is None else command_deg
        _r, _u, y, y_true = self.sim.advance(1, self._command, 0, self._out)
        self.position_deg = float(y_true[0, 0])
        self.adc = self.counts(float(y[0, 0]))
        return self.adc


class TwinBoard:
    """The Python twin of the firmware wired to a rig: the board :class:`VirtualDevice` runs by
    default (the other is :class:`~gripper_env.hardware.emulator.board.EmulatedBoard`, the real
    image).

    Parameters
    ----------
    rig : VirtualRig
        The simulated gripper.
    device_id : int
        Board id reported in INFO.

    Attributes
    ----------
    firmware : Firmware
        The board's state machine.
    """

    def __init__(self, rig: VirtualRig, device_id: int = VIRTUAL_DEVICE_ID) -> None:
        self.rig = rig
        self.device_id = device_id
        self.firmware = Firmware(device_id, 0)
        self.firmware.tx += b"\x00"  # the sketch's boot delimiter (gripper.ino, setup)

    @property
    def active(self) -> bool:
        """In an active mode (open or closed loop)."""
        return self.firmware.mode != 0

    @property
    def last_rx_us(self) -> int:
        """Device time (us) of the last valid host frame."""
        return self.firmware.last_rx_us

    def receive(self, data: bytes, now_us: int) -> None:
        """Bytes from the host at device time ``now_us``."""
        self.firmware.receive(data, now_us)

    def step(self, now_us: int, overrun: bool = False) -> None:
        """One control tick with the rig's reading, then one physics step with its command."""
        fw = self.firmware
        fw.tick(now_us, self.rig.adc, overrun)
        self.rig.step(fw.command if fw.servo_on else None)

    def uart_out(self, max_bytes: int) -> bytes:
        """At most ``max_bytes`` of the transmit queue, as the UART sends them in one tick."""
        return self.firmware.uart_drain(max_bytes) if self.firmware.tx and max_bytes else b""

    def reset(self, now_us: int) -> None:
        """The board restarts (no session, servo limp) and sends its boot delimiter."""
        self.firmware.begin(self.device_id, now_us)
        self.firmware.tx += b"\x00"
