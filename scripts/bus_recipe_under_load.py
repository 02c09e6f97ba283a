"""The README's bus-servo recipe, as printed, several times over on a loaded host: the measurement
behind the README's bus table and issue 33's "Ms <= 1.6 on the truth in 5 of 5 reruns".

For each family and rerun, in a fresh folder: ``busy`` processes that spin (``python -c 'while
True: pass'``) start, then the README block runs line by line (the six-servo virtual bus with
the gripper at ID 6 and calibrated limits, calibrate, record, identify, tune, deploy with the
hold), each command as a subprocess, exactly as printed but for ``--model`` and the folder. The
tuned registers are then judged on the virtual servo's truth (the family's shipped model): its
margins alone, and on the truth's corners with the fit's own uncertainties and alternatives.

Usage::

    python scripts/bus_recipe_under_load.py --families sts3215 xl330 --reruns 5 --busy 2 \\
        --out runs/bus_under_load

It prints one line per run and writes ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

BLOCK = [
    "python -m tuners.bus.calibrate --port {link} --id 6 --model {family} --closed-ticks 1760 "
    "--open-ticks 2940 --out {out}/jaw.json",
    "python -m tuners.bus.record --port {link} --id 6 --model {family} --jaw {out}/jaw.json "
    "--out {out}",
    "python -m tuners.bus.identify {records} --model {family} --name my-{family}",
    "python -m tuners.bus.tune --model {out}/my-{family}_model.json --out {out}",
    "python -m tuners.bus.deploy --registers {out}/my-{family}_registers.json --port {link} "
    "--id 6 --hold 10 --save --no-plot",
]
VIRTUAL = ("python -m tuners.bus.virtual --model {family} --id 6 --others 1 2 3 4 5 "
           "--limits 1750 2950 {lerobot}--object 185 --link {link}")  # fmt: skip
#: The README's arm is an SO-101 as LeRobot leaves it (``--lerobot``: the gripper's
#: ``Overload_Torque`` 25 %); LeRobot's SO follower is built on STS3215s.
LEROBOT = {"sts3215": "--lerobot "}


def _run(cmd: str, log) -> tuple[int, float]:
    start = time.perf_counter()
    argv = [sys.executable if a == "python" else a for a in shlex.split(cmd)]
    if "{records}" in cmd:
        raise AssertionError(cmd)
    proc = subprocess.run(argv, stdout=log, stderr=subprocess.STDOUT, check=False)
    return proc.returncode, time.perf_counter() - start


def one_run(family: str, out: Path, busy: int) -> dict:
    from gripper_env.evaluation.bus_servo import corner_models, loop_margins
    from gripper_env.model.bus_servo import (
        RegisterSet,
        alternative_models,
        load_bus_servo,
        relative_uncertainties,
    )

    out.mkdir(parents=True, exist_ok=True)
    link = f"/tmp/busload-{os.getpid()}-{family}"
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                for _ in range(busy)]  # fmt: skip
    result: dict = {"family": family, "out": str(out), "steps": []}
    with open(out / "log.txt", "w") as log:
        virtual = subprocess.Popen([sys.executable if a == "python" else a for a in
                                    shlex.split(VIRTUAL.format(family=family, link=link,
                                                               lerobot=LEROBOT.get(family, "")))],
                                   stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
        try:
            for _ in range(200):
                if os.path.exists(link):
                    break
                time.sleep(0.1)
            for line in BLOCK:
                records = " ".join(str(p) for p in sorted(out.glob("record_*.csv")))
                cmd = line.replace("{records}", records).format(family=family, out=out, link=link)
                print(f"$ {cmd}", file=log, flush=True)
                code, seconds = _run(cmd, log)
                result["steps"].append({"command": cmd.split()[2], "exit": code,
                                        "seconds": round(seconds, 1)})  # fmt: skip
                if code != 0:
                    result["failed"] = cmd.split()[2]
                    return result
        finally:
            virtual.send_signal(signal.SIGINT)
            virtual.wait(timeout=20)
            for s in spinners:
                s.kill()
                s.wait()
    model_file = out / f"my-{family}_model.json"
    doc = json.loads(model_file.read_text())
    tuned = json.loads((out / f"my-{family}_registers.json").read_text())
    regs = RegisterSet(**tuned["registers"])
    truth = load_bus_servo(family)
    on_truth = loop_margins(truth, regs)
    rel = relative_uncertainties(doc, "uncertainty", str(model_file)) or {}
    alts = alternative_models(doc, "alternatives", str(model_file))
    corners = [loop_margins(c, regs) for c in corner_models(truth, rel, alternatives=[])[1:]]
    report = json.loads((out / f"deploy_my-{family}" / "report.json").read_text())
    result.update(
        fit_pct=doc["fit_pct"],
        loop_delay_ms=round(doc["loop_delay_s"] * 1e3),
        alternatives_ms=[round(a.physics.loop_delay_s * 1e3) for a in alts],
        registers=tuned["registers"],
        robust_ms=tuned["score"]["robust_margins"]["ms"],
        ms_truth=on_truth.ms,
        gm_truth_db=on_truth.gm_db,
        ms_truth_corners=max((c.ms for c in corners), default=on_truth.ms),
        deploy_fit_pct=report.get("fit_pct"),
        hold=report.get("hold"),
    )
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--families", nargs="+", default=["sts3215", "xl330"])
    parser.add_argument("--reruns", type=int, default=5)
    parser.add_argument("--busy", type=int, default=2, help="spinning processes beside it")
    parser.add_argument("--out", type=Path, default=Path("runs/bus_under_load"))
    args = parser.parse_args()
    runs = []
    for family in args.families:
        for k in range(args.reruns):
            r = one_run(family, args.out / f"{family}-{k}", args.busy)
            runs.append(r)
            args.out.mkdir(parents=True, exist_ok=True)  # written after every run: kept if cut
            (args.out / "summary.json").write_text(json.dumps(runs, indent=1, default=str))
            steps = ", ".join(f"{s['command'].split('.')[-1]} {s['seconds']:.0f} s"
                              for s in r["steps"])  # fmt: skip
            if "failed" in r:
                print(f"{family} #{k}: FAILED at {r['failed']} ({steps})", flush=True)
                continue
            print(f"{family} #{k}: fit {r['fit_pct']:.1f} %, loop delay {r['loop_delay_ms']} ms "
                  f"(alternatives {r['alternatives_ms']}), {r['registers']}, Ms on the truth "
                  f"{r['ms_truth']:.2f} (corners {r['ms_truth_corners']:.2f}), GM "
                  f"{r['gm_truth_db']:.1f} dB, deploy fit {r['deploy_fit_pct']:.1f} % ({steps})",
                  flush=True)  # fmt: skip
    return 0 if all("failed" not in r for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
