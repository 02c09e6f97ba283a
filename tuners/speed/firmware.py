"""The compiled Mega 2560 firmware's timing, measured on the emulated CPU (simavr, 16 MHz).

``python -m tuners.speed.firmware [--duration 60] [--image ELF] [--out DIR]`` writes
``firmware_speed.md`` and ``firmware_speed.json`` into ``DIR`` (default ``runs/``; the committed
ones with ``--out results``). Every figure but the last is
in emulated cycles or microseconds, counted by the firmware-in-the-loop harness
(``firmware/emulator``), so it is the same on any machine:

* flash and static RAM (``avr-size``), the stack's high-water mark, the RAM left;
* a closed-loop run of ``--duration`` s (tuned paper gains on test2, the actual gripper, the
  paper's step profile repeated, 1 kHz telemetry in batches of 10, the host traffic of
  ``tuners.rig.deploy``: the reference every 20 ms, a heartbeat every 200 ms), scripted on emulated
  time: cycles of the control path (safety, PID, servo update: pin 13 high) and of the
  telemetry (a tick's sample, and the frame's completion every batch: pin 12 high), the worst
  tick, the headroom at 1 kHz, the CPU's busy share (it sleeps when idle), the start jitter of
  the ticks, overruns, telemetry frames lost;
* the same run through the pseudo-terminal with the host's own stack (``GripperDevice``,
  ``run_profile``): frames lost, samples missing;
* latency from a SETPOINT's last byte to the servo: to the output-compare register, to the
  start of the first pulse with the new width, to its end (when the servo has it);
* the watchdog: from the host's last byte to the end of the first pulse at the safe angle;
* 4 KiB of random bytes on the line in closed loop: late ticks, the worst lateness;
* ``--fuzz`` (100,000) fuzzed host frames against the image
  (:func:`gripper_env.hardware.emulator.link_fuzz.fuzz_image`): pulses outside the hard range, bad
  frames accepted, lost frames reported;
* the agreement of the emulated board, the Python twin and the simulation core;
* the emulation's speed (emulated seconds per wall second; the one machine-dependent figure,
  the median of the runs).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.emulator.board import EmulatedBoard
from gripper_env.hardware.emulator.build import ensure_built
from gripper_env.hardware.emulator.link_fuzz import HARD_WINDOW_US, fuzz_image
from gripper_env.hardware.emulator.mega2560 import CYCLES_PER_MS, CYCLES_PER_US
from gripper_env.hardware.emulator.scripted import (
    AGREEMENT_SHIFT_MS,
    ScriptedHost,
    run_agreement,
)
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.host.configuration import configure_message
from gripper_env.hardware.host.device import GripperDevice
from gripper_env.hardware.host.experiment import run_profile
from gripper_env.hardware.twin.rig import VirtualRig
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.io.files import collect_provenance, write_atomic, write_group
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.references import Reference, load_reference

GAINS = PIDGains(1.0, 9.0, -0.001)  # the paper's tuned gains (Table 3)
OPTIONS = PIDOptions(output_limits=(21.0, 92.0))
BUDGET = CYCLES_PER_MS  # cycles in one 1 kHz period
CONTROL, TELEMETRY = 0, 1  # watched pins: 13 (PB7) and 12 (PB6)


def _profile(duration_s: float) -> Reference:
    step = load_reference("step")
    reps = int(np.ceil(duration_s / (len(step.values_deg) * step.dt_s)))
    values = np.tile(step.values_deg, reps)[: round(duration_s / step.dt_s)]
    return Reference(f"step x{reps}", step.dt_s, values)


def _board(image: Path, harness: Path, seed: int = 0) -> tuple[EmulatedBoard, Calibration]:
    rig = VirtualRig("test2", "actual", seed, 92.0, pulse_train=True)
    board = EmulatedBoard(rig, image=image, harness=harness, record=True)
    return board, Calibration(*rig.true_calibration)


def _spans(edges: np.ndarray, pin: int) -> tuple[np.ndarray, np.ndarray]:
    """Start cycles and lengths (cycles) of the high phases of a pin."""
    e = edges[edges["pin"] == pin]
    rise = e["cycle"][e["level"] == 1].astype(np.int64)
    fall = e["cycle"][e["level"] == 0].astype(np.int64)
    fall = fall[fall > rise[0]] if len(rise) else fall
    n = min(len(rise), len(fall))
    return rise[:n], fall[:n] - rise[:n]


def image_size(image: Path) -> dict[str, int]:
    out = subprocess.run(["avr-size", str(image)], capture_output=True, text=True, check=True)
    text, data, bss = (int(x) for x in out.stdout.splitlines()[-1].split()[:3])
    return {"flash": text + data, "static_ram": data + bss}


def closed_loop(image: Path, harness: Path, duration_s: float) -> dict[str, Any]:
    """The scripted closed-loop run (module docstring): the loop's cycle budget."""
    board, cal = _board(image, harness)
    host = ScriptedHost(board)
    wall = time.perf_counter()
    host.run(50)
    host.open_session(configure_message(GAINS, OPTIONS, cal))
    values = _profile(duration_s).values_deg
    start_cycle = board.mega.cycle
    sleep0 = board.mega.stats()["sleep_cycles"]
    host.deploy(values)
    stats = board.mega.stats()
    since = host.ms
    host.send(proto.Heartbeat(1))
    host.run(20)
    (status,) = host.replies(proto.Status, since)
    wall = time.perf_counter() - wall
    edges = board.edges()
    edges = edges[edges["cycle"] >= start_cycle]
    c_start, c_len = _spans(edges, CONTROL)
    t_start, t_len = _spans(edges, TELEMETRY)
    # every tick encodes its sample; one in `batch` also completes the frame (CRC, COBS, queue):
    # those take ~2.5x the others, and the two groups do not overlap
    frames = t_len > 1.5 * np.median(t_len)
    # a tick = its control span, then (same tick) the telemetry span that follows it
    follows = np.searchsorted(c_start, t_start) - 1
    total = c_len.copy()
    total[follows[frames]] += t_len[frames] + (t_start[frames] - (c_start + c_len)[follows[frames]])
    k = np.round((c_start - c_start[0]) / BUDGET).astype(np.int64)
    offset = c_start - c_start[0] - k * BUDGET
    lateness = offset - offset.min()  # from the earliest start relative to the 1 ms grid
    period = np.diff(c_start) / CYCLES_PER_US
    s = host.samples()
    closed = (s.flags & proto.SampleFlag.MODE_MASK) == proto.Mode.CLOSED_LOOP
    gaps = np.round(np.diff(s.t_us[closed]) / 1000).astype(np.int64) - 1
    busy = 1.0 - (stats["sleep_cycles"] - sleep0) / (stats["cycle"] - start_cycle)
    stack = board.mega.stack_peak_bytes
    board.close()
    return {
        "ticks": len(c_start),
        "control_cycles": _dist(c_len),
        "telemetry_sample_cycles": _dist(t_len[~frames]),
        "telemetry_frame_cycles": _dist(t_len[frames]),
        "frames_encoded": int(frames.sum()),
        "worst_tick_cycles": int(total.max()),
        "headroom_worst_pct": 100.0 * (1 - total.max() / BUDGET),
        "headroom_control_pct": 100.0 * (1 - c_len.max() / BUDGET),
        "cpu_busy_pct": 100.0 * busy,
        "start_jitter_us": float(lateness.max() / CYCLES_PER_US),
        "period_us": [float(period.min()), float(period.max())],
        "overruns": status.overruns,
        "tx_dropped": status.tx_dropped,
        "frames_lost": host.decoder.stats.lost + host.decoder.stats.rejected,
        "samples": int(closed.sum()),
        "samples_missing": int(gaps.sum()),
        "stack_peak_bytes": stack,
        "emulated_s": (stats["cycle"] - start_cycle) / (BUDGET * 1000),
        "wall_s": wall,
    }


def _dist(x: np.ndarray) -> dict[str, float]:
    if not len(x):
        return {"n": 0}
    return {
        "n": len(x),
        "median": float(np.median(x)),
        "p99": float(np.percentile(x, 99)),
        "max": float(x.max()),
        "min": float(x.min()),
    }


def through_the_pty(image: Path, harness: Path, duration_s: float) -> dict[str, Any]:
    """The same closed loop with the host's own stack over the pty (speed: as fast as it goes)."""
    ref = _profile(duration_s)
    with VirtualDevice("test2", "actual", speed=0, image=image, harness=harness) as vd:
        cal = Calibration(*vd.rig.true_calibration)
        wall = time.perf_counter()
        ticks0 = vd.ticks
        with GripperDevice(vd.path, calibration=cal, boot_wait_s=0.0, timeout_s=2.0) as dev:
            dev.configure(GAINS, OPTIONS)
            rec = run_profile(dev, ref, proto.Mode.CLOSED_LOOP)
            status, _ = dev.heartbeat()
        wall = time.perf_counter() - wall
        emulated = (vd.ticks - ticks0) / 1000
    traj = rec.trajectory()
    return {
        "complete": rec.complete,
        "samples": len(rec.samples),
        "frames_lost": rec.frames_lost,
        "missing_samples": traj.missing_samples,
        "overruns": status.overruns,
        "tx_dropped": status.tx_dropped,
        "host_periods": rec.host_periods,
        "missed_deadlines": rec.missed_deadlines,
        "emulated_s": emulated,
        "wall_s": wall,
    }


def latency(image: Path, harness: Path, n: int = 200, seed: int = 1) -> dict[str, Any]:
    """SETPOINT -> servo, open loop, commands at random phases of the tick and servo frame."""
    board, cal = _board(image, harness)
    host = ScriptedHost(board)
    host.run(50)
    host.open_session(configure_message(PIDGains(0.0, 0.0, 0.0), OPTIONS, cal))
    host.send(proto.Setpoint(40.0))
    host.send(proto.SetMode(proto.Mode.OPEN_LOOP))
    host.run(100, heartbeat_ms=100)
    rng = np.random.default_rng(seed)
    to_register, to_start, to_end = [], [], []
    for k in range(n):
        angle = 45.0 + (k % 2) * 10.0 + (k % 7)  # never the last one (nor the first, 40)
        board.mega.run_until(board.mega.cycle + int(rng.integers(0, BUDGET)))
        board.edges()
        n_pulses = len(board.pulses)
        host.send(proto.Setpoint(angle))
        arrived = board.mega.rx_last_cycle
        host.run(45)
        edges = board.edges()
        c_start, c_len = _spans(edges, CONTROL)
        c_end = c_start + c_len
        applied = c_end[c_start >= arrived][0]  # servo_apply ends the tick's control span
        new = board.pulses[n_pulses:]
        width = board.pulse_angles(new)
        hit = np.flatnonzero(np.abs(width - angle) < 0.05)[0]
        start = int(new["start"][hit])
        to_register.append(applied - arrived)
        to_start.append(start - arrived)
        to_end.append(start + int(new["width"][hit]) - arrived)
        host.send(proto.Heartbeat(k))
    board.close()
    us = {
        "register": np.array(to_register) / CYCLES_PER_US,
        "pulse_start": np.array(to_start) / CYCLES_PER_US,
        "pulse_end": np.array(to_end) / CYCLES_PER_US,
    }
    return {name: _dist(v) for name, v in us.items()}


def watchdog(image: Path, harness: Path, n: int = 10, seed: int = 2) -> dict[str, Any]:
    """Host silence -> the end of the first pulse at the safe angle (92 deg), ``n`` phases."""
    board, cal = _board(image, harness)
    host = ScriptedHost(board)
    host.run(50)
    host.open_session(configure_message(PIDGains(0.0, 0.0, 0.0), OPTIONS, cal))
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        host.send(proto.SetMode(proto.Mode.IDLE))
        host.send(proto.Setpoint(40.0))
        host.send(proto.SetMode(proto.Mode.OPEN_LOOP))
        host.run(100 + int(rng.integers(0, 40)))
        board.mega.run_until(board.mega.cycle + int(rng.integers(0, BUDGET)))
        host.send(proto.Heartbeat(0))
        silent_from = board.mega.rx_last_cycle
        before = len(board.pulses)
        host.run(560)
        new = board.pulses[before:]
        safe = np.flatnonzero(np.abs(board.pulse_angles(new) - 92.0) < 0.05)
        first = new[safe[0]]
        out.append((int(first["start"]) + int(first["width"]) - silent_from) / CYCLES_PER_MS)
    board.close()
    return {"safe_pulse_ms": _dist(np.array(out))}


def line_noise(image: Path, harness: Path, n_bytes: int = 4096, seed: int = 4) -> dict[str, Any]:
    """4 KiB of random bytes on the line during the closed loop."""
    board, cal = _board(image, harness)
    host = ScriptedHost(board)
    host.run(50)
    host.open_session(configure_message(GAINS, OPTIONS, cal))
    host.send(proto.SetMode(proto.Mode.CLOSED_LOOP))
    host.run(300, heartbeat_ms=100)
    board.edges()
    start = board.mega.cycle
    noise = np.random.default_rng(seed).integers(0, 256, n_bytes, dtype=np.uint8).tobytes()
    host.send_raw(noise)
    host.run(100)
    flood_ms = (board.mega.rx_last_cycle - start) / CYCLES_PER_MS
    since = host.ms
    host.send_raw(b"\x00")
    host.send(proto.Heartbeat(1))
    host.run(20)
    (status,) = host.replies(proto.Status, since)
    c_start, _ = _spans(board.edges(), CONTROL)
    k = np.round((c_start - c_start[0]) / BUDGET).astype(np.int64)
    offset = c_start - c_start[0] - k * BUDGET
    board.close()
    return {
        "bytes": n_bytes,
        "flood_ms": flood_ms,
        "overruns": status.overruns,
        "rejected_frames": status.bad_frame + status.bad_crc,
        "worst_lateness_us": float((offset.max() - offset.min()) / CYCLES_PER_US),
        "ticks": len(c_start),
        "faults": status.faults,
    }


def fuzz(image: Path, harness: Path, n_frames: int, seed: int = 21) -> dict[str, Any]:
    """``n_frames`` fuzzed host frames against the image
    (:mod:`gripper_env.hardware.emulator.link_fuzz`)."""
    wall = time.perf_counter()
    out = fuzz_image(n_frames, seed, image=image, harness=harness).as_dict()
    out["seed"] = seed
    out["wall_s"] = time.perf_counter() - wall
    return out


def agreement(image: Path, harness: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, gains in (("tuned", GAINS), ("untuned", PIDGains(-0.4, 7.0, -0.045))):
        a = run_agreement(gains, "step", options=OPTIONS, image=image, harness=harness)
        out[name] = {"gains": gains.as_array().tolist(), "pairs": a.summary()}
        out["tolerance_deg"] = a.tolerance_deg
    return out


def _fmt_cycles(d: dict[str, float]) -> str:
    return (
        f"{d['median']:.0f} ({d['median'] / CYCLES_PER_US:.0f} us) median, "
        f"{d['max']:.0f} ({d['max'] / CYCLES_PER_US:.0f} us) max"
    )


def report(result: dict[str, Any]) -> str:
    """The markdown of ``results/firmware_speed.md`` from the measurements (its JSON)."""
    lines = _memory_section(result)
    lines += _loop_section(result["closed_loop"], result["pty"])
    lines += _latency_section(result["latency"])
    lines += _safety_section(result["watchdog"], result["line_noise"])
    if "fuzz" in result:
        lines += _fuzz_section(result["fuzz"])
    lines += _agreement_section(result["agreement"])
    lines += [
        "## Emulation speed",
        "",
        f"{result['speed_x']:.1f}x real time (median of the runs above, emulated seconds per wall "
        "second) on the machine of `firmware_speed.provenance.json`.",
    ]
    return "\n".join(lines) + "\n"


def _memory_section(result: dict[str, Any]) -> list[str]:
    """Title, provenance and memory."""
    size, stack = result["image"], result["closed_loop"]["stack_peak_bytes"]
    return [
        "# Firmware speed on the emulated Mega 2560",
        "",
        f"`python -m tuners.speed.firmware --duration {result['duration_s']:g}`: the compiled "
        "image (`firmware/build.sh`) under simavr at 16 MHz (`firmware/emulator`). Every figure "
        "but the last is counted in emulated cycles, the same on any machine; timings come from "
        "the firmware's own marks (pin 13 high while the control path runs, pin 12 while the "
        "tick's telemetry sample is encoded and, every batch, the frame completed and queued).",
        "",
        "## Memory",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| flash | {size['flash']} of 253,952 bytes ({100 * size['flash'] / 253952:.1f} %) |",
        f"| static RAM (data + bss) | {size['static_ram']} of 8,192 bytes |",
        f"| stack high-water (closed loop, host traffic, boot included) | {stack} bytes |",
        f"| RAM never touched | {8192 - size['static_ram'] - stack} bytes |",
        "",
    ]


def _loop_section(cl: dict[str, Any], pty: dict[str, Any]) -> list[str]:
    """The 1 kHz loop: cycles, headroom, jitter, and the run through the pseudo-terminal."""
    return [
        f"## The 1 kHz loop over {cl['emulated_s']:.0f} s of closed loop",
        "",
        "Tuned paper gains on test2, actual gripper, the paper's step profile repeated, telemetry "
        "every tick in batches of 10, the host sending the reference every 20 ms and a "
        "heartbeat every 200 ms.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| control path per tick (safety, PID, servo update) | "
        f"{_fmt_cycles(cl['control_cycles'])} |",
        f"| telemetry, a tick's sample (CRC and COBS of its 7 bytes into the frame) | "
        f"{_fmt_cycles(cl['telemetry_sample_cycles'])} |",
        f"| telemetry, the tick that completes a frame (its sample, the CRC's and COBS's first "
        f"block, into the queue) | {_fmt_cycles(cl['telemetry_frame_cycles'])} |",
        f"| worst tick (control and telemetry) | {cl['worst_tick_cycles']} cycles of {BUDGET} |",
        f"| headroom at 1 kHz, worst tick | {cl['headroom_worst_pct']:.0f} % |",
        f"| headroom at 1 kHz, control path alone | {cl['headroom_control_pct']:.0f} % |",
        f"| CPU busy, on average (idle sleep otherwise; UART and timer interrupts included) | "
        f"{cl['cpu_busy_pct']:.0f} % |",
        f"| tick start jitter, worst (peak to peak on the 1 ms grid) | "
        f"{cl['start_jitter_us']:.1f} us |",
        f"| tick period, min / max | {cl['period_us'][0]:.1f} / {cl['period_us'][1]:.1f} us |",
        f"| ticks that started > 250 us late (STATUS.overruns) | {cl['overruns']} of "
        f"{cl['ticks']} |",
        f"| telemetry frames lost / dropped by the board | {cl['frames_lost']} / "
        f"{cl['tx_dropped']} of {cl['frames_encoded']} |",
        f"| telemetry samples received / missing (gaps in their 1 ms times) | {cl['samples']} / "
        f"{cl['samples_missing']} |",
        "",
        "Through the pseudo-terminal with the host's own stack (`GripperDevice`, `run_profile`, "
        "as `tuners.rig.deploy`), the board as fast as the emulation goes:",
        "",
        "| run | samples | frames lost | samples missing | board overruns | missed host "
        "deadlines |",
        "|---|---|---|---|---|---|",
        f"| {pty['emulated_s']:.0f} s closed loop | {pty['samples']} | {pty['frames_lost']} | "
        f"{pty['missing_samples']} | {pty['overruns']} | {pty['missed_deadlines']} / "
        f"{pty['host_periods']} |",
        "",
    ]


def _latency_section(lat: dict[str, Any]) -> list[str]:
    """From a host command's last byte to the register, the pulse's start and its end."""
    lines = [
        "## Latency from a host command to the servo",
        "",
        f"{lat['register']['n']} SETPOINTs in open loop at random phases of the tick and of the "
        "servo frame, from the frame's last byte on the line:",
        "",
        "| to | min | median | max |",
        "|---|---|---|---|",
    ]
    for key, what in (
        ("register", "the output-compare register (the tick that applies it ends)"),
        ("pulse_start", "the start of the first pulse with the new width"),
        ("pulse_end", "the end of that pulse (the servo has the command)"),
    ):
        d = lat[key]
        lines.append(
            f"| {what} | {d['min'] / 1000:.2f} ms | {d['median'] / 1000:.2f} ms | "
            f"{d['max'] / 1000:.2f} ms |"
        )
    lines += [
        "",
        "The firmware's share is at most one tick (1 ms); the rest is the servo's 50 Hz frame: "
        "a new width waits for the next 20 ms period of Timer1 (OCR1A is double-buffered).",
        "",
    ]
    return lines


def _safety_section(wd: dict[str, Any], noise: dict[str, Any]) -> list[str]:
    """The watchdog's safe pulse after host silence, and random bytes on the line."""
    w = wd["safe_pulse_ms"]
    return [
        "## Safety timing",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| host silence -> end of the first pulse at the safe angle ({w['n']} phases) | "
        f"{w['min']:.1f} - {w['max']:.1f} ms (watchdog 500 ms, + 1 ms tick, + one 20 ms servo "
        "frame, + the pulse) |",
        f"| {noise['bytes']} random bytes on the line (closed loop, {noise['flood_ms']:.0f} ms at "
        f"the line rate): ticks > 250 us late | {noise['overruns']} of {noise['ticks']}, the "
        f"latest {noise['worst_lateness_us']:.0f} us late; {noise['rejected_frames']} frames "
        f"rejected; faults {noise['faults']} |",
        "",
    ]


def _fuzz_section(fz: dict[str, Any]) -> list[str]:
    """Fuzzed host frames against the image: pulses, frames accepted, losses reported."""
    lo, hi = HARD_WINDOW_US
    kinds = ", ".join(f"{k} {v}" for k, v in sorted(fz["damage_kinds"].items()))
    return [
        f"## {fz['frames']:,} fuzzed host frames",
        "",
        f"`gripper_env.hardware.emulator.link_fuzz.fuzz_image` (seed {fz['seed']}), "
        f"{fz['emulated_s']:.0f} s of emulated time: setpoints of any value, mode changes, "
        "configurations that are mostly hostile (widened jaw ranges, reversed and shifted pulse "
        "mappings, non-finite gains), heartbeats, ESTOPs, CRC-valid frames of unknown types and "
        f"wrong lengths; {fz['damaged']:,} of them damaged on the way ({kinds}), and "
        f"{fz['noise_bytes']:,} bytes of line noise in bursts of up to 2 KiB, each ended by a "
        "delimiter. A frame the board answers is followed by the next 1 ms later, as a host that "
        "waits for the answer; a setpoint 0.33 ms later.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| servo pulses outside the hard window {lo:g}-{hi:g} us (21-92 deg), measured on the "
        f"pin | {fz['pulses_outside']} of {fz['pulses']:,} ({fz['pulse_us'][0]:g}-"
        f"{fz['pulse_us'][1]:g} us) |",
        f"| bad frames accepted (taken from the line, bytes differing from the frame sent) | "
        f"{fz['bad_accepted']} (the board took {fz['board_accepted'] - 4:,} frames, the "
        f"protocol's decoder {fz['delivered']:,}) |",
        f"| frames lost on the line / reported lost by the board (FRAMES_LOST) / not reported | "
        f"{fz['lost']:,} / {fz['reported_lost']:,} / {fz['unreported']} |",
        f"| the board's setpoint at its answers, against the last one delivered: mismatches | "
        f"{fz['setpoint_mismatches']} of {fz['setpoint_checks']:,} |",
        f"| bytes lost before the decoder / device frames dropped or lost on the way back | "
        f"{fz['rx_overflow']} / {fz['tx_dropped'] + fz['device_frames_lost']} |",
        f"| commands refused (ERROR) | {fz['refused']:,} |",
        f"| ticks that started > 250 us late (a frame's handling before them) | "
        f"{fz['overruns']} of {round(fz['emulated_s'] * 1000):,} |",
        "",
        "CRC-16/CCITT detects every error of up to 3 bits and every burst of up to 16 bits in "
        "these frames, and a frame missing bytes lost on the board's receive path is dropped "
        "whatever its CRC; a random corruption otherwise passes with probability 2^-16 (about "
        "one in 65,000 damaged frames).",
        "",
    ]


def _agreement_section(agree: dict[str, Any]) -> list[str]:
    """The emulated board, the Python twin and the simulation core on one profile."""
    lines = [
        "## Agreement: emulated board, Python twin, simulation core",
        "",
        "The paper's step profile (92 -> 21 deg at 1 s, -> 92 at 10 s, 20 s) deployed with "
        "`tuners.rig.deploy`'s traffic on each, the rig without friction and noise "
        "(`gripper_env.hardware.emulator.scripted.AGREEMENT_DISTURBANCE`: whole-degree servo "
        "commands at 50 Hz, 10-bit ADC). Largest difference of the measured jaw angle, allowing "
        f"{AGREEMENT_SHIFT_MS} ms of phase (one servo frame, the pulse, one step), and at the "
        f"same instant; the quantisation budget is {agree['tolerance_deg']:.2f} deg (one degree "
        "of command, two ADC counts).",
        "",
        "| gains | pair | largest (phase allowed) | largest (same instant) | RMS |",
        "|---|---|---|---|---|",
    ]
    for name in ("tuned", "untuned"):
        g = agree[name]["gains"]
        for pair, d in agree[name]["pairs"].items():
            lines.append(
                f"| {name} ({g[0]:g}, {g[1]:g}, {g[2]:g}) | {pair} | {d['largest_deg']:.2f} deg | "
                f"{d['largest_pointwise_deg']:.2f} deg | {d['rms_deg']:.2f} deg |"
            )
    lines += [
        "",
        "At the same instant the emulated response differs by up to a servo frame's worth of "
        "motion during the fast grip: the firmware's Timer1 frames fall at another phase than the "
        "simulation's 20 ms refresh, and the servo acts at the end of a pulse.",
        "",
    ]
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.speed.firmware``."""
    parser = argparse.ArgumentParser(
        prog="python -m tuners.speed.firmware",
        description="Measure the compiled firmware on the emulated Mega 2560 (simavr) and write "
        "firmware_speed.md and .json into --out (default: runs).",
    )
    parser.add_argument(
        "--duration", type=float, default=60.0, help="closed-loop run, emulated s (default: 60)"
    )
    parser.add_argument(
        "--fuzz",
        type=int,
        default=100_000,
        help="fuzzed host frames sent to the image (default: 100000; 0: none)",
    )
    parser.add_argument("--image", default=None, help="firmware image (default: build it)")
    parser.add_argument(
        "--out",
        default="runs",
        help="output directory (default: runs; the committed figures: --out results)",
    )
    args = parser.parse_args(argv)
    if not args.duration > 0:
        parser.error(f"--duration must be > 0, got {args.duration}")
    if not 0 <= args.fuzz <= 10_000_000:
        parser.error(f"--fuzz must be 0..10000000 frames, got {args.fuzz}")
    image, harness = ensure_built(args.image, rebuild=args.image is None)
    print(f"image {image}, harness {harness}", flush=True)
    started = time.perf_counter()
    result: dict[str, Any] = {
        "duration_s": args.duration,
        "image": image_size(image),
    }
    for name, fn in (
        ("closed_loop", lambda: closed_loop(image, harness, args.duration)),
        ("pty", lambda: through_the_pty(image, harness, args.duration)),
        ("latency", lambda: latency(image, harness)),
        ("watchdog", lambda: watchdog(image, harness)),
        ("line_noise", lambda: line_noise(image, harness)),
        ("fuzz", lambda: fuzz(image, harness, args.fuzz)),
        ("agreement", lambda: agreement(image, harness)),
    ):
        if name == "fuzz" and not args.fuzz:
            continue
        t = time.perf_counter()
        result[name] = fn()
        print(f"{name}: {time.perf_counter() - t:.1f} s", flush=True)
    speeds = [r["emulated_s"] / r["wall_s"] for r in (result["closed_loop"], result["pty"])]
    result["speed_x"] = float(np.median(speeds))
    out = Path(args.out)
    text = report(result)
    command = " ".join(["python -m tuners.speed.firmware", *(sys.argv[1:] if argv is None
                                                             else argv)])  # fmt: skip
    with write_group(), collect_provenance(out, "firmware_speed", command=command, started=started):
        write_atomic(out / "firmware_speed.json",
                     json.dumps(result, indent=2, default=float) + "\n")  # fmt: skip
        write_atomic(out / "firmware_speed.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
