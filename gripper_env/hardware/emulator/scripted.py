"""A scripted host on an in-process board, and the three-way agreement of the firmware models.

:class:`ScriptedHost` drives a board object (the Python twin, :class:`~gripper_env.hardware.
virtual_rig.TwinBoard`, or the compiled image under simavr,
:class:`~gripper_env.hardware.emulator.board.
EmulatedBoard`) without a pty: every frame goes out at a chosen millisecond of device time and
the board's bytes are decoded as they come. A run is therefore deterministic, which the fault
tests and the agreement need and a host racing a pty cannot give.

:func:`run_agreement` deploys one set of gains and one reference profile three ways:

1. on the emulated board (the real firmware, float32 PID on the AVR, the servo driven by its
   Timer1 pulses: 0.5 us resolution, 50 Hz at the timer's phase);
2. on the Python twin of the firmware (float64 PID; the rig's servo takes the command in whole
   degrees every 20 ms, like ``Servo.write``);
3. in the simulation core, :func:`gripper_env.sim.simulate`, closed loop with the same
   PID, command path and sensor;

with the same host traffic as ``tuners.rig.deploy`` (the profile's value every 20 ms, a heartbeat
every 200 ms) and compares the measured jaw angles. The models differ by the quantisation of
the command (whole degrees at 50 Hz, or the pulse's 0.05 deg at the timer's 50 Hz phase) and of
the 10-bit ADC, so the largest difference is judged against those: an angle may differ by the
command quantum plus two ADC counts, and in time by one 20 ms servo frame plus the pulse's
width and one physics step (:data:`AGREEMENT_SHIFT_MS`: the same response, its servo updated
at another phase).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.host.configuration import configure_message
from gripper_env.hardware.host.telemetry import TelemetryBlock, TelemetryClock
from gripper_env.hardware.twin.firmware import UART_BYTES_PER_TICK
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.references import Reference, load_reference
from gripper_env.sim import simulate

__all__ = [
    "AGREEMENT_DISTURBANCE",
    "AGREEMENT_SHIFT_MS",
    "Agreement",
    "ScriptedHost",
    "run_agreement",
    "tube_difference",
]

# The rig of the agreement: the actual gripper's command path (whole degrees, 50 Hz), stops and
# 10-bit ADC, without friction and sensor noise (stick-slip would make small command differences
# large and is not what is being compared).
AGREEMENT_DISTURBANCE: dict[str, Any] = {
    "extends": "actual",
    "friction": {"model": "none", "S_deg": 0.0, "J_deg": 0.0},
    "sensor": {"noise_std_deg": 0.0},
}
SERVO_FRAME_MS = 20
# A response may lag another by one servo frame, plus the pulse (the servo has a command when its
# pulse ends: 1.5 ms at 92 deg, rounded up) and the 1 ms physics step that then takes it in.
AGREEMENT_SHIFT_MS = SERVO_FRAME_MS + 2 + 1
HOST_PERIOD_MS = 20  # tuners.rig.deploy sends the profile's value every 20 ms...
HEARTBEAT_MS = 200  # ...and a heartbeat every 200 ms


class Board(Protocol):
    """What :class:`ScriptedHost` needs of a board (both board classes have it)."""

    def receive(self, data: bytes, now_us: int) -> None: ...

    def step(self, now_us: int, overrun: bool = False) -> None: ...

    def uart_out(self, max_bytes: int) -> bytes: ...


class ScriptedHost:
    """A host that talks to an in-process board at chosen instants of device time.

    Parameters
    ----------
    board : TwinBoard or EmulatedBoard
        The board; it has just been made (device time 0).
    """

    def __init__(self, board: Board) -> None:
        self.board = board
        self.ms = 0
        self.seq = 0
        self.decoder = proto.FrameDecoder()  # from power-on: the first byte starts a frame
        self.messages: list[tuple[int, proto.Message]] = []
        self._blocks: list[TelemetryBlock] = []
        self._clock = TelemetryClock()

    @property
    def now_us(self) -> int:
        """Device time (us) of the next step."""
        return self.ms * 1000

    def send(self, msg: proto.Message) -> int:
        """Put ``msg`` on the line now; returns its sequence number."""
        seq = self.seq
        self.send_raw(proto.encode_frame(seq, msg))
        self.seq = (seq + 1) & 0xFF
        return seq

    def send_raw(self, data: bytes) -> None:
        """Put bytes on the line now (noise, a corrupted frame...)."""
        self.board.receive(data, self.now_us)

    def run(self, ms: int, heartbeat_ms: int = 0) -> None:
        """Let ``ms`` milliseconds of device time pass, collecting what the board sends, and send
        a HEARTBEAT every ``heartbeat_ms`` (0: none; the board's watchdog needs a frame at least
        every 500 ms in an active mode)."""
        for k in range(ms):
            if heartbeat_ms and k % heartbeat_ms == heartbeat_ms - 1:
                self.send(proto.Heartbeat(self.ms))
            self.board.step(self.now_us)
            self.ms += 1
            self._collect(self.board.uart_out(UART_BYTES_PER_TICK))

    def _collect(self, data: bytes) -> None:
        if not data:
            return
        for frame in self.decoder.feed(data):
            msg = frame.message
            if isinstance(msg, proto.Telemetry):
                self._blocks.append(self._clock.block(msg))
            else:
                self.messages.append((self.ms, msg))

    def replies(self, kind: type[proto.Message], since_ms: int = 0) -> list[Any]:
        """Messages of one type received at or after ``since_ms``."""
        return [m for t, m in self.messages if isinstance(m, kind) and t >= since_ms]

    def samples(self) -> TelemetryBlock:
        """Every telemetry sample received so far (``position_deg`` is NaN: no calibration)."""
        self._blocks = [TelemetryBlock.concatenate(self._blocks)]
        return self._blocks[0]

    def deploy(self, values: np.ndarray) -> int:
        """``tuners.rig.deploy``'s traffic on an open, configured session: the profile's first
        value,
        closed loop, then the value every 20 ms and a heartbeat every 200 ms, one sample of
        ``values`` (deg) per millisecond. Returns the device ms at which closed loop was asked."""
        self.send(proto.Setpoint(float(values[0])))
        self.send(proto.SetMode(proto.Mode.CLOSED_LOOP))
        start = self.ms
        for k in range(len(values)):
            if k % HOST_PERIOD_MS == 0 and k:
                self.send(proto.Setpoint(float(values[k])))
            if k % HEARTBEAT_MS == 0 and k:
                self.send(proto.Heartbeat(k))
            self.run(1)
        return start

    def open_session(self, configure: proto.Configure | None = None) -> proto.Info:
        """HELLO (and CONFIGURE), 5 ms apart; returns the INFO.

        Raises
        ------
        RuntimeError
            If the board does not answer as the protocol says.
        """
        since = self.ms
        self.send_raw(b"\x00")
        self.send(proto.Hello())
        self.run(5)
        info = self.replies(proto.Info, since)
        if not info:
            raise RuntimeError(f"no INFO within 5 ms of HELLO: {self.messages[-3:]}")
        if configure is not None:
            since = self.ms
            self.send(configure)
            self.run(5)
            if not self.replies(proto.Status, since):
                raise RuntimeError(f"CONFIGURE not acknowledged: {self.messages[-3:]}")
        return info[-1]


def tube_difference(y: np.ndarray, other: np.ndarray, shift: int) -> np.ndarray:
    """At each sample, the distance from ``y`` to the nearest value ``other`` takes within
    ``shift`` samples either side: the difference left once a time shift of up to ``shift``
    samples is allowed (NaN where ``other`` has no value in the window)."""
    n = len(y)
    out = np.full(n, np.inf)
    for s in range(-shift, shift + 1):
        lo, hi = max(0, -s), min(n, n - s)
        d = np.abs(y[lo:hi] - other[lo + s : hi + s])
        out[lo:hi] = np.fmin(out[lo:hi], d)
    out[~np.isfinite(out)] = np.nan
    return out


@dataclass
class Agreement:
    """The three responses of :func:`run_agreement` on one time axis (the profile's, 1 ms).

    Attributes
    ----------
    t_s : ndarray
        Time from the board's first closed-loop sample (s).
    reference_deg : ndarray
        The reference as the emulated board applied it.
    y_deg : dict of str to ndarray
        Measured jaw angle (deg) of ``"emulated"``, ``"twin"`` and ``"simulation"``, each read
        through the same two-point calibration from its 10-bit ADC counts.
    command_deg : dict of str to ndarray
        PID output (deg) of each (the servo command before the servo's quantisation).
    lsb_deg, command_quantum_deg : float
        The ADC's and the servo command's resolution (deg).
    """

    t_s: np.ndarray
    reference_deg: np.ndarray
    y_deg: dict[str, np.ndarray]
    command_deg: dict[str, np.ndarray]
    lsb_deg: float
    command_quantum_deg: float
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def tolerance_deg(self) -> float:
        """The quantisation budget: one command quantum plus two ADC counts (deg)."""
        return self.command_quantum_deg + 2 * self.lsb_deg

    def pairs(self) -> list[tuple[str, str]]:
        return [("emulated", "twin"), ("emulated", "simulation"), ("twin", "simulation")]

    def largest(self, a: str, b: str, shift_ms: int = AGREEMENT_SHIFT_MS) -> float:
        """Largest difference (deg) of two responses, within ``shift_ms`` of time."""
        return float(np.nanmax(tube_difference(self.y_deg[a], self.y_deg[b], shift_ms)))

    def largest_pointwise(self, a: str, b: str) -> float:
        """Largest difference (deg) of two responses at the same instant."""
        return float(np.nanmax(np.abs(self.y_deg[a] - self.y_deg[b])))

    def rms(self, a: str, b: str) -> float:
        """Root-mean-square difference (deg) of two responses at the same instant."""
        d = self.y_deg[a] - self.y_deg[b]
        return float(np.sqrt(np.nanmean(d * d)))

    def summary(self) -> dict[str, dict[str, float]]:
        """Per pair: largest difference within a servo frame, pointwise, and RMS (deg)."""
        return {
            f"{a} vs {b}": {
                "largest_deg": self.largest(a, b),
                "largest_pointwise_deg": self.largest_pointwise(a, b),
                "rms_deg": self.rms(a, b),
            }
            for a, b in self.pairs()
        }


def _script(host: ScriptedHost, cfg: proto.Configure, values: np.ndarray) -> None:
    """Boot, session, the deploy's traffic (:meth:`ScriptedHost.deploy`)."""
    host.run(50)  # boot
    host.open_session(cfg)
    start = host.deploy(values)
    host.run(10)  # the last telemetry batch
    if host.replies(proto.ErrorReport, start):
        raise RuntimeError(f"the board refused the deploy: {host.replies(proto.ErrorReport)}")


def _closed_loop_run(host: ScriptedHost, calibration: Calibration, n: int) -> dict[str, np.ndarray]:
    s = host.samples()
    active = np.flatnonzero((s.flags & proto.SampleFlag.MODE_MASK) == proto.Mode.CLOSED_LOOP)
    if len(active) < n:
        raise RuntimeError(f"{len(active)} closed-loop samples, {n} expected")
    first = active[0]
    idx = slice(first, first + n)
    # batches are stamped with micros() (4 us steps, the tick's wake-up latency): whole ms apart
    if np.any(np.round(np.diff(s.t_us[idx]) / 1000) != 1):
        raise RuntimeError("telemetry samples are missing or not 1 ms apart")
    return {
        "r": s.reference_deg[idx],
        "u": s.command_deg[idx],
        "adc": s.adc[idx],
        "y": np.asarray(calibration.to_deg(s.adc[idx])),
        "flags": s.flags[idx],
    }


def run_agreement(
    gains: PIDGains,
    profile: str | Reference = "step",
    *,
    options: PIDOptions | None = None,
    plant: str = "test2",
    disturbance: Any = None,
    image: Any = None,
    harness: Any = None,
    seed: int = 0,
) -> Agreement:
    """Deploy ``gains`` with ``profile`` on the emulated board, the Python twin and the
    simulation core, and put the three responses on one time axis (module docstring).

    Parameters
    ----------
    gains : PIDGains
        The controller.
    profile : str or Reference
        Reference profile (name, CSV path or :class:`~gripper_env.model.references.Reference`).
    options : PIDOptions, optional
        Output limits (default the jaw range), anti-windup, sign...
    plant : str
        Plant of the rig and of the simulation.
    disturbance : preset, dict or Disturbance, optional
        The rig (default :data:`AGREEMENT_DISTURBANCE`).
    image, harness : path, optional
        Firmware image and emulator harness
        (:class:`~gripper_env.hardware.emulator.mega2560.Mega2560`).
    seed : int
        Noise seed of the rigs and the simulation.
    """
    from gripper_env.hardware.emulator.board import EmulatedBoard
    from gripper_env.hardware.twin.rig import TwinBoard, VirtualRig

    ref = load_reference(profile)
    values = ref.values_deg
    options = options or PIDOptions(output_limits=(21.0, 92.0))
    disturbance = AGREEMENT_DISTURBANCE if disturbance is None else disturbance
    y0 = float(values[0])
    rig_e = VirtualRig(plant, disturbance, seed, y0, pulse_train=True)
    rig_t = VirtualRig(plant, disturbance, seed, y0)
    lo, hi = rig_t.true_calibration
    calibration = Calibration(lo, hi)
    cfg = configure_message(gains, options, calibration)
    runs = {}
    board_e = EmulatedBoard(rig_e, image=image, harness=harness)
    try:
        for name, board in (("emulated", board_e), ("twin", TwinBoard(rig_t))):
            host = ScriptedHost(board)
            _script(host, cfg, values)
            runs[name] = _closed_loop_run(host, calibration, len(values))
    finally:
        board_e.close()
    # the simulation core, driven by the reference as the twin's firmware applied it
    r = runs["twin"]["r"]
    sim = simulate(plant, r, gains=[gains.as_array()], disturbance=disturbance, seeds=seed,
                   pid_options=options, y0_deg=y0)  # fmt: skip
    dist = rig_t.disturbance
    lsb = dist.sensor.lsb_deg
    codes = np.floor((sim.y[0] - dist.sensor.adc_range_deg[0]) / lsb + 0.5)
    runs["simulation"] = {
        "r": sim.r[0],
        "u": sim.u[0],
        "adc": codes.astype(np.int64),
        "y": np.asarray(calibration.to_deg(codes)),
    }
    t = np.arange(len(values)) * ref.dt_s
    quantum = dist.command.quantum_deg
    return Agreement(
        t_s=t,
        reference_deg=runs["emulated"]["r"],
        y_deg={k: v["y"] for k, v in runs.items()},
        command_deg={k: v["u"] for k, v in runs.items()},
        lsb_deg=float(abs(calibration.deg_per_count)),
        command_quantum_deg=float(quantum) if quantum > 0 else math.nan,
        details={"calibration": calibration, "runs": runs, "disturbance": dist},
    )
