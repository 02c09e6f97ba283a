"""``python -m tuners.bus.joint``: an arm's loaded joint (SO-101 shoulder_lift, elbow_flex,
wrist_flex): a virtual arm with gravity, a safe record, the load's identification, the tuning.

Sub-commands:

* ``virtual``: the SO-101's six servos on a pseudo-terminal, every joint under the weight of the
  links beyond it (:class:`gripper_env.hardware.bus.arm.VirtualArm`), a payload at the gripper;
* ``record``: small steps around the pose the joint holds, at the owner's P, I, D and at P
  doubled (:func:`gripper_env.sysid.bus_load.load_plan`). Before a byte moves it refuses a plan
  outside the servo's calibrated limits, or one where gravity (the published links, a payload
  up to ``--payload-max``) reaches 60 % of the torque limit in force or the overload threshold;
  an error bit in any reply (an overload) stops it; the joint's registers are restored and read
  back at the end; the neighbouring joints must be held by their own servos (``--others-held``
  says so) and are never addressed: not one packet goes to another ID;
* ``identify``: the load (gravity's amplitude and hang angle, the links' inertia) from the
  records, with standard errors (:func:`gripper_env.sysid.bus_load.identify_load`); writes the
  loaded model the tuner takes;
* ``tune``: P, I, D and the torque limit under the margins of the loaded loop at every payload
  of ``--payload`` and at the fit's uncertainty corners, and the hold against the servo's own
  protection (:func:`gripper_env.evaluation.bus_load.judge_loaded`, through
  :func:`tuners.bus.tune.tune_registers`); the factory's, LeRobot's and the community's
  ``P 48, I 4`` judged beside it.

Examples
--------
``python -m tuners.bus.joint virtual --payload 0.05 --link /tmp/so101arm &``
``python -m tuners.bus.joint record --port /tmp/so101arm --id 3 --joint elbow_flex --others-held``
``python -m tuners.bus.joint identify runs/bus/joint/elbow_flex_*.csv --joint elbow_flex``
``python -m tuners.bus.joint tune --model runs/bus/joint/elbow_flex_load.json``
``python -m tuners.bus.joint tune --joint elbow_flex`` (the published links, 0-100 g)
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gripper_env.io.files import collect_provenance, write_atomic, write_json
from tuners.bus.cli import EXIT_ERROR, BusArgumentParser, add_servo_arguments, run_cli
from tuners.conventions import conform

__all__ = ["COMMUNITY_I", "main"]

_JOINTS = ("shoulder_lift", "elbow_flex", "wrist_flex")
#: The community's fix for a sagging STS3215 joint: more P and a little I.
COMMUNITY_I = {"p": 48, "i": 4, "d": 32}


def _parser() -> argparse.ArgumentParser:
    parser = BusArgumentParser(
        prog="python -m tuners.bus.joint",
        description="An arm's loaded joint (SO-101): a virtual arm with gravity, a safe load "
        "record, the load's identification, the registers tuned against it.",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=BusArgumentParser)

    v = sub.add_parser("virtual", help="the SO-101's six servos with gravity on a pty")
    v.add_argument("--model", default="sts3215", help="every joint's servo (default sts3215)")
    v.add_argument("--payload", type=float, default=0.0, help="payload at the gripper (kg)")
    v.add_argument("--link", default=None, help="a symbolic link to the pty at this path")

    r = sub.add_parser("record", help="the load's records: small steps around the held pose")
    add_servo_arguments(r, keep_torque=False)
    r.add_argument("--joint", choices=_JOINTS, required=True, help="the joint the ID drives")
    r.add_argument("--others-held", action="store_true",
                   help="confirm the other joints are held by their own servos (torque on); "
                   "required: they are never addressed")  # fmt: skip
    r.add_argument("--payload-max", type=float, default=0.1,
                   help="the heaviest payload the gripper may hold (kg; default 0.1)")  # fmt: skip
    r.add_argument("--out", type=Path, default=Path("runs/bus/joint"),
                   help="folder for JOINT_load_K.csv (default runs/bus/joint)")  # fmt: skip

    i = sub.add_parser("identify", help="the load from the records")
    i.add_argument("records", nargs="+", type=Path, help="record files (joint record)")
    i.add_argument("--joint", choices=_JOINTS, required=True)
    i.add_argument("--model", default="sts3215",
                   help="the servo's loop: a family or an identified model file")  # fmt: skip
    i.add_argument("--payload", type=float, nargs=2, default=(0.0, 0.1), metavar=("LO", "HI"),
                   help="payloads the tuner judges (kg; default 0 0.1)")  # fmt: skip
    i.add_argument("--out", type=Path, default=None, help="folder (default the records')")

    t = sub.add_parser("tune", help="registers against the load, the margins and the hold")
    t.add_argument("--model", default=None,
                   help="a loaded model file (joint identify); default the published links "
                   "on --joint's servo")  # fmt: skip
    t.add_argument("--joint", choices=_JOINTS, default="elbow_flex",
                   help="with the published links (default elbow_flex)")  # fmt: skip
    t.add_argument("--servo", default="sts3215", help="the servo (default sts3215)")
    t.add_argument("--payload", type=float, nargs=2, default=(0.0, 0.1), metavar=("LO", "HI"),
                   help="payloads judged (kg; default 0 0.1)")  # fmt: skip
    t.add_argument("--trials", type=int, default=200, help="TPE trials (default 200)")
    t.add_argument("--polish", type=int, default=300, help="local search budget (default 300)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--out", type=Path, default=Path("runs/bus/joint"))
    t.add_argument("--no-progress", action="store_true")
    return conform(parser, "tuners.bus.joint")


# ---- virtual ------------------------------------------------------------------------------------


def _virtual(args: argparse.Namespace) -> int:
    from gripper_env.hardware.bus.arm import SO101_IDS, VirtualArm

    if not 0.0 <= args.payload <= 1.0:
        raise ValueError(f"--payload must be 0..1 kg, got {args.payload}")
    link = None if args.link is None else os.path.abspath(args.link)
    if link and os.path.lexists(link) and not os.path.islink(link):
        raise ValueError(f"--link {args.link}: a file is there (only a symbolic link is replaced)")
    arm = VirtualArm(args.model, payload_kg=args.payload)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    with arm.bus() as bus:
        if link:
            if os.path.islink(link):
                os.unlink(link)
            os.symlink(bus.path, link)
        try:
            print(bus.path, flush=True)
            names = ", ".join(f"{k} {v}" for k, v in SO101_IDS.items())
            print(f"virtual SO-101 ({arm.servo.name}): {names}; payload {args.payload:g} kg"
                  + (f", linked at {link}" if link else "") + "; Ctrl-C to stop",
                  file=sys.stderr, flush=True)  # fmt: skip
            while not stop.wait(0.2) and bus.running:
                pass
        finally:
            if link and os.path.islink(link):
                os.unlink(link)
    return 0


# ---- record -------------------------------------------------------------------------------------


def _record(args: argparse.Namespace) -> int:
    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.sysid.bus_load import record_load
    from gripper_env.sysid.bus_servo import write_bus_record
    from tuners.bus.cli import output_folder

    if not args.others_held:
        raise ValueError("--others-held is required: the other joints must hold the arm "
                         "with their own servos (torque on); they are never addressed")  # fmt: skip
    if not 0.0 <= args.payload_max <= 1.0:
        raise ValueError(f"--payload-max must be 0..1 kg, got {args.payload_max}")
    out = output_folder(args.out)
    servo = load_bus_servo(args.model)

    def opened(g: Any) -> None:
        args.gripper = g  # the last word says what the servo reads back

    records = record_load(args.port, servo, args.id, args.joint, payload_max_kg=args.payload_max,
                          baudrate=args.baudrate, log=lambda t: print(t, flush=True),
                          opened=opened)  # fmt: skip
    for k, rec in enumerate(records):
        print(f"wrote {write_bus_record(out / f'{args.joint}_load_{k}.csv', rec)}")
    print(args.gripper.restored.describe() if args.gripper.restored else "restored")
    return 0


# ---- identify -----------------------------------------------------------------------------------


def _identify(args: argparse.Namespace) -> int:
    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.model.so101_arm import joint_model, load_arm, q_of_shaft
    from gripper_env.sysid.bus_load import identify_load
    from gripper_env.sysid.bus_servo import read_bus_record

    lo, hi = args.payload
    if not 0.0 <= lo <= hi <= 1.0:
        raise ValueError(f"--payload must be LO HI with 0 <= LO <= HI <= 1 kg, got {lo} {hi}")
    out = args.out or args.records[0].parent
    records = [read_bus_record(p) for p in args.records]
    servo = load_bus_servo(args.model)
    held = float(records[0].goal_values_deg[0])
    arm = load_arm()
    pose = {args.joint: q_of_shaft(held)}
    links = arm.joint_load(args.joint, pose, payload_kg=0.0)
    prior = links.with_payload(0.5 * (lo + hi))
    print(f"identifying the load on {args.joint} from {len(records)} records", flush=True)
    est = identify_load(records, servo, prior, links=links)
    print("| parameter | value | std |\n|---|---|---|")
    for k, v in est.values.items():
        print(f"| {k} | {v:.4g} | {est.std[k]:.2g} |")
    print(f"RMS error {est.rmse_deg:.3f} deg")
    # the fitted load (whatever the arm held when recorded) plus the payloads to judge
    load = est.load.model_copy(update={
        "payload_range_kg": (lo, hi), "payload_lever_m": links.payload_lever_m,
        "payload_hang_deg": links.payload_hang_deg, "payload_kg": hi})  # fmt: skip
    model = joint_model(servo, args.joint, pose, arm=arm).with_updates(load=load)
    model = model.with_updates(jaw=model.jaw.model_copy(update={"open_deg": held}))
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{args.joint}_load.json"
    write_json(path, {"model": model.model_dump(mode="json"), "estimate": est.as_dict(),
                      "records": [str(p) for p in args.records]})  # fmt: skip
    print(f"wrote {path}; next: python -m tuners.bus.joint tune --model {path}")
    return 0


# ---- tune ---------------------------------------------------------------------------------------


def loaded_model(args: argparse.Namespace) -> Any:
    """The loaded model ``tune`` judges: a file of ``identify``, or the published links."""
    from gripper_env.io.config import validate
    from gripper_env.model.bus_servo import BusServoModel, load_bus_servo
    from gripper_env.model.so101_arm import joint_model

    lo, hi = args.payload
    if not 0.0 <= lo <= hi <= 1.0:
        raise ValueError(f"--payload must be LO HI with 0 <= LO <= HI <= 1 kg, got {lo} {hi}")
    if args.model is not None:
        from gripper_env.io.config import MAX_CONFIG_BYTES, read_bounded

        doc = json.loads(read_bounded(Path(args.model), MAX_CONFIG_BYTES, "loaded model"))
        model = validate(BusServoModel, doc.get("model", doc), str(args.model))
        if model.load is None:
            raise ValueError(f"--model {args.model}: the model carries no load")
        load = model.load.model_copy(update={"payload_range_kg": (lo, hi), "payload_kg": hi})
        return model.with_updates(load=load)
    return joint_model(load_bus_servo(args.servo), args.joint, {}, payload_range_kg=(lo, hi))


def format_table(rows: dict[str, Any]) -> str:
    """A markdown table of register sets judged on a loaded joint (the worst payload's
    tracking, the hold, the loaded loop's margins)."""
    lines = [
        "| registers | cost | IAE/step (s) | overshoot (deg) | settled error (deg) | hold 10 s "
        "| Ms | GM (dB) | robust Ms / GM | feasible |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, sc in rows.items():
        t, h, m, r = sc.tracking, sc.hold, sc.margins, sc.robust_margins
        hold = "no trip" if not h.overload else f"{h.trip} at {h.trip_at_s:.2f} s"
        ok = "yes" if sc.feasible else "no: " + "; ".join(sc.violations)
        lines.append(
            f"| {name}: {sc.registers.label()} | {sc.cost:.2f} | {t.iae_per_deg_s:.3f} "
            f"| {t.overshoot_deg:.2f} | {t.settled_error_deg:.2f} | {hold} | {m.ms:.2f} "
            f"| {m.gm_db:.1f} | {r.ms:.2f} / {r.gm_db:.1f} | {ok} |"
        )
    return "\n".join(lines)


def _tune(args: argparse.Namespace) -> int:
    from gripper_env.evaluation.bus_load import judge_loaded
    from tuners.bus.tune import tune_registers

    if not 1 <= args.trials <= 100_000 or not 0 <= args.polish <= 100_000:
        raise ValueError("--trials must be 1..100000 and --polish 0..100000")
    model = loaded_model(args)
    started = time.perf_counter()
    print(f"tuning {model.name} against gravity, payloads {list(args.payload)} kg "
          f"({args.trials} trials, then local searches: minutes)", flush=True)  # fmt: skip
    best, study = tune_registers(model, trials=args.trials, polish=args.polish, seed=args.seed,
                                 progress=not args.no_progress, judge_fn=judge_loaded)  # fmt: skip
    base = model.factory
    full = model.scale.duty_full
    baselines = {
        "factory": base,
        "lerobot": model.community.get("lerobot", base).model_copy(update={"torque_limit": full}),
        "community P48 I4": base.model_copy(update=COMMUNITY_I),
    }
    judged = dict(zip(baselines, judge_loaded(model, list(baselines.values())), strict=True))
    rows = {"tuned": best, **judged}
    table = format_table(rows)
    print(table)
    lerobot = judged["lerobot"].tracking.settled_error_deg
    print(f"settled error: tuned {best.tracking.settled_error_deg:.2f} deg, LeRobot's "
          f"{lerobot:.2f} deg ({best.tracking.settled_error_deg / lerobot:.2f} of it)")  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    stem = args.out / f"{model.name}_registers"
    doc = {"name": model.name, "registers": best.registers.model_dump(),
           "score": best.as_dict(), "baselines": {k: v.as_dict() for k, v in judged.items()},
           "trials": args.trials, "judged": len(study.trials), "seed": args.seed,
           "model": model.model_dump(mode="json")}  # fmt: skip
    command = " ".join(["python -m tuners.bus.joint", *sys.argv[1:]])
    with collect_provenance(args.out, stem.name, command=command, started=started):
        write_json(stem.with_suffix(".json"), doc)
        write_atomic(stem.with_suffix(".md"),
                     f"# {model.name}: registers against gravity\n\n{table}\n")  # fmt: skip
    print(f"wrote {stem.with_suffix('.json')}")
    return 0


def _body(args: argparse.Namespace) -> int:
    return {"virtual": _virtual, "record": _record, "identify": _identify, "tune": _tune}[
        args.command
    ](args)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.bus.joint``."""
    status = run_cli(_parser(), _body, argv)
    return EXIT_ERROR if status is None else status


if __name__ == "__main__":
    sys.exit(main())
