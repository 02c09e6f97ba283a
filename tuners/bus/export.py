"""``python -m tuners.bus.export``: an identified bus servo and a register set as MuJoCo classes.

From a model (a shipped family, an identified model file of ``python -m tuners.bus.identify``,
or a registers file of ``python -m tuners.bus.tune``, whose model and registers it takes) and
the registers (the file's, the model's factory set, or ``--p/--i/--d/--limit``), it writes to
``--out``:

* ``NAME_native.xml``: the **native** class (MuJoCo's joint and position actuator: armature,
  damping, frictionloss, forcerange, kp and kv fitted to the register loop, the delays) in a
  one-joint test model;
* ``NAME_exact.xml``: the **exact** class (the joint, and a motor whose duty the servo's register
  loop computes) in a one-joint test model, and ``NAME_exact.json``: the model and the
  registers the runtime (:class:`gripper_env.mujoco.runtime.ExactServo`) runs;

and prints the native class and what MuJoCo's stock actuators cannot hold
(:mod:`gripper_env.mujoco.servo_class`). ``--verify FAMILY`` instead runs the verification
(:func:`gripper_env.mujoco.verify.verify_family`): records of the virtual servo, the
identification, the recipe's profiles in the core, the native class, the exact runtime and a
Menagerie-style class, a ``mujoco.sysid`` fit, and writes ``FAMILY_mujoco.md``, ``.json`` and
``.png``.

Examples
--------
``python -m tuners.bus.export --model runs/bus/sts3215/my-sts3215_model.json --out runs/mujoco``
``python -m tuners.bus.export --registers runs/bus/sts3215/my-sts3215_registers.json``
``python -m tuners.bus.export --verify sts3215 --out runs/mujoco`` (a few minutes)
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gripper_env.io.files import (
    collect_provenance,
    save_figure,
    write_atomic,
    write_group,
    write_json,
)
from tuners.cli import check_output_folder
from tuners.conventions import conform

if TYPE_CHECKING:  # the library is imported after parsing
    from gripper_env.model.bus_servo import BusServoModel, RegisterSet
    from gripper_env.mujoco.verify import VerifyResult

__all__ = ["main"]

_FAMILIES = ("sts3215", "xl330")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.bus.export",
        description="Write an identified bus servo and a register set as MuJoCo classes (native "
        "and exact) with one-joint test models; or verify them against the virtual servo.",
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument(
        "--model",
        default=None,
        help="a shipped family (sts3215, xl330, xl430) or a model file (tuners.bus.identify); "
        "default sts3215",
    )
    source.add_argument(
        "--registers", type=Path, default=None,
        help="a registers file (tuners.bus.tune): its model and registers",
    )  # fmt: skip
    source.add_argument(
        "--verify",
        choices=_FAMILIES,
        default=None,
        help="verify the export for a family against its virtual servo (a few minutes)",
    )
    for reg in ("p", "i", "d", "limit"):
        what = "torque limit" if reg == "limit" else reg.upper()
        parser.add_argument(f"--{reg}", type=int, default=None,
                            help=f"the {what} register (default: the model's factory)")  # fmt: skip
    parser.add_argument("--name", default=None, help="the files' stem (default: the model's name)")
    parser.add_argument("--out", type=Path, default=Path("runs/mujoco"),
                        help="output folder (default runs/mujoco)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="--verify: the records' seed")
    parser.add_argument("--generations", type=int, default=80,
                        help="--verify: the identification's search (default 80)")  # fmt: skip
    parser.add_argument("--no-plot", action="store_true",
                        help="--verify: no figure (FAMILY_mujoco.png)")  # fmt: skip
    parser.add_argument("--no-fit", action="store_true",
                        help="native kp and kv by the register mapping alone (no fit)")  # fmt: skip
    return conform(parser, "tuners.bus.export")


def _registers(args: argparse.Namespace, model: BusServoModel, base: RegisterSet) -> RegisterSet:
    update: dict[str, int] = {}
    for key, attr in (("p", "p"), ("i", "i"), ("d", "d"), ("limit", "torque_limit")):
        value = getattr(args, key)
        if value is not None:
            if value < 0:
                raise ValueError(f"--{key} must be >= 0, got {value}")
            update[attr] = value
    return base.model_copy(update=update)


def _export(args: argparse.Namespace) -> int:
    from gripper_env.io.files import safe_name
    from gripper_env.model.bus_servo import load_bus_servo, load_registers_file
    from gripper_env.mujoco.servo_class import (
        fit_native_gains,
        native_servo,
        servo_mjcf,
    )
    from gripper_env.mujoco.verify import recipe_profiles, run_core

    if args.registers is not None:
        model, base, _doc = load_registers_file(args.registers)
    else:
        model = load_bus_servo(args.model or "sts3215")
        base = model.factory
    regs = _registers(args, model, base)
    name = safe_name(args.name or model.name, "--name")
    check_output_folder(args.out, "--out")
    if args.no_fit:
        native = native_servo(model, regs)
    else:
        print(f"fitting the native class's kp and kv to {model.name}'s register loop "
              f"({regs.label()}) on the recipe's profiles (seconds)", flush=True)  # fmt: skip
        goals = list(recipe_profiles(model).values())
        native = fit_native_gains(model, regs, goals, [run_core(model, regs, g) for g in goals])
    args.out.mkdir(parents=True, exist_ok=True)
    paths = {
        "native": args.out / f"{name}_native.xml",
        "exact": args.out / f"{name}_exact.xml",
        "runtime": args.out / f"{name}_exact.json",
    }
    write_atomic(paths["native"], servo_mjcf(model, regs, "native", native=native).encode())
    write_atomic(paths["exact"], servo_mjcf(model, regs, "exact").encode())
    write_json(paths["runtime"], {"model": model.model_dump(mode="json"),
                                  "registers": regs.model_dump(),
                                  "joint": "shaft", "actuator": "servo"})  # fmt: skip
    mapped = native_servo(model, regs)
    print(f"{model.name} ({model.family}), registers {regs.label()}")
    print("native class (MuJoCo joint + position actuator):")
    for key, value in native.as_dict().items():
        note = (
            ""
            if key not in ("kp", "kv") or args.no_fit
            else f" (mapping {getattr(mapped, key):.4g})"
        )
        print(f"  {key:<13} {value:.4g}{note}")
    print("not in the native class (MuJoCo's stock actuators cannot hold them): the 1 kHz "
          "integer loop (ticks, dead band, profile), the I term, static friction above Coulomb "
          f"({model.physics.static:.3f} vs {model.physics.coulomb:.3f} of stall), the "
          "protections, the gear's backlash; the exact class runs them (ExactServo)")  # fmt: skip
    for key, path in paths.items():
        print(f"wrote {path} ({key})")
    return 0


def format_verification(result: VerifyResult) -> str:
    """The verification's tables in markdown."""
    places = result.places
    profiles = list(places["core"].rms_deg)
    lines = [
        f"## {result.family}: RMS error against the virtual servo's truth (deg)",
        "",
        f"Registers {result.registers.label()}; identified model fit "
        f"{result.estimate.get('fit_pct', float('nan')):.1f} %.",
        "",
        "| place | " + " | ".join(profiles) + " | mean |",
        "|---|" + "---|" * (len(profiles) + 1),
    ]
    labels = {
        "core": "simulation core (identified model)",
        "native": "native class in MuJoCo (kp, kv fitted)",
        "exact": "exact runtime in MuJoCo",
        "menagerie": "Menagerie-style class in MuJoCo",
    }
    for key, label in labels.items():
        r = places[key]
        cells = " | ".join(f"{r.rms_deg[p]:.3f}" for p in profiles)
        lines.append(f"| {label} | {cells} | {r.mean():.3f} |")
    n, m = places["native"].mean(), places["menagerie"].mean()
    c, e = places["core"].mean(), places["exact"].mean()
    lines += [
        "",
        f"Native / Menagerie-style: {n / m:.3f} (at most 1/3). Exact against the core: "
        f"{e:.3f} vs {c:.3f} deg ({100 * (e - c) / c:+.1f} %; within 10 %).",
        "",
        "### On the records: the exact runtime and a `mujoco.sysid` fit of MuJoCo's position "
        "actuator",
        "",
        "| record | exact runtime | mujoco.sysid fit | exact / sysid |",
        "|---|---|---|---|",
    ]
    fit_label = f"{result.registers.label()} (the fit's)"
    changed = f"{result.changed_registers.label()} (changed: sysid fit not refitted)"
    for key, label in (("fit_setting", fit_label), ("changed_setting", changed)):
        row = result.on_records[key]
        lines.append(f"| {label} | {row['exact']:.3f} | {row['sysid']:.3f} | "
                     f"{row['exact'] / row['sysid']:.3f} |")  # fmt: skip
    s = result.sysid.servo
    lines += [
        "",
        f"The sysid fit: armature {s.armature:.4g} kg m^2, frictionloss {s.frictionloss:.4g} "
        f"N m, stiffness (kp) {s.kp:.4g} N m/rad, damping {s.damping:.4g} N m s/rad, delay "
        f"{1e3 * s.delay_s:.1f} ms.",
    ]
    return "\n".join(lines) + "\n"


def _plot(result: VerifyResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.mujoco.servo_class import rollout_native
    from gripper_env.mujoco.verify import menagerie_style, recipe_profiles, run_core, run_exact

    truth = load_bus_servo(result.family)
    ident, regs = result.identified, result.registers
    goal = recipe_profiles(truth)["tracking"]
    t = np.arange(goal.size) * 1e-3
    native = result.places["native"].native
    lines = {
        "truth (virtual servo)": run_core(truth, regs, goal),
        "exact runtime (MuJoCo)": run_exact(ident, regs, goal),
        "native class (MuJoCo)": rollout_native(native, ident, [goal])[0] if native else None,
        "Menagerie-style (MuJoCo)": rollout_native(menagerie_style(truth), truth, [goal])[0],
    }
    fig, ax = plt.subplots(figsize=(9, 3.6))
    ax.plot(t, goal, "k:", lw=0.9, label="goal")
    for label, y in lines.items():
        if y is not None:
            ax.plot(t, y, lw=1.1, label=label)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("shaft angle (deg)")
    ax.set_title(f"{result.family}: tracking steps, {regs.label()}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def _verify(args: argparse.Namespace) -> int:
    from gripper_env.mujoco.verify import verify_family

    check_output_folder(args.out, "--out")
    if not 1 <= args.generations <= 10_000:
        raise ValueError(f"--generations must be 1..10000, got {args.generations}")
    start = time.monotonic()
    started = time.perf_counter()

    def say(text: str) -> None:
        stamped = text.startswith("[")  # the identification's lines carry their own time
        print(text if stamped else f"[{time.monotonic() - start:5.0f} s] {text}", flush=True)

    say(f"verifying the {args.verify} export: identification (2-4 minutes on 2 cores), then "
        "MuJoCo (about a minute)")  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"{args.verify}_mujoco"
    command = " ".join(["python -m tuners.bus.export", *sys.argv[1:]])
    result = verify_family(args.verify, seed=args.seed, generations=args.generations, log=say)
    with write_group(), collect_provenance(args.out, stem.name, command=command, started=started):
        doc: dict[str, Any] = result.as_dict()
        write_json(stem.with_suffix(".json"), doc)
        text = format_verification(result)
        write_atomic(stem.with_suffix(".md"), text.encode())
        if not args.no_plot:
            _plot(result, stem.with_suffix(".png"))
    print(text)
    print(f"wrote {stem.with_suffix('.md')} and .json" + ("" if args.no_plot else ", .png"))
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.verify is not None:
        return _verify(args)
    return _export(args)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.export``."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return _run(args)
    except (ValueError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except ImportError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
