"""Speed of the host <-> board link over the virtual device's pseudo-terminal.

``python -m tuners.speed.hardware [--duration 60] [--speeds 1,max] [--out DIR]`` writes
``hardware_speed.md`` and ``hardware_speed.json`` into ``DIR`` (default ``runs/``; the committed
ones with ``--out results``):

* round-trip latency HEARTBEAT -> STATUS over the pty (median, p99), board at real time;
* achievable host-in-the-loop rate: synchronous round trips per second (each one a SETPOINT
  plus a HEARTBEAT answered by STATUS);
* per-tick cost of the virtual board (firmware twin + simulation core), hence its top speed;
* frames lost in a closed-loop run of ``--duration`` seconds of device time at 1 kHz telemetry
  (batches of 10), the host streaming a step profile at 50 Hz, for each ``--speeds`` entry
  (``max`` = as fast as the virtual board goes; the host must keep up with the watchdog).

The virtual board shares the machine with the host, so these are figures for this machine and
this Python, not for the Mega's USB link (which adds about 4 ms per transfer).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.host.device import GripperDevice
from gripper_env.hardware.host.experiment import run_profile
from gripper_env.hardware.protocol import Mode
from gripper_env.hardware.twin.firmware import Firmware
from gripper_env.hardware.twin.rig import VirtualRig
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.io.files import collect_provenance, write_atomic, write_group
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.references import step_profile
from tuners.rig.virtual import parse_speed


def _device(vd: VirtualDevice) -> GripperDevice:
    lo, hi = vd.rig.true_calibration
    return GripperDevice(vd.path, calibration=Calibration(lo, hi), boot_wait_s=0.0, timeout_s=1.0)


def round_trips(n: int = 1000) -> dict[str, float]:
    with VirtualDevice("test2", "actual", speed=1.0) as vd, _device(vd) as dev:
        dev.configure(decimation=0)  # quiet line: pure request/answer latency
        rtt = np.array([dev.heartbeat()[1] for _ in range(n)])
        dev.configure()  # with 1 kHz telemetry flowing
        dev.set_mode(Mode.OPEN_LOOP)
        t = time.perf_counter()
        loops = 0
        while time.perf_counter() - t < 3.0:
            dev.set_setpoint(40.0 + (loops % 2))
            dev.heartbeat()
            loops += 1
        rate = loops / (time.perf_counter() - t)
    return {
        "rtt_median_ms": float(np.median(rtt) * 1e3),
        "rtt_p99_ms": float(np.percentile(rtt, 99) * 1e3),
        "rtt_max_ms": float(rtt.max() * 1e3),
        "host_loop_rate_hz": rate,
    }


def tick_cost(n: int = 20000) -> dict[str, float]:
    fw, rig = Firmware(), VirtualRig("test2", "actual")
    from gripper_env.hardware import protocol as proto

    fw.receive(proto.encode_frame(0, proto.Hello()), 0)
    fw.receive(proto.encode_frame(1, proto.Configure(p=1.0, i=9.0, d=-0.001)), 0)
    fw.receive(proto.encode_frame(2, proto.SetMode(Mode.CLOSED_LOOP)), 0)
    t = time.perf_counter()
    for k in range(n):
        if k % 400 == 0:
            fw.receive(proto.encode_frame(3 + k // 400 & 0xFF, proto.Setpoint(21.0)), k * 1000)
        fw.tick(k * 1000, rig.adc)
        rig.step(fw.command)
        fw.take_tx()
    us = (time.perf_counter() - t) / n * 1e6
    return {"tick_us": us, "max_speed_x": 1000.0 / us}


def closed_loop_run(duration_s: float, speed: float) -> dict[str, Any]:
    half = duration_s / 2
    ref = step_profile(hold_s=1.0, grip_s=half - 1.0, ungrip_s=half)
    with VirtualDevice("test2", "actual", speed=speed) as vd, _device(vd) as dev:
        dev.configure(PIDGains(1.0, 9.0, -0.001), PIDOptions(output_limits=(21.0, 92.0)))
        t = time.perf_counter()
        rec = run_profile(dev, ref, Mode.CLOSED_LOOP)
        wall = time.perf_counter() - t
        _, _ = dev.heartbeat()
        status = dev.last_status
        assert vd.firmware is not None  # the Python twin
        overruns = vd.firmware.overruns
    traj = rec.trajectory()
    return {
        "speed": speed,
        "device_s": duration_s,
        "wall_s": wall,
        "samples": len(rec.samples),
        "device_frames_lost": rec.frames_lost,
        "missing_samples": traj.missing_samples,
        "host_frames_lost_at_device": int(status.frames_lost) if status else -1,
        "tx_dropped": int(status.tx_dropped) if status else -1,
        "board_overruns": overruns,
        "host_periods": rec.host_periods,
        "missed_deadlines": rec.missed_deadlines,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tuners.speed.hardware")
    parser.add_argument("--duration", type=float, default=60.0, help="closed-loop run (s)")
    parser.add_argument("--speeds", default="max,1", help="comma-separated speeds (1, max...)")
    parser.add_argument(
        "--out",
        default="runs",
        help="output folder (default: runs; the committed figures: --out results)",
    )
    args = parser.parse_args(argv)
    speeds = [parse_speed(s) for s in args.speeds.split(",")]
    started = time.perf_counter()
    result: dict[str, Any] = {
        "round_trip": round_trips(),
        "tick": tick_cost(),
        "closed_loop": [closed_loop_run(args.duration, s) for s in speeds],
    }
    out = Path(args.out)
    rt, tk = result["round_trip"], result["tick"]
    lines = [
        "# Host <-> board link speed over the virtual device",
        "",
        "`python -m tuners.speed.hardware`, virtual board and host on the same machine (its "
        "platform and versions: `hardware_speed.provenance.json`).",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| round trip HEARTBEAT -> STATUS, median | {rt['rtt_median_ms']:.3f} ms |",
        f"| round trip, p99 | {rt['rtt_p99_ms']:.3f} ms |",
        f"| host-in-the-loop rate (SETPOINT + HEARTBEAT round trip) | "
        f"{rt['host_loop_rate_hz']:.0f} Hz |",
        f"| virtual board cost per 1 ms tick (firmware + simulation) | {tk['tick_us']:.1f} us |",
        f"| virtual board top speed | {tk['max_speed_x']:.0f}x real time |",
        "",
        "Closed-loop step (tuned paper gains on test2, actual gripper), 1 kHz telemetry in "
        "batches of 10, host streaming the reference at 50 Hz:",
        "",
        "| speed | device time | wall time | samples | frames lost | samples missing | "
        "board overruns | missed host deadlines |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in result["closed_loop"]:
        speed = "max" if r["speed"] == 0 else f"{r['speed']:g}x"
        lines.append(
            f"| {speed} | {r['device_s']:g} s | {r['wall_s']:.1f} s | {r['samples']} | "
            f"{r['device_frames_lost']} | {r['missing_samples']} | {r['board_overruns']} | "
            f"{r['missed_deadlines']} / {r['host_periods']} |"
        )
    command = " ".join(["python -m tuners.speed.hardware", *(sys.argv[1:] if argv is None
                                                             else argv)])  # fmt: skip
    with write_group(), collect_provenance(out, "hardware_speed", command=command, started=started):
        write_atomic(out / "hardware_speed.json", json.dumps(result, indent=2) + "\n")
        write_atomic(out / "hardware_speed.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
