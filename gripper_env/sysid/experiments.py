"""The paper's identification experiments end to end: record, identify, validate.

1. **Record** each Table-1 experiment open loop (the desired angle is the servo command):

   ======  =========  ==================================================
   test    profile    input (desired), grip and un-grip
   ======  =========  ==================================================
   test1   ``step``     step response
   test2   ``slope60``  slope, 60 s ramps
   test3   ``slope40``  slope, 40 s ramps
   test4   ``slope20``  slope, 20 s ramps
   ======  =========  ==================================================

   (profiles of :mod:`gripper_env.references`). A *recorder* runs one profile and writes its log
   as CSV ``t_s, desired_deg, actual_deg``; two implementations exist: the simulated actual
   gripper (:class:`SimulatedRecorder`, here) and the board (``tuners.identify``, through
   ``tuners.record``). Everything downstream reads the CSV, so
   ``python -m gripper_env.sysid LOG.csv`` reproduces each fit.
2. **Identify** each record with :func:`gripper_env.sysid.tfest` (2 poles, 1 zero: the paper's
   structure), initial state estimated.
3. **Validate** as the paper's stage 1 (Table 2): drive every identified model and the actual
   gripper with one validation profile (:func:`validation_reference`), and compare the sample SD of
   each response with the actual one's (the SD gap; the paper picks the smallest) and the fit % of
   each model to the actual response.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gripper_env import paper
from gripper_env.disturbances import Disturbance, describe, load_disturbance
from gripper_env.metrics import fit_percent, sample_sd
from gripper_env.plants import Plant, load_plant
from gripper_env.references import Reference, load_reference, step_profile
from gripper_env.simulation import simulate
from gripper_env.sysid.logfile import LOG_COLUMNS, read_log
from gripper_env.sysid.plant_file import plant_dict
from gripper_env.sysid.tfest import TFEstimate, tfest
from gripper_env.sysid.zoh import zoh_response

__all__ = [
    "EXPERIMENTS",
    "QUICK_EXPERIMENTS",
    "SVF_LAMBDAS",
    "Experiment",
    "IdentificationRun",
    "IdentifiedExperiment",
    "Recorder",
    "SimulatedRecorder",
    "Validation",
    "ValidationRow",
    "atomic_write_text",
    "identify_log",
    "run_identification",
    "save_plants",
    "step_t63",
    "validate_models",
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
        Reference profile name (:func:`gripper_env.references.load_reference`).
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

#: Run index of the validation record (the experiments use their Table-1 position - 1).
VALIDATION_RUN = len(EXPERIMENTS)


def validation_reference(hold_s: float = 60.0, dt_s: float = 1e-3) -> Reference:
    """The direct-response validation profile (the paper's Figure 9 / Table 2).

    1 s at 92 deg (open), grip step to 21 deg, ``hold_s`` at 21, un-grip step to 92, ``hold_s``
    at 92. The paper does not publish its profile; 60 s holds bring TF test1's SD near the
    paper's (``tuners.reproduce``, section 2).

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


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file and :func:`os.replace`."""
    p = Path(path)
    tmp = _temp_path(p)
    try:
        with tmp.open("w", encoding="utf-8", newline="") as fh:
            fh.write(text)
        os.replace(tmp, p)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return p


def _temp_path(path: Path) -> Path:
    """A temporary name beside ``path`` (same file system, so :func:`os.replace` is atomic)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def write_log(
    path: str | os.PathLike[str],
    t_s: np.ndarray,
    desired_deg: np.ndarray,
    actual_deg: np.ndarray,
) -> Path:
    """Write an identification log (CSV ``t_s, desired_deg, actual_deg``), atomically.

    Values are written with 6 decimals (1 us, 1e-6 deg), far below the sensor's resolution.
    """
    p = Path(path)
    tmp = _temp_path(p)
    try:
        with tmp.open("w", encoding="utf-8", newline="") as fh:
            np.savetxt(
                fh,
                np.column_stack([t_s, desired_deg, actual_deg]),
                delimiter=",",
                header=",".join(LOG_COLUMNS),
                comments="",
                fmt="%.6f",
            )
        os.replace(tmp, p)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return p


@dataclass
class SimulatedRecorder:
    """The simulated actual gripper as a :data:`Recorder`: ``plant`` behind ``disturbance``.

    Each run is an open-loop :func:`gripper_env.simulation.simulate` from rest at the profile's
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


# ----------------------------------------------------------------------------------------------
# Identification


def step_t63(
    num: Sequence[float], den: Sequence[float], dt_s: float = 1e-3, horizon_s: float = 60.0
) -> float:
    """Time for the unit step response to first cover 63.2 % of the commanded move (s).

    A summary of speed that holds for any structure (real, complex or non-minimum-phase
    poles and zeros, almost-cancelling pairs) and does not lean on the infinite-time DC gain:
    ``0.1 s`` for a 10 rad/s first-order lag. ``inf`` if not reached within ``horizon_s``.
    """
    y = zoh_response(num, den, np.ones(round(horizon_s / dt_s)), dt_s)
    hit = np.flatnonzero(y >= 1.0 - np.exp(-1.0))
    return float(hit[0] * dt_s) if hit.size else float("inf")


def _uniform(
    t: np.ndarray, u: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample a log onto a uniform grid at its median interval (a no-op when it is uniform)."""
    dt = float(np.median(np.diff(t)))
    if np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9):
        return t, u, y
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
    return grid, np.interp(grid, t, u), np.interp(grid, t, y)


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
        """The estimate as a :class:`~gripper_env.plants.Plant` (absolute angles, as plant files
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
            "fit_pct_zero_ic": float(est.fit_pct_zero_ic),
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
) -> IdentifiedExperiment:
    """Read a log and identify it like the paper (continuous-time TF, initial state estimated).

    :func:`~gripper_env.sysid.tfest` runs once per start in ``svf_lambdas`` and the estimate
    with the best fit is kept, like MATLAB's ``tfest`` with ``InitializeMethod = 'all'``. One
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
    """
    if not svf_lambdas:
        raise ValueError("svf_lambdas needs at least one start")
    t, u, y = _uniform(*read_log(path))
    best: TFEstimate | None = None
    for lam in svf_lambdas:
        est = tfest(t, u, y, n_poles, n_zeros, svf_lambda_rad_s=lam)
        if best is None or est.fit_pct > best.fit_pct:
            best = est
    assert best is not None
    return IdentifiedExperiment(experiment, Path(path), t, u, y, best)


# ----------------------------------------------------------------------------------------------
# Validation (stage 1: direct response)


@dataclass(frozen=True)
class ValidationRow:
    """One model's direct response against the actual one.

    Attributes
    ----------
    name : str
        ``"test1"`` ...
    sd_deg : float
        Sample SD of the model's response over the run (deg, ``ddof=1``).
    sd_gap_deg : float
        ``SD_actual - SD_model`` (deg), the paper's Table-2 column (signed).
    fit_pct : float
        MATLAB ``compare`` fit (%) of the model's response to the actual measured one.
    fit_pct_plant : float
        The same for the model used as a plant file (absolute angles from quasi-rest at the
        first angle, the ``ideal`` preset); NaN when not computed.
    stable : bool
        All poles in the open left half plane.
    """

    name: str
    sd_deg: float
    sd_gap_deg: float
    fit_pct: float
    fit_pct_plant: float = float("nan")
    stable: bool = True

    @property
    def abs_sd_gap_deg(self) -> float:
        """``|SD_actual - SD_model|`` (deg)."""
        return abs(self.sd_gap_deg)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "sd_deg": self.sd_deg,
            "sd_gap_deg": self.sd_gap_deg,
            "abs_sd_gap_deg": self.abs_sd_gap_deg,
            "fit_pct": self.fit_pct,
            "fit_pct_plant": None if np.isnan(self.fit_pct_plant) else self.fit_pct_plant,
            "stable": self.stable,
        }


@dataclass(frozen=True)
class Validation:
    """The direct-response validation (the paper's Table 2, Figure 9).

    Attributes
    ----------
    log_path : Path
        CSV record of the actual gripper's run.
    t_s, desired_deg, actual_deg : ndarray
        That record (uniform grid).
    responses : dict of str to ndarray
        Each identified model's response (as identified: at rest at its operating point).
    rows : tuple of ValidationRow
        Our identified models, in Table-1 order.
    paper_rows : tuple of ValidationRow
        The paper's four transfer functions on the same run (absolute angles, ``ideal`` preset,
        as ``tuners.reproduce`` drives them).
    """

    log_path: Path
    t_s: np.ndarray = field(repr=False)
    desired_deg: np.ndarray = field(repr=False)
    actual_deg: np.ndarray = field(repr=False)
    responses: dict[str, np.ndarray] = field(repr=False)
    rows: tuple[ValidationRow, ...]
    paper_rows: tuple[ValidationRow, ...]

    @property
    def sd_actual_deg(self) -> float:
        """Sample SD of the actual measured response (deg)."""
        return float(sample_sd(self.actual_deg))

    @property
    def best_by_sd_gap(self) -> str:
        """The paper's choice: the model with the smallest ``|SD_actual - SD_model|``."""
        return min(self.rows, key=lambda r: r.abs_sd_gap_deg).name

    @property
    def best_by_fit(self) -> str:
        """The model whose response fits the actual one best (fit %)."""
        return max(self.rows, key=lambda r: r.fit_pct).name

    @property
    def criteria_agree(self) -> bool:
        """Whether the SD-gap and fit-% choices are the same model."""
        return self.best_by_sd_gap == self.best_by_fit

    def to_dict(self) -> dict[str, Any]:
        return {
            "log": str(self.log_path),
            "duration_s": float(self.t_s[-1] - self.t_s[0]),
            "sd_actual_deg": self.sd_actual_deg,
            "rows": [r.to_dict() for r in self.rows],
            "paper_rows": [r.to_dict() for r in self.paper_rows],
            "best_by_sd_gap": self.best_by_sd_gap,
            "best_by_fit": self.best_by_fit,
            "criteria_agree": self.criteria_agree,
        }


def _plant_response(plant: Plant, u: np.ndarray, dt_s: float) -> np.ndarray:
    if not np.isclose(plant.dt_s, dt_s):
        plant = dataclasses.replace(plant, dt_s=dt_s)
    return simulate(plant, u, gains=None, disturbance="ideal").y_true[0]


def _row(name: str, y_actual: np.ndarray, y_model: np.ndarray, **extra: Any) -> ValidationRow:
    sd = float(sample_sd(y_model))
    return ValidationRow(
        name=name,
        sd_deg=sd,
        sd_gap_deg=float(sample_sd(y_actual)) - sd,
        fit_pct=float(fit_percent(y_actual, y_model)),
        **extra,
    )


def validate_models(
    identified: Sequence[IdentifiedExperiment], log_path: str | os.PathLike[str]
) -> Validation:
    """Compare each identified model with the actual gripper's validation record.

    Each model is driven by the record's desired angle *as identified*: at rest at its
    operating point, ``y_op + G(s) (u - u_op)`` (:meth:`TFEstimate.simulate` with a zero initial
    state). The fit of the same model used as a plant file (absolute angles, as every other
    command uses it) is reported beside it, and so are the paper's transfer functions.

    Parameters
    ----------
    identified : sequence of IdentifiedExperiment
        The models.
    log_path : str or PathLike
        The actual gripper's validation record (CSV).
    """
    t, u, y = _uniform(*read_log(log_path))
    dt = float(t[1] - t[0])
    responses: dict[str, np.ndarray] = {}
    rows = []
    for item in identified:
        est = item.estimate
        # the model on the validation grid (the log's interval may differ from the record's)
        est_v = dataclasses.replace(est, dt_s=dt)
        y_model = est_v.simulate(u, np.zeros_like(est.initial_state))
        responses[item.experiment.name] = y_model
        y_plant = _plant_response(item.plant(), u, dt)
        rows.append(
            _row(
                item.experiment.name,
                y,
                y_model,
                fit_pct_plant=float(fit_percent(y, y_plant)),
                stable=bool(est.stable),
            )
        )
    paper_rows = []
    for name in paper.PLANTS:
        y_paper = _plant_response(load_plant(name), u, dt)
        paper_rows.append(_row(name, y, y_paper, stable=load_plant(name).is_stable))
    return Validation(Path(log_path), t, u, y, responses, tuple(rows), tuple(paper_rows))


# ----------------------------------------------------------------------------------------------
# The session


@dataclass(frozen=True)
class IdentificationRun:
    """A whole session: every experiment identified, then validated.

    Attributes
    ----------
    experiments : tuple of IdentifiedExperiment
        In Table-1 order.
    validation : Validation
        Stage 1 (Table 2).
    source : str
        What was recorded (the simulated gripper's description, or the device).
    """

    experiments: tuple[IdentifiedExperiment, ...]
    validation: Validation
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "experiments": [e.to_dict() for e in self.experiments],
            "validation": self.validation.to_dict(),
        }


def run_identification(
    recorder: Recorder,
    log_dir: str | os.PathLike[str],
    experiments: Sequence[Experiment] = EXPERIMENTS,
    validation: Reference | None = None,
    source: str = "",
    progress: Callable[[str], None] | None = None,
    svf_lambdas: Sequence[float | None] = SVF_LAMBDAS,
) -> IdentificationRun:
    """Record and identify every experiment, then record and run the validation.

    Parameters
    ----------
    recorder : Recorder
        Runs a profile open loop and writes its CSV log.
    log_dir : str or PathLike
        Folder of the logs: ``<test>_<profile>.csv`` per experiment and ``validation.csv``.
    experiments : sequence of Experiment
        Which Table-1 experiments (default: all four).
    validation : Reference, optional
        Validation profile; default :func:`validation_reference`.
    source : str
        Description of what ``recorder`` records, kept in the result.
    progress : callable, optional
        Called with a short message after each step.
    svf_lambdas : sequence of float or None
        Starts of each identification (:func:`identify_log`).
    """
    log_dir = Path(log_dir)
    say = progress or (lambda _msg: None)
    done = []
    for exp in experiments:
        ref = load_reference(exp.profile)
        path = recorder(ref, log_dir / f"{exp.label}.csv", exp.number - 1)
        item = identify_log(path, exp, svf_lambdas=svf_lambdas)
        est = item.estimate
        say(f"{exp.name} ({exp.profile}): {est.paper_form()}, fit {est.fit_pct:.2f} %")
        done.append(item)
    ref = validation if validation is not None else validation_reference()
    path = recorder(ref, log_dir / "validation.csv", VALIDATION_RUN)
    val = validate_models(done, path)
    say(
        f"validation: SD actual {val.sd_actual_deg:.3f} deg; best by SD gap "
        f"{val.best_by_sd_gap}, best by fit {val.best_by_fit}"
    )
    return IdentificationRun(tuple(done), val, source)


def save_plants(
    run: IdentificationRun, folder: str | os.PathLike[str], source: str = ""
) -> list[Path]:
    """Write each identified model as a plant file ``ident_<test>_<profile>.yaml``, atomically.

    The files load with :func:`gripper_env.plants.load_plant` (by path) like the paper's plants.
    """
    out = []
    for item in run.experiments:
        name = f"ident_{item.experiment.label}"
        est = item.estimate
        description = (
            f"Identified by python -m tuners.identify from {item.experiment.name} "
            f"({item.experiment.description}){', ' + source if source else ''}: "
            f"{est.residuals.size} samples at {est.dt_s:g} s, fit {est.fit_pct:.2f} % (initial "
            f"state estimated), {est.fit_pct_zero_ic:.2f} % (zero initial state); identified "
            f"about the operating point u_op={est.u_op:.4g} deg, y_op={est.y_op:.4g} deg."
        )
        doc = plant_dict(est, name, description)
        text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
        out.append(atomic_write_text(Path(folder) / f"{name}.yaml", text))
    return out


def write_reference_csv(reference: Reference, path: str | os.PathLike[str]) -> Path:
    """Write a profile as CSV ``t_s, desired_deg`` (what ``load_reference`` and the board's
    recorder read), atomically."""
    data = np.column_stack([reference.t_s, reference.values_deg])
    lines = ["t_s,desired_deg", *(f"{t:.6f},{v:.6f}" for t, v in data)]
    return atomic_write_text(path, "\n".join(lines) + "\n")
