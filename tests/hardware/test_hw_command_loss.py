"""Host commands lost on the way to the virtual board: each one the board reports is sent again or
was superseded, a mode never starts from a lost setpoint, and a command that cannot get through
fails loudly (CommandLost)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from virtual_support import open_device

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.command_log import CommandLog
from gripper_env.hardware.host.errors import CommandLost
from gripper_env.hardware.host.experiment import run_profile
from gripper_env.hardware.protocol import Mode
from gripper_env.model.references import Reference


def test_a_lost_setpoint_is_sent_again_before_the_mode_starts(virtual_twin) -> None:
    with open_device(virtual_twin) as dev:
        dev.configure()
        virtual_twin.lose_host_frames(proto.Setpoint.TYPE, 1)
        dev.set_setpoint(40.0)  # lost on the way: the board still holds no setpoint
        status = dev.set_mode(Mode.OPEN_LOOP)
        assert virtual_twin.host_frames_lost == 1
        assert status.mode == Mode.OPEN_LOOP and status.setpoint_deg == 40.0
        assert dev.commands.lost >= 1 and dev.commands.resent >= 1
        dev.wait_telemetry(0.1)
        assert virtual_twin.firmware.command == 40.0  # not the safe position it would hold


def test_a_lost_mode_change_is_sent_again(virtual_twin) -> None:
    with open_device(virtual_twin) as dev:
        dev.configure()
        dev.set_setpoint(50.0, confirm=True)
        virtual_twin.lose_host_frames(proto.SetMode.TYPE, 1)
        assert dev.set_mode(Mode.OPEN_LOOP).mode == Mode.OPEN_LOOP
        assert virtual_twin.host_frames_lost == 1 and dev.commands.lost == 1
        dev.wait_telemetry(0.05)
        assert (
            virtual_twin.firmware.mode == Mode.OPEN_LOOP and virtual_twin.firmware.command == 50.0
        )


def test_a_setpoint_that_never_arrives_fails_loudly(virtual_twin) -> None:
    with open_device(virtual_twin, retries=2, timeout_s=1.0) as dev:  # replies late under load
        dev.configure()
        virtual_twin.lose_host_frames(proto.Setpoint.TYPE, 100)
        with pytest.raises(CommandLost, match=r"does not hold SETPOINT 33 deg after 3 tries"):
            dev.set_setpoint(33.0, confirm=True)
        with pytest.raises(CommandLost, match="SETPOINT 33 deg"):
            dev.set_mode(Mode.OPEN_LOOP)  # not started from a setpoint the board lacks
        assert virtual_twin.firmware.mode == Mode.IDLE
        virtual_twin.lose_host_frames(proto.Setpoint.TYPE, 0)


def test_streamed_setpoints_lost_mid_run_are_reported_and_the_run_follows_the_profile(
    virtual_twin,
) -> None:
    values = np.concatenate([np.full(300, 60.0), np.linspace(60.0, 30.0, 400), np.full(300, 30.0)])
    profile = Reference("ramp", 1e-3, values)
    fired: list[float] = []

    def lose_some(fraction: float) -> None:
        if not fired and fraction > 0.35:
            fired.append(fraction)
            virtual_twin.lose_host_frames(proto.Setpoint.TYPE, 3)

    with open_device(virtual_twin) as dev:
        dev.configure()
        rec = run_profile(dev, profile, Mode.OPEN_LOOP, progress=lose_some)
    assert rec.complete and virtual_twin.host_frames_lost == 3
    # every lost setpoint was reported by the board: sent again, or replaced by the next one
    assert rec.commands_lost == 3
    assert rec.commands_resent + dev.commands.superseded == 3
    # and the board ends on the profile's last value
    ref = rec.samples.reference_deg
    assert math.isclose(ref[-1], 30.0, abs_tol=0.01)


def test_the_command_log_resends_only_the_current_setpoint_and_estops() -> None:
    log = CommandLog()
    for seq, msg in enumerate(
        [proto.Setpoint(40.0), proto.Heartbeat(1), proto.Setpoint(41.0), proto.Estop()]
    ):
        log.sent(250 + seq, msg)  # 250..253
    report = proto.ErrorReport(proto.ErrorCode.FRAMES_LOST, 0, 250, 4)
    assert log.to_resend(report) == [proto.Setpoint(41.0), proto.Estop()]
    assert (log.lost, log.resent, log.superseded) == (4, 2, 1)
    refusal = proto.ErrorReport(proto.ErrorCode.BAD_VALUE, proto.Setpoint.TYPE, 252, 0)
    assert log.to_resend(refusal) == []
    log.sent(255, proto.Setpoint(42.0))
    log.sent(0, proto.Setpoint(43.0))  # the sequence wraps
    assert log.to_resend(proto.ErrorReport(proto.ErrorCode.FRAMES_LOST, 0, 255, 2)) == [
        proto.Setpoint(43.0)
    ]
