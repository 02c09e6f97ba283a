"""The paper's identification experiments: the Table-1 records, and identifying each.

1. **Record** each Table-1 experiment open loop (the desired angle is the servo command):

   ======  =========  ==================================================
   test    profile    input (desired), grip and un-grip
   ======  =========  ==================================================
   test1   ``step``     step response
   test2   ``slope60``  slope, 60 s ramps
   test3   ``slope40``  slope, 40 s ramps
   test4   ``slope20``  slope, 20 s ramps
   ======  =========  ==================================================

   (profiles of :mod:`gripper_env.model.references`). A *recorder* runs one profile and writes its
   log
   as CSV ``t_s, desired_deg, actual_deg``; two implementations: the simulated actual gripper
   (:class:`SimulatedRecorder`) and the board (:class:`DeviceRecorder`). Everything downstream
   reads the CSV, so ``python -m tuners.sysid LOG.csv`` reproduces each fit.
2. **Identify** each record with :func:`gripper_env.sysid.tfest` (2 poles, 1 zero, no delay:
   the paper's structure), initial state estimated (:func:`identify_log`).

The session (validation as the paper's stage 1, the grey-box fit of the actual gripper) is
:mod:`gripper_env.sysid.session`; its report :mod:`gripper_env.sysid.report`.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from gripper_env.hardware.host.errors import DeviceError
from gripper_env.io.files import write_csv
from gripper_env.model.disturbances import Disturbance, describe, load_disturbance
from gripper_env.model.plants import Plant, load_plant
from gripper_env.model.references import Reference, step_profile
from gripper_env.sim import simulate
from gripper_env.sysid.data import prepare_data
from gripper_env.sysid.logfile import LOG_COLUMNS, read_log
from gripper_env.sysid.tfest import TFEstimate, tfest
from gripper_env.sysid.zoh import zoh_response

if TYPE_CHECKING:
    from gripper_env.hardware.host.calibration import Calibration
    from gripper_env.hardware.host.experiment import Recording

__all__ = [
    "EXPERIMENTS",
    "QUICK_EXPERIMENTS",
    "SVF_LAMBDAS",
    "DeviceRecorder",
    "Experiment",
    "IdentifiedExperiment",
    "Recorder",
    "RecordingGaps",
    "SimulatedRecorder",
    "identify_log",
    "step_t63",
    "validation_reference",
    "write_log",
    "write_reference_csv",
]


@dataclass(frozen=True)
class Experiment:
    """One row of the paper's Table 1.

    Attributes
    ----------
    name : str
        ``"test1"`` ... ``"test4"``.
    profile : str
        Reference profile name (:func:`gripper_env.model.references.load_reference`).
    description : str
        The input as Table 1 words it.
    """

    name: str
    profile: str
    description: str

    @property
    def label(self) -> str:
        """File stem of the experiment's record and figure, e.g. ``"test2_slope60"``."""
        return f"{self.name}_{self.profile}"

    @property
    def number(self) -> int:
        """Position in Table 1, from 1."""
        return int(self.name.removeprefix("test"))


#: The paper's Table 1.
EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment("test1", "step", "step response (grip and un-grip)"),
    Experiment("test2", "slope60", "slope, 60 s ramps (grip and un-grip)"),
    Experiment("test3", "slope40", "slope, 40 s ramps (grip and un-grip)"),
    Experiment("test4", "slope20", "slope, 20 s ramps (grip and un-grip)"),
)

#: A short session (for tests and smoke runs): the step and the fastest slope.
QUICK_EXPERIMENTS: tuple[Experiment, ...] = (EXPERIMENTS[0], EXPERIMENTS[3])

#: Starts of the identification (SVF poles in rad/s; None = tfest's own choice from the data).
SVF_LAMBDAS: tuple[float | None, ...] = (None, 1.0, 10.0, 100.0)

#: Longest input delay the experiments estimate (s): a 20 ms servo frame plus a few ms.
MAX_SERVO_DELAY_S = 0.05

#: Run index of the validation record (the experiments use their Table-1 position - 1).
VALIDATION_RUN = len(EXPERIMENTS)


def validation_reference(hold_s: float = 60.0, dt_s: float = 1e-3) -> Reference:
    """The direct-response validation profile (the paper's Figure 9 / Table 2).

    1 s at 92 deg (open), grip step to 21 deg, ``hold_s`` at 21, un-grip step to 92, ``hold_s``
    at 92. The paper does not publish its profile; 60 s holds bring TF test1's SD near the
    paper's (``gripper_env.paper``, section 2).

    Parameters
    ----------
    hold_s : float
        Length of each hold after a step (s).
    dt_s : float
        Sample interval (s).
    """
    ref = step_profile(dt_s=dt_s, hold_s=1.0, grip_s=hold_s, ungrip_s=hold_s)
    return dataclasses.replace(ref, name="validation")


# ----------------------------------------------------------------------------------------------
# Recording


#: ``recorder(reference, path, run) -> path``: run ``reference`` open loop and write its log as CSV
#: ``t_s, desired_deg, actual_deg`` to ``path``. ``run`` numbers the runs of a session (the
#: simulated gripper derives its noise seed from it; a device ignores it).
Recorder = Callable[[Reference, Path, int], Path]


def write_log(
    path: str | os.PathLike[str],
    t_s: np.ndarray,
    desired_deg: np.ndarray,
    actual_deg: np.ndarray,
) -> Path:
    """Write an identification log (CSV ``t_s, desired_deg, actual_deg``), atomically.

    Values are written with 6 decimals (1 us, 1e-6 deg), far below the sensor's resolution.
    """
    return write_csv(path, LOG_COLUMNS, np.column_stack([t_s, desired_deg, actual_deg]))


@dataclass
class SimulatedRecorder:
    """The simulated actual gripper as a :data:`Recorder`: ``plant`` behind ``disturbance``.

    Each run is an open-loop :func:`gripper_env.sim.simulate` from rest at the profile's
    first angle; the log holds the desired angle and the *measured* angle (sensor noise and ADC
    included), as a board would report them. The disturbance parameters are the preset's nominal
    values (one gripper for the whole session); run ``k`` draws its noise from seed ``seed + k``.

    Parameters
    ----------
    plant : str, path or Plant
        The gripper's true transfer function (``"test2"``).
    disturbance : str, path, mapping or Disturbance
        Preset of the actual-gripper blocks (``"actual"``; ``"ideal"`` is the TF alone).
    seed : int
        Base noise seed.
    """

    plant: str | os.PathLike[str] | Plant = "test2"
    disturbance: str | os.PathLike[str] | Mapping[str, Any] | Disturbance = "actual"
    seed: int = 0

    def __post_init__(self) -> None:
        self.plant = load_plant(self.plant)
        self.disturbance = load_disturbance(self.disturbance)

    def __call__(self, reference: Reference, path: Path, run: int = 0) -> Path:
        traj = simulate(
            self.plant,
            reference,
            gains=None,
            disturbance=self.disturbance,
            seeds=self.seed + run,
        )
        return write_log(path, traj.t, traj.r[0], traj.y[0])

    def describe(self) -> str:
        """What stands in for the gripper, for reports."""
        assert isinstance(self.plant, Plant) and isinstance(self.disturbance, Disturbance)
        return (
            f"simulated: plant {self.plant.name} behind the `{self.disturbance.name}` preset "
            f"(nominal values), noise seeds {self.seed} + run index\n" + describe(self.disturbance)
        )


class RecordingGaps(DeviceError):
    """Every run of a recording had samples missing: telemetry frames lost on the link."""


@dataclass
class DeviceRecorder:
    """The board as a :data:`Recorder`: each run streams the profile open loop through
    :func:`gripper_env.hardware.host.experiment.run_profile` and logs ``t_s, desired_deg,
    actual_deg`` at 1 kHz (``python -m tuners.rig.record`` is one run of it).

    The log is written as it goes under ``LOG.partial.csv`` and renamed to ``LOG.csv`` when the
    profile completes; a run that fails keeps its partial log and says where in a note on the
    exception. ``desired_deg`` is the command the board applied (the host's setpoint as the
    board saw it), ``actual_deg`` the potentiometer through the calibration.

    Parameters
    ----------
    port : str
        Serial port (or the virtual board's pty).
    calibration : path or Calibration, optional
        Calibration file, or one already read: refused if it is another board's. Default: the
        board's own, found by its device id after the handshake
        (:func:`gripper_env.hardware.host.calibration.board_calibration`).
    boot_wait_s, timeout_s : float
        Seconds to let the board boot after opening the port, and to wait for an answer.
    progress : callable, optional
        Called with a line after each run (and before each run again).
    fraction : callable, optional
        Called with the fraction of the profile done, as it runs (each host period).
    attempts : int
        Runs of the profile at most: a run that completes with samples missing
        (:meth:`~gripper_env.hardware.host.experiment.Recording.gaps`, telemetry frames lost on
        the link; identification refuses gaps) is run again, its log kept beside the log as
        ``LOG.attemptK.csv``; after the last, :class:`RecordingGaps`.
    warn : callable, optional
        Called with a line when a run is recorded again (default: ``progress``).
    calibration_source : str, optional
        What named the calibration, for a refusal (``"--calibration cal.json"``).
    """

    port: str
    calibration: str | os.PathLike[str] | Calibration | None = None
    boot_wait_s: float = 2.0
    timeout_s: float = 0.5
    progress: Callable[[str], None] | None = None
    fraction: Callable[[float], None] | None = None
    attempts: int = 3
    warn: Callable[[str], None] | None = None
    calibration_source: str | None = None

    def __post_init__(self) -> None:
        if self.attempts < 1:
            raise ValueError(f"attempts must be at least 1, got {self.attempts}")

    def __call__(self, reference: Reference, path: Path, run: int = 0) -> Path:
        self.record(reference, path)
        return Path(path)

    def record(self, reference: Reference, path: str | os.PathLike[str]) -> Recording:
        """Run ``reference`` open loop on the board, logging to ``path``; again while a run
        has samples missing, up to :attr:`attempts` runs.

        Returns
        -------
        Recording
            The samples, frames lost and where the log is (``extra["log"]``).

        Raises
        ------
        RecordingGaps
            Every run had samples missing (the last one's log is at ``path``).
        """
        path = Path(path)
        for attempt in range(1, self.attempts + 1):
            rec = self._run(reference, path)
            gaps = rec.gaps()
            if not gaps:
                return rec
            at_s, worst = max(gaps, key=lambda g: g[1])
            what = (f"{sum(n for _, n in gaps)} samples missing from the record ({len(gaps)} "
                    f"gaps, the longest {worst} samples at {at_s:.3f} s: frames lost on the "
                    "link)")  # fmt: skip
            if attempt == self.attempts:
                raise RecordingGaps(
                    f"{what} in each of {attempt} runs; the last one is {rec.extra['log']} "
                    "(identification refuses gaps beyond its --max-gap)"
                )
            kept = path.with_name(f"{path.stem}.attempt{attempt}{path.suffix}")
            os.replace(str(rec.extra["log"]), kept)
            warn = self.warn or self.progress
            if warn is not None:
                warn(f"warning: {what}; that run is kept as {kept}; recording again (run "
                     f"{attempt + 1} of at most {self.attempts})")  # fmt: skip
        raise AssertionError("unreachable")  # the loop returns or raises

    def _run(self, reference: Reference, path: Path) -> Recording:
        """One run of the profile."""
        from gripper_env.hardware.host.calibration import (
            Calibration,
            board_calibration,
            load_calibration,
        )
        from gripper_env.hardware.host.device import GripperDevice
        from gripper_env.hardware.host.experiment import CsvLog, run_profile
        from gripper_env.hardware.protocol import Mode

        given = self.calibration
        source = self.calibration_source or f"calibration {given}"
        if given is not None and not isinstance(given, Calibration):
            given = load_calibration(given)
        log = CsvLog(path, LOG_COLUMNS, _log_rows)
        with GripperDevice(
            self.port, boot_wait_s=self.boot_wait_s, timeout_s=self.timeout_s
        ) as device:
            device_id = device.info.device_id if device.info else None
            # the board's own calibration, or the given one if it is this board's: before the
            # first CONFIGURE, so a refusal leaves the board as it was
            device.configure(calibration=board_calibration(device_id, self.port, given, source))
            rec = run_profile(device, reference, Mode.OPEN_LOOP, log=log, progress=self.fraction)
        if self.progress is not None:
            self.progress(
                f"recorded {reference.name} on {self.port}: {len(rec.samples)} samples, "
                f"{rec.frames_lost} frames lost"
            )
        return rec

    def describe(self) -> str:
        """What is recorded, for reports."""
        return f"the board at {self.port}"


def _log_rows(block: Any, t0_us: int) -> np.ndarray:
    """Log rows ``t_s, desired_deg, actual_deg`` of a telemetry block."""
    return np.column_stack([(block.t_us - t0_us) / 1e6, block.reference_deg, block.position_deg])


# ----------------------------------------------------------------------------------------------
# Identification


def step_t63(num: ArrayLike, den: ArrayLike, dt_s: float = 1e-3, horizon_s: float = 60.0) -> float:
    """Time for the unit step response to first cover 63.2 % of the commanded move (s).

    A summary of speed that holds for any structure (real, complex or non-minimum-phase
    poles and zeros, almost-cancelling pairs) and does not lean on the infinite-time DC gain:
    ``0.1 s`` for a 10 rad/s first-order lag. ``inf`` if not reached within ``horizon_s``.
    """
    y = zoh_response(num, den, np.ones(round(horizon_s / dt_s)), dt_s)
    hit = np.flatnonzero(y >= 1.0 - np.exp(-1.0))
    return float(hit[0] * dt_s) if hit.size else float("inf")


@dataclass(frozen=True)
class IdentifiedExperiment:
    """One recorded and identified experiment.

    Attributes
    ----------
    experiment : Experiment
        The Table-1 row.
    log_path : Path
        The CSV record.
    t_s, desired_deg, actual_deg : ndarray
        The record as read back (uniform grid).
    estimate : TFEstimate
        The identified model (deviations from the initial rest point).
    """

    experiment: Experiment
    log_path: Path
    t_s: np.ndarray = field(repr=False)
    desired_deg: np.ndarray = field(repr=False)
    actual_deg: np.ndarray = field(repr=False)
    estimate: TFEstimate

    @property
    def dc_gain(self) -> float:
        """``G(0)`` of the estimate (deg/deg)."""
        num, den = self.estimate.num, self.estimate.den
        return float(num[-1] / den[-1]) if den[-1] != 0 else float("inf")

    @property
    def fast_pole(self) -> float:
        """Real part of the fastest pole (rad/s, negative when stable)."""
        return float(np.min(self.estimate.poles.real))

    @property
    def t63_s(self) -> float:
        """:func:`step_t63` of the estimate (s)."""
        return step_t63(self.estimate.num, self.estimate.den, self.estimate.dt_s)

    def plant(self, name: str | None = None) -> Plant:
        """The estimate as a :class:`~gripper_env.model.plants.Plant` (absolute angles, as plant
        files
        are used)."""
        est = self.estimate
        return Plant.from_coefficients(
            list(est.num),
            list(est.den),
            name=name or f"ident_{self.experiment.label}",
            fit_pct=round(float(est.fit_pct), 2),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary."""
        est = self.estimate
        return {
            "test": self.experiment.name,
            "profile": self.experiment.profile,
            "description": self.experiment.description,
            "log": str(self.log_path),
            "n_samples": int(self.t_s.size),
            "duration_s": float(self.t_s[-1] - self.t_s[0]),
            "tf": est.paper_form(),
            "num": [float(c) for c in est.num],
            "den": [float(c) for c in est.den],
            "fit_pct": float(est.fit_pct),
            "fit_pct_rest": float(est.fit_pct_rest),
            "input_delay_s": float(est.input_delay_s),
            "poles": [[float(p.real), float(p.imag)] for p in est.poles],
            "zeros": [[float(z.real), float(z.imag)] for z in est.zeros],
            "dc_gain": self.dc_gain,
            "t63_s": self.t63_s,
            "stable": bool(est.stable),
            "u_op": float(est.u_op),
            "y_op": float(est.y_op),
            "residual_rms_deg": float(np.sqrt(np.mean(est.residuals**2))),
            "converged": bool(est.converged),
        }


def identify_log(
    path: str | os.PathLike[str],
    experiment: Experiment,
    n_poles: int = 2,
    n_zeros: int = 1,
    svf_lambdas: Sequence[float | None] = SVF_LAMBDAS,
    input_delay_s: float | str = 0.0,
    max_delay_s: float = MAX_SERVO_DELAY_S,
) -> IdentifiedExperiment:
    """Read a log and identify it like the paper (continuous-time TF, initial state estimated).

    :func:`~gripper_env.sysid.tfest` starts once per entry of ``svf_lambdas`` and keeps the
    best, like MATLAB's ``tfest`` with ``InitializeMethod = 'all'``. One
    start is not enough on friction data: the output-error cost is flat there, and on a slope
    record of the simulated actual gripper the data-chosen start ends in a non-minimum-phase
    local optimum that a 1 rad/s start beats.

    Parameters
    ----------
    path : str or PathLike
        CSV log (``t_s, desired_deg, actual_deg``).
    experiment : Experiment
        Which Table-1 experiment it records.
    n_poles, n_zeros : int
        Model structure (the paper's: 2 poles, 1 zero).
    svf_lambdas : sequence of float or None
        Poles of the state-variable filter of each start (rad/s); ``None`` lets ``tfest`` choose.
    input_delay_s : float or "estimate"
        Input delay of the model (s), or ``"estimate"``. Default 0, the paper's structure: on
        the slope records the friction's lag poses as dead time (a 20 s slope's model then
        hits any bound on the delay and fits the validation record 10 points worse); the
        delay is identified with the friction instead (:mod:`gripper_env.sysid.greybox`).
    max_delay_s : float
        Longest delay estimated (s): a hobby servo's, :data:`MAX_SERVO_DELAY_S`.
    """
    if not svf_lambdas:
        raise ValueError("svf_lambdas needs at least one start")
    t_raw, u_raw, y_raw = read_log(path)
    with warnings.catch_warnings(record=True):
        # the paper's structure has the slow near-cancelling pair the diagnostics point out;
        # the estimate keeps them in est.warnings for the report
        warnings.simplefilter("always")
        est = tfest(t_raw, u_raw, y_raw, n_poles, n_zeros, input_delay_s=input_delay_s,
                    max_delay_s=max_delay_s, svf_lambda_rad_s=list(svf_lambdas))  # fmt: skip
    grid = prepare_data(t_raw, u_raw, y_raw, offset="none")
    return IdentifiedExperiment(experiment, Path(path), grid.t_s, grid.u, grid.y, est)


def write_reference_csv(reference: Reference, path: str | os.PathLike[str]) -> Path:
    """Write a profile as CSV ``t_s, desired_deg`` (what ``load_reference`` and the board's
    recorder read), atomically."""
    data = np.column_stack([reference.t_s, reference.values_deg])
    return write_csv(path, ("t_s", "desired_deg"), data)
