"""The exported servo verified in MuJoCo: the recipe's goal profiles run in the simulation core,
the native class, the exact runtime and a Menagerie-style class, each against the virtual
servo's truth; and a ``mujoco.sysid`` fit of MuJoCo's position actuator on the same records.

The **truth** is the virtual servo: the family's shipped model run in the simulation core, as
:class:`~gripper_env.hardware.bus.unit.ServoUnit` runs it behind the pseudo-terminal. The
**identified** model is what ``python -m tuners.bus.identify`` fitted to records of it. The
profiles (:func:`recipe_profiles`) are the recipe's: the record's steps of 30, 10 and 4 deg and
its creep (a slope of one tick per 20 ms), and the tuner's tracking steps of 4 to 44 deg. The
measure is the RMS difference (deg) between a place's response and the truth's, at every 1 ms
tick, from rest at the profile's first goal.

Places (:func:`compare_places`):

* ``core``: the identified model in the simulation core;
* ``native``: the identified model's native class (kp and kv fitted to the core's register
  loop), in MuJoCo;
* ``exact``: the identified model's register loop in MuJoCo (:class:`ExactServo`);
* ``menagerie``: MuJoCo Menagerie's hand-set STS3215 class
  (:data:`~gripper_env.mujoco.servo_class.MENAGERIE_STS3215`); for another family the same
  class with every torque scaled by the ratio of the stall torques (its dynamics kept), the
  way a user would carry it over.

:func:`sysid_position_fit` fits MuJoCo's own position actuator to a record with
``mujoco.sysid`` (MuJoCo 4's ``sysid`` extra: Gauss-Newton on the rollout's error), as MuJoCo
Playground's SO-101 identification does: armature, frictionloss, stiffness (the actuator's kp),
damping, and the command's delay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from gripper_env.model.bus_servo import BusServoModel, RegisterSet
from gripper_env.mujoco import require_mujoco
from gripper_env.mujoco.runtime import ExactServo
from gripper_env.mujoco.servo_class import (
    MENAGERIE_STS3215,
    NativeServo,
    fill_history,
    fit_native_gains,
    rollout_native,
    servo_mjcf,
)
from gripper_env.sim.bus_servo import DT, simulate_bus
from gripper_env.sysid.bus_experiments import record_plan, tracking_plan
from gripper_env.sysid.bus_servo import BusRecord

__all__ = [
    "CHANGED_SETTINGS",
    "PLACES",
    "PositionFit",
    "VerifyResult",
    "compare_places",
    "menagerie_style",
    "recipe_profiles",
    "rms_deg",
    "run_exact",
    "sysid_position_fit",
    "verify_family",
]

#: The places a profile runs in, in the table's order.
PLACES: tuple[str, ...] = ("core", "native", "exact", "menagerie")


def recipe_profiles(model: BusServoModel) -> dict[str, np.ndarray]:
    """The recipe's goal profiles on ``model``'s jaw, per 1 ms tick (deg): ``"record"`` (steps
    of 30, 10, 4 deg and the creep) and ``"tracking"`` (steps of 4 to 44 deg)."""
    return {
        "record": record_plan(model).per_tick(),
        "tracking": tracking_plan(model).per_tick(),
    }


def rms_deg(a: np.ndarray, b: np.ndarray) -> float:
    """RMS of ``a - b`` (deg)."""
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def menagerie_style(model: BusServoModel) -> NativeServo:
    """Menagerie's hand-set STS3215 class, for another family scaled by its stall torque over
    Menagerie's 2.94 N m (kp, kv, forcerange, damping, frictionloss and armature alike), and
    without a delay."""
    if model.family == "sts3215":
        return MENAGERIE_STS3215
    k = model.physics.stall_torque_nm / MENAGERIE_STS3215.forcerange
    m = MENAGERIE_STS3215
    return NativeServo(
        armature=m.armature * k,
        damping=m.damping * k,
        frictionloss=m.frictionloss * k,
        forcerange=m.forcerange * k,
        kp=m.kp * k,
        kv=m.kv * k,
    )


def run_exact(model: BusServoModel, registers: RegisterSet, goal_deg: np.ndarray) -> np.ndarray:
    """The exact runtime's one-joint model (:func:`servo_mjcf` ``"exact"``) driven by
    ``goal_deg`` (deg per tick) from rest at its first goal: the encoder's readings (deg)."""
    mujoco = require_mujoco()
    m = mujoco.MjModel.from_xml_string(servo_mjcf(model, registers, "exact"))
    d = mujoco.MjData(m)
    d.qpos[0] = math.radians(float(goal_deg[0]))
    mujoco.mj_forward(m, d)
    servo = ExactServo(m, d, model, registers)
    return servo.run(goal_deg) * model.deg_per_tick


def run_core(model: BusServoModel, registers: RegisterSet, goal_deg: np.ndarray) -> np.ndarray:
    """The simulation core's encoder readings (deg) for ``goal_deg`` from rest."""
    return simulate_bus(model, registers, goal_deg).position[0] * model.deg_per_tick


@dataclass(frozen=True)
class PlaceResult:
    """One place's RMS error against the truth per profile (deg), and what it ran."""

    place: str
    rms_deg: dict[str, float]
    native: NativeServo | None = None

    def mean(self) -> float:
        """The RMS over every profile's ticks together (deg)."""
        return float(np.mean(list(self.rms_deg.values())))


def compare_places(
    truth: BusServoModel,
    identified: BusServoModel,
    registers: RegisterSet,
    *,
    native: NativeServo | None = None,
) -> dict[str, PlaceResult]:
    """Each place's RMS error against the truth on the recipe's profiles (see the module).

    ``native`` skips the kp/kv fit (a class fitted before, e.g. at other registers: then the
    row shows what a continuous class keeps when the registers change)."""
    goals = recipe_profiles(truth)
    truths = {k: run_core(truth, registers, g) for k, g in goals.items()}
    core_runs = {k: run_core(identified, registers, g) for k, g in goals.items()}
    if native is None:
        native = fit_native_gains(
            identified, registers, list(goals.values()), list(core_runs.values())
        )
    native_runs = dict(
        zip(goals, rollout_native(native, identified, list(goals.values())), strict=True)
    )
    menagerie = menagerie_style(truth)
    men_runs = dict(zip(goals, rollout_native(menagerie, truth, list(goals.values())), strict=True))
    exact_runs = {k: run_exact(identified, registers, g) for k, g in goals.items()}
    runs = {"core": core_runs, "native": native_runs, "exact": exact_runs, "menagerie": men_runs}
    out = {}
    for place, per in runs.items():
        err = {k: rms_deg(per[k], truths[k]) for k in goals}
        out[place] = PlaceResult(
            place, err, native if place == "native" else menagerie if place == "menagerie" else None
        )
    return out


@dataclass(frozen=True)
class PositionFit:
    """MuJoCo's position actuator fitted by ``mujoco.sysid`` (see :func:`sysid_position_fit`).

    Attributes
    ----------
    servo : NativeServo
        The fitted class (forcerange kept at the record's torque limit).
    cost : float
        The fit's final cost (``mujoco.sysid``'s, half the sum of squared normalised
        residuals).
    iterations : int
        Gauss-Newton iterations taken.
    """

    servo: NativeServo
    cost: float
    iterations: int


def sysid_position_fit(
    model: BusServoModel, record: BusRecord, *, max_iters: int = 60, x_scale: Any = None
) -> PositionFit:
    """Fit MuJoCo's position actuator to ``record`` with ``mujoco.sysid``: armature,
    frictionloss, stiffness (kp), damping and the command's delay, started from the register
    mapping (:func:`~gripper_env.mujoco.servo_class.native_servo`) with the forcerange kept at
    the record's torque limit. The record's goals are the control (rad), its readings the
    measured joint position, resampled by ``mujoco.sysid`` at the rollout's steps. The
    Gauss-Newton steps are scaled by the parameters' nominal sizes (``x_scale``; unscaled, the
    fit stopped at a 1.5 times larger cost on the STS3215's record).

    Raises
    ------
    ImportError
        Without MuJoCo's ``sysid`` extra (``pip install 'mujoco[sysid]'``).
    """
    mujoco = require_mujoco()
    try:
        from mujoco import sysid
    except ImportError as exc:  # pragma: no cover - installed with the extra
        raise ImportError(
            "mujoco.sysid needs MuJoCo's sysid extra: pip install 'mujoco[sysid]'"
        ) from exc
    if not hasattr(sysid, "Parameter"):  # the package imports, its optional deps did not
        raise ImportError("mujoco.sysid needs MuJoCo's sysid extra: pip install 'mujoco[sysid]'")
    from gripper_env.mujoco.servo_class import native_servo

    start = native_servo(model, record.registers)
    # the damping is the joint's alone (Playground's parameters): no kv on the actuator
    bare = replace(start, delay_s=0.0, kv=0.0)
    xml = servo_mjcf(model, record.registers, "native", native=bare)
    xml = xml.replace("<actuator>", "<actuator>").replace(
        "</worldbody>", '</worldbody>\n  <sensor><jointpos name="angle" joint="shaft"/></sensor>'
    )
    spec = mujoco.MjSpec.from_string(xml)
    # the command's delay as a continuous parameter: MuJoCo's actuator delay, linearly
    # interpolated in its history
    act = spec.actuator("servo")
    act.nsample = 40
    act.interp = 1
    m0 = spec.compile()
    d0 = mujoco.MjData(m0)
    goal = record.goal_per_tick()
    t_ctrl = np.arange(goal.size) * DT
    d0.qpos[0] = math.radians(float(goal[0]))
    d0.ctrl[0] = d0.qpos[0]
    # at rest at the first goal, held long: the delayed actuator's history holds that goal
    # (sysid.create_initial_state would leave it at 0 rad, a kick at the start)
    fill_history(m0, d0, float(d0.qpos[0]))
    mujoco.mj_forward(m0, d0)
    initial = np.empty(mujoco.mj_stateSize(m0, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m0, d0, initial, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    control = sysid.TimeSeries(t_ctrl, np.radians(goal)[:, None])
    keep = record.t_s < t_ctrl[-1]
    sensor = sysid.TimeSeries.from_names(
        record.t_s[keep], np.radians(record.position_deg[keep])[:, None], m0
    )

    def set_joint(attr: str) -> Any:
        def modify(s: Any, p: Any) -> None:
            joint = s.joint("shaft")
            if attr == "damping":  # MuJoCo 4: a polynomial's coefficients
                joint.damping = np.array([p.value[0], 0.0, 0.0])
            else:
                setattr(joint, attr, p.value[0])

        return modify

    def set_kp(s: Any, p: Any) -> None:
        a = s.actuator("servo")
        a.gainprm[0] = p.value[0]
        a.biasprm[1] = -p.value[0]

    def set_delay(s: Any, p: Any) -> None:
        s.actuator("servo").delay = p.value[0]

    params = sysid.ParameterDict()
    specs = (
        ("armature", start.armature, set_joint("armature")),
        ("frictionloss", start.frictionloss, set_joint("frictionloss")),
        ("stiffness", start.kp, set_kp),
        ("damping", start.damping + start.kv, set_joint("damping")),
    )
    scale = []
    for name, nominal, modifier in specs:
        scale.append(nominal)
        params.add(sysid.Parameter(name, nominal=nominal, min_value=nominal / 20,
                                   max_value=nominal * 20, modifier=modifier))  # fmt: skip
    params.add(sysid.Parameter("delay", nominal=0.004, min_value=0.0, max_value=0.03,
                               modifier=set_delay))  # fmt: skip
    if x_scale is None:  # each parameter on its own scale: a better optimum than unscaled
        x_scale = np.array([*scale, 0.004])
    seq = sysid.ModelSequences("servo", spec, "record", initial, control, sensor)
    residual_fn = sysid.build_residual_fn(models_sequences=[seq], n_threads=1)
    fitted, result = sysid.optimize(
        initial_params=params, residual_fn=residual_fn, optimizer="mujoco", verbose=False,
        max_iters=max_iters, x_scale=x_scale,
    )  # fmt: skip
    v = {name: float(fitted[name].value[0]) for name in fitted.keys()}
    servo = NativeServo(
        armature=v["armature"],
        damping=v["damping"],
        frictionloss=v["frictionloss"],
        forcerange=start.forcerange,
        kp=v["stiffness"],
        kv=0.0,
        delay_s=v["delay"],
    )
    cost = float(getattr(result, "cost", math.nan))
    return PositionFit(servo=servo, cost=cost, iterations=int(getattr(result, "nfev", 0)))


def record_rms(predicted_deg: np.ndarray, record: BusRecord) -> float:
    """RMS (deg) of a prediction per 1 ms tick against a record's readings (at their times)."""
    idx = np.clip((record.t_s / DT).astype(int), 0, predicted_deg.size - 1)
    return rms_deg(predicted_deg[idx], record.position_deg)


def predictions_on_record(
    identified: BusServoModel, fit: PositionFit, record: BusRecord
) -> dict[str, np.ndarray]:
    """The exact runtime (at the record's registers) and the sysid fit (unchanged: it has no
    registers) driven by the record's goals: the angle per tick (deg)."""
    goal = record.goal_per_tick()
    exact = run_exact(identified, record.registers, goal)
    fitted = rollout_native(fit.servo, identified, [goal])[0]
    return {"exact": exact, "sysid": fitted}


#: The register setting a ``mujoco.sysid`` fit is made at (the family's factory P, I, D) and the
#: one it is then asked to carry over to, both among the identification's record settings.
FIT_SETTINGS: dict[str, tuple[int, int, int]] = {"sts3215": (32, 0, 32), "xl330": (400, 0, 0)}
CHANGED_SETTINGS: dict[str, tuple[int, int, int]] = {"sts3215": (64, 0, 32), "xl330": (800, 0, 800)}


@dataclass(frozen=True)
class VerifyResult:
    """What :func:`verify_family` measured (see it)."""

    family: str
    registers: RegisterSet
    identified: BusServoModel
    estimate: dict[str, Any]
    places: dict[str, PlaceResult]
    sysid: PositionFit
    on_records: dict[str, dict[str, float]]
    changed_registers: RegisterSet

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (the identified model whole, so that the tests can run it again)."""
        return {
            "family": self.family,
            "registers": self.registers.model_dump(),
            "identified_model": self.identified.model_dump(mode="json"),
            "identification": {
                k: self.estimate[k] for k in ("fit_pct", "rmse_deg") if k in self.estimate
            },
            "rms_deg": {k: r.rms_deg for k, r in self.places.items()},
            "native": self.places["native"].native.as_dict()
            if self.places["native"].native
            else None,
            "menagerie_style": self.places["menagerie"].native.as_dict()
            if self.places["menagerie"].native
            else None,
            "sysid_fit": self.sysid.servo.as_dict(),
            "changed_registers": self.changed_registers.model_dump(),
            "on_records_rms_deg": self.on_records,
        }


def verify_family(
    family: str,
    *,
    seed: int = 0,
    generations: int = 80,
    log: Any = None,
) -> VerifyResult:
    """The whole verification for one family (``"sts3215"`` or ``"xl330"``): records of the
    virtual servo (the shipped model, :func:`~gripper_env.sysid.bus_experiments.simulate_record`
    with the host's sampling) at the recipe's five settings, the identification from them, the
    places compared on the recipe's profiles at the factory registers, a ``mujoco.sysid`` fit of
    MuJoCo's position actuator on the record at the factory setting, and both that fit and the
    exact runtime on the record at a changed setting (the fit unchanged: it has no registers;
    the runtime with the new registers, no refit).

    ``log`` takes progress lines. A few minutes on 2 cores (the identification most of it).
    """
    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.sysid.bus_experiments import settings_registers, simulate_record
    from gripper_env.sysid.bus_servo import identify_bus_servo

    say = log or (lambda _text: None)
    truth = load_bus_servo(family)
    rng = np.random.default_rng(seed)
    settings = settings_registers(truth)
    records = [simulate_record(truth, r, rng=rng) for r in settings]
    say(f"{family}: identifying from {len(records)} records of the virtual servo")
    est = identify_bus_servo(records, truth, name=f"identified-{family}", seed=seed,
                             generations=generations, log=say)  # fmt: skip
    identified = est.model
    regs = truth.factory
    say(f"{family}: the recipe's profiles in the core, the native class, the exact runtime and "
        "the Menagerie-style class")  # fmt: skip
    places = compare_places(truth, identified, regs)
    by_pid = {(r.registers.p, r.registers.i, r.registers.d): r for r in records}
    fit_rec = by_pid[FIT_SETTINGS[family]]
    changed_rec = by_pid[CHANGED_SETTINGS[family]]
    say(f"{family}: mujoco.sysid fit of MuJoCo's position actuator on the record at "
        f"{fit_rec.registers.label()}")  # fmt: skip
    fit = sysid_position_fit(identified, fit_rec)
    on_records = {}
    for name, rec in (("fit_setting", fit_rec), ("changed_setting", changed_rec)):
        pred = predictions_on_record(identified, fit, rec)
        on_records[name] = {k: record_rms(v, rec) for k, v in pred.items()}
    return VerifyResult(
        family=family,
        registers=regs,
        identified=identified,
        estimate=est.as_dict(),
        places=places,
        sysid=fit,
        on_records=on_records,
        changed_registers=changed_rec.registers,
    )
