"""End to end over a pseudo-terminal: GripperDevice against the virtual board and its rig."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest
from virtual_support import SPEED, open_device, short_step

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.errors import DeviceFault, DeviceRefused, VersionMismatch
from gripper_env.hardware.host.experiment import CsvLog, run_profile
from gripper_env.hardware.protocol import Fault, Mode
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.sim import simulate

GAINS = PIDGains(1.0, 9.0, -0.001)  # the paper's tuned gains on test2
OPTIONS = PIDOptions(output_limits=(21.0, 92.0))


@pytest.fixture
def virtual() -> Iterator[VirtualDevice]:
    with VirtualDevice("test2", "actual", speed=SPEED, seed=3) as vd:
        yield vd


def test_handshake_reports_the_firmware_and_refuses_another_version(virtual) -> None:
    with open_device(virtual) as dev:
        assert dev.info is not None
        assert dev.info.protocol_version == proto.PROTOCOL_VERSION
        assert dev.info.device_id == virtual.device_id
        assert dev.info.tick_period_us == 1000
        status, rtt = dev.heartbeat()
        assert status.flags & proto.StatusFlag.SESSION and 0 < rtt < 0.5
        with pytest.raises(VersionMismatch, match="protocol version 3"):
            dev._request(proto.Hello(protocol_version=1), proto.Info)


def test_open_loop_step_matches_the_simulation(virtual, tmp_path) -> None:
    with open_device(virtual) as dev:
        dev.configure()
        log = CsvLog(tmp_path / "ol.csv", ("t_s", "desired_deg", "actual_deg"), _rows)
        rec = run_profile(dev, short_step(), Mode.OPEN_LOOP, log=log)
    assert rec.complete and (tmp_path / "ol.csv").exists()
    assert not (tmp_path / "ol.partial.csv").exists()
    traj = rec.trajectory()
    sim = simulate("test2", traj.r[0], gains=None, disturbance="actual", seeds=3)
    fit = float(fit_percent(traj.y[0], sim.y[0]))
    assert fit > 90.0, fit
    # The servo command in open loop is the setpoint itself.
    assert np.nanmax(np.abs(traj.u[0] - traj.r[0])) < 0.011


def _rows(block, t0_us):
    return np.column_stack([(block.t_us - t0_us) / 1e6, block.reference_deg, block.position_deg])


def test_closed_loop_step_on_the_board_pid_matches_the_simulation(virtual) -> None:
    with open_device(virtual) as dev:
        dev.configure(GAINS, OPTIONS)
        rec = run_profile(dev, short_step(), Mode.CLOSED_LOOP)
        assert rec.frames_lost == 0
    traj = rec.trajectory()
    sim = simulate(
        "test2", traj.r[0], gains=[GAINS.as_array()], disturbance="actual", pid_options=OPTIONS
    )
    fit = float(fit_percent(traj.y[0], sim.y[0]))
    assert fit > 90.0, fit
    assert traj.missing_samples == 0
    # context manager: the board is left idle at the safe (open) position
    assert virtual.wait_ticks(5)
    assert virtual.firmware.mode == Mode.IDLE and virtual.firmware.command == 92.0


def test_watchdog_host_silent_moves_the_jaw_to_the_safe_position(virtual) -> None:
    with open_device(virtual) as dev:
        dev.configure()
        dev.set_setpoint(40.0)
        dev.set_mode(Mode.OPEN_LOOP)
        dev.wait_telemetry(0.3)  # heartbeats keep it alive
        assert virtual.firmware.mode == Mode.OPEN_LOOP
        # The host goes silent: no frame for 500 ms of device time.
        deadline = time.monotonic() + 5.0
        with pytest.raises(DeviceFault, match="WATCHDOG") as info:
            while time.monotonic() < deadline:
                dev.poll(0.01)
        assert info.value.faults & Fault.WATCHDOG
        dev.read_telemetry()
        last = dev.wait_telemetry(0.1, heartbeat_s=0)
        last = last.flags[-50:], last.command_deg[-50:]  # the batch in flight may predate it
        assert np.all(last[0] & proto.SampleFlag.MODE_MASK == Mode.IDLE)
        assert np.all(last[0] & proto.SampleFlag.FAULT)
        assert np.all(last[1] == 92.0)
        assert virtual.firmware.faults & Fault.WATCHDOG
    # leaving the block acknowledged the fault and left the board idle and open
    assert virtual.wait_ticks(5)
    assert virtual.firmware.faults == 0 and virtual.firmware.command == 92.0


def test_estop_latches_until_idle(virtual) -> None:
    with open_device(virtual) as dev:
        dev.configure()
        dev.set_mode(Mode.OPEN_LOOP)
        dev.estop()
        dev.wait_telemetry(0.05, heartbeat_s=0)
        with pytest.raises(DeviceRefused, match=r"FAULT_LATCHED.*ESTOP"):
            dev.set_mode(Mode.OPEN_LOOP)
        dev.set_mode(Mode.IDLE)
        dev.set_mode(Mode.OPEN_LOOP)


def test_bad_configuration_is_refused_with_the_field_name(virtual) -> None:
    with open_device(virtual) as dev:
        # the board's hard limits (INFO), checked by the host before anything is sent
        with pytest.raises(ValueError, match=r"jaw_deg 21\.\.200 deg .* hard range 21\.\.92 deg"):
            dev.configure(jaw_deg=(21.0, 200.0))
        with pytest.raises(ValueError, match=r"servo_us 2400/544 gives 21 deg a pulse of 2183\.5"):
            dev.configure(servo_us=(2400, 544))
        # and by the board, whatever the host: the refusal names the field
        with pytest.raises(DeviceRefused, match="field jaw_max"):
            dev._request(proto.Configure(jaw_max=200.0), proto.Status)
        with pytest.raises(DeviceRefused, match="field decimation"):
            dev.configure(decimation=5000)
        with pytest.raises(DeviceRefused, match="NOT_CONFIGURED"):
            dev.set_mode(Mode.CLOSED_LOOP)


def test_the_context_manager_stops_the_board_on_an_exception(virtual) -> None:
    with pytest.raises(RuntimeError, match="boom"), open_device(virtual) as dev:
        dev.configure()
        dev.set_setpoint(30.0)
        dev.set_mode(Mode.OPEN_LOOP)
        dev.wait_telemetry(0.2)
        assert virtual.firmware.command == 30.0
        raise RuntimeError("boom")
    assert virtual.wait_ticks(5)
    assert virtual.firmware.mode == Mode.IDLE and virtual.firmware.command == 92.0
