"""Helpers of the bus commands' tests: an SO-101-like arm on a virtual bus (six servos of one
family, the gripper at ID 6 with its position limits narrower than the factory's, as LeRobot's
calibration writes them, and its registers as a LeRobot session leaves them); the vendors' SDKs
as the independent reader of every register; the commands as subprocesses."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import dynamixel_sdk
import pytest
import scservo_sdk

from gripper_env.hardware.bus.control_table import ControlTable
from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.tables import get_spec
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.model.bus_servo import BusServoModel, load_bus_servo
from tuners.bus.virtual import LEROBOT_GRIPPER

ROOT = Path(__file__).resolve().parents[3]
GRIPPER = 6
OTHERS = (1, 2, 3, 4, 5)
#: The gripper's position limits (ticks): the factory's are 0-4095.
LIMITS = (1750, 2950)
#: The jaw's closed and open positions (ticks), inside the limits.
CLOSED, OPEN = 1760, 2940
#: The open position a session finds the gripper holding (ticks; 240 deg, the shipped jaw's).
HOLDING = 2731

#: The gripper's registers as found, by field name: on the STS3215 LeRobot's SO follower's
#: (``python -m tuners.bus.virtual --lerobot``'s: P 16, Acceleration 254, the torque limit cut to
#: 50 %, ``Overload_Torque`` 25 %, ``Protection_Current`` 250, in flash too, since LeRobot
#: writes them with the torque off, under Lock 0; the torque on and locked); a Koch-like set on
#: the XL330.
FOUND = {
    "sts3215": {**LEROBOT_GRIPPER["sts3215"], "lock": 1},
    "xl330": {"position_p_gain": 800, "position_d_gain": 200, "position_i_gain": 0,
              "goal_pwm": 600, "profile_acceleration": 0},
}  # fmt: skip


def registers_within_protection(family: str, folder: Path) -> Path:
    """The committed tuned registers of ``family`` (``results/bus``, tuned on the shipped model)
    with the torque limit cut to hold under the found ``Overload_Torque`` (LeRobot's 25 % on
    the STS3215), written into ``folder``: what a deploy on the arm's gripper passes the gate
    with."""
    doc = json.loads((ROOT / f"results/bus/{family}_registers.json").read_text())
    overload = FOUND[family].get("overload_torque")
    if overload is not None:
        doc["registers"]["torque_limit"] = min(doc["registers"]["torque_limit"], overload * 10 - 10)
    path = folder / f"{family}_registers.json"
    path.write_text(json.dumps(doc))
    return path


def gripper_table(family: str) -> ControlTable:
    """ID 6 as found: the limits written to flash as the host writes them, the loop's
    registers set, the torque on, holding :data:`HOLDING`."""
    table = ControlTable(family, GRIPPER)
    spec = table.spec
    for role, value in (("min_position", LIMITS[0]), ("max_position", LIMITS[1])):
        f = spec.role(role)
        assert table.write(f.address, f.encode(value)) == 0
    for name, value in FOUND[family].items():  # as LeRobot writes them: under Lock 0, saved
        table.store(name, value)
    table.set_role("goal_position", HOLDING)
    table.set_role("torque_enable", 1)
    return table


@contextmanager
def arm_bus(
    family: str, truth: BusServoModel | None = None, object_deg: float | None = None
) -> Iterator[VirtualBus]:
    """Six servos of ``family``; ID 6 runs ``truth`` (default the shipped model) with its shaft
    at :data:`HOLDING`, the others mirror their goals."""
    model = truth or load_bus_servo(family)
    unit = ServoUnit(model, angle_deg=HOLDING * 360 / 4096, object_deg=object_deg)
    with VirtualBus(family, ids=[*OTHERS, gripper_table(family)], physics={GRIPPER: unit}) as bus:
        yield bus


def sdk_registers(port: str, family: str, servo_id: int = GRIPPER) -> dict[str, bytes]:
    """Every writable register of a servo, read with its vendor's SDK (raw bytes by name)."""
    spec = get_spec(family)
    feetech = spec.protocol == "feetech"
    sdk = scservo_sdk if feetech else dynamixel_sdk
    port_handler = sdk.PortHandler(port)
    packets = sdk.PacketHandler(0) if feetech else sdk.PacketHandler(2.0)
    assert port_handler.openPort() and port_handler.setBaudRate(1_000_000 if feetech else 57_600)
    out = {}
    try:
        for f in spec.fields:
            if not f.writable:
                continue
            for _ in range(5):  # a loaded host may miss a reply: ask again, once it is drained
                port_handler.ser.reset_input_buffer()
                data, result, _error = packets.readTxRx(port_handler, servo_id, f.address, f.size)
                if result == sdk.COMM_SUCCESS and len(data) == f.size:
                    break
                time.sleep(0.05)  # a late reply must not pass for the next one's
            assert result == sdk.COMM_SUCCESS, (f.name, packets.getTxRxResult(result))
            out[f.name] = bytes(data)
    finally:
        port_handler.closePort()
    return out


def command(
    module: str, *args: str, stdin: int | None = subprocess.DEVNULL, cwd: Path | None = None
) -> subprocess.Popen:
    """``python -m module args`` from ``cwd`` (default the repository's root), its output
    captured."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg"}
    return subprocess.Popen(
        [sys.executable, "-m", module, *args],
        cwd=ROOT if cwd is None else cwd,
        env=env,
        stdin=stdin,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def at_packet(bus: VirtualBus, kind: str, count: int, act: Callable[[], None]) -> dict[str, int]:
    """Call ``act`` in the bus thread when the gripper receives its ``count``-th (1-based)
    instruction of ``kind`` from now on: ``"packet"`` (any), ``"write"`` (a WRITE) or
    ``"goal"`` (a WRITE of the goal position), before the reply goes out. An observable event,
    so the moment does not depend on how fast a loaded host runs. Returns the counts
    (``acted`` is 1 once ``act`` ran)."""
    goal = bus.spec.role("goal_position").address
    feetech = bus.spec.protocol == "feetech"
    state = {"seen": 0, "acted": 0}

    def watch(packet) -> None:
        if packet.id != GRIPPER or state["acted"]:
            return
        write = packet.instruction == 0x03 and len(packet.params) > 2  # WRITE on both protocols
        if write:
            address = packet.params[0] if feetech else int.from_bytes(packet.params[:2], "little")
        if kind == "packet" or (write and (kind == "write" or address == goal)):
            state["seen"] += 1
            if state["seen"] == count:
                state["acted"] = 1
                act()

    bus.on_packet = watch
    return state


def finish(proc: subprocess.Popen, timeout_s: float = 300.0) -> tuple[int, str, str]:
    """Wait for the command; its status, stdout and stderr."""
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(f"the command did not end:\n{out}\n{err}")
    return proc.returncode, out, err
