"""Link and device faults against the virtual board: each gives its error or a recovery, the log
written so far is kept, and nothing hangs (every wait is bounded by the device's timeouts)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest
from virtual_support import SPEED, open_device, short_step

from gripper_env.hardware import protocol as proto
from gripper_env.hardware.host.device import HANDSHAKE_PATIENCE_S
from gripper_env.hardware.host.errors import (
    DeviceReset,
    DeviceTimeout,
    LinkError,
    PortVanished,
)
from gripper_env.hardware.host.experiment import CsvLog, run_profile
from gripper_env.hardware.protocol import Mode
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.model.references import step_profile


@pytest.fixture
def virtual() -> Iterator[VirtualDevice]:
    with VirtualDevice("test2", "actual", speed=SPEED, seed=1) as vd:
        yield vd


def _rows(block, t0_us):
    return np.column_stack([(block.t_us - t0_us) / 1e6, block.reference_deg, block.position_deg])


def _fault_during_run(dev, vd, tmp_path, fault, after_s: float = 0.6):
    """Start a long open-loop run and trigger ``fault`` once the run itself has streamed
    ``after_s`` of its profile (the run's own progress, so the fault lands inside the run)."""
    log = CsvLog(tmp_path / "run.csv", ("t_s", "desired_deg", "actual_deg"), _rows)
    profile = step_profile()
    fired: list[float] = []

    def trigger(fraction: float) -> None:
        if not fired and fraction * profile.duration_s >= after_s:
            fired.append(fraction)
            fault()

    run_profile(dev, profile, Mode.OPEN_LOOP, log=log, progress=trigger)
    return log


def test_garbage_between_frames_is_skipped(virtual) -> None:
    with open_device(virtual) as dev:
        for k in range(10):
            virtual.inject_garbage(bytes([0xFF, 0x13, 0x55, 7 + k]) * 5 + b"\x00")
            status, _rtt = dev.heartbeat()
            assert status.echo == dev._token
        assert dev.decoder.stats.discarded_bytes > 0


def test_a_truncated_reply_is_resent(virtual) -> None:
    with open_device(virtual) as dev:
        virtual.truncate_frames(1)
        dev.heartbeat()  # the first STATUS is cut short: the host retries
        assert dev.decoder.stats.truncated == 1


def test_one_corrupted_crc_recovers_and_persistent_corruption_is_a_link_error(virtual) -> None:
    # the retry's reply may take a while on a loaded machine (the board's thread unscheduled):
    # a generous timeout, which the persistent corruption below waits out twice
    with open_device(virtual, retries=1, timeout_s=2.0) as dev:
        virtual.corrupt_frames(1)
        dev.heartbeat()
        assert dev.decoder.stats.bad_crc == 1
        dev.configure(decimation=0)  # no telemetry: only replies are corrupted now
        virtual.corrupt_frames(1000)
        with pytest.raises(LinkError, match=r"corrupted frames.*CRC mismatch"):
            dev.heartbeat()
        virtual.corrupt_frames(-virtual._corrupt)  # disarm for the safe exit


def test_a_silent_device_times_out(virtual) -> None:
    with open_device(virtual, retries=1, timeout_s=0.2) as dev:
        virtual.go_silent()
        with pytest.raises(DeviceTimeout, match=r"HEARTBEAT.*silent"):
            dev.heartbeat()
        virtual.go_silent(False)


def test_lost_telemetry_frames_are_counted(virtual) -> None:
    with open_device(virtual) as dev:
        dev.wait_telemetry(0.05)
        virtual.drop_frames(3)
        # a loss shows when a later frame arrives: wait for one however slow the machine is
        deadline = time.monotonic() + 30.0
        while dev.decoder.stats.lost < 3 and time.monotonic() < deadline:
            dev.wait_telemetry(0.05)
        dev.wait_telemetry(0.05)
        assert dev.decoder.stats.lost >= 3
        assert dev.samples_missing >= 20


def test_a_reset_mid_run_is_reported_and_the_partial_log_kept(virtual, tmp_path) -> None:
    with open_device(virtual) as dev:
        dev.configure()
        with pytest.raises(DeviceReset, match="reset"):
            _fault_during_run(dev, virtual, tmp_path, virtual.reset)
        log = tmp_path / "run.partial.csv"
        assert log.exists() and not (tmp_path / "run.csv").exists()
        rows = log.read_text().splitlines()
        assert rows[0] == "t_s,desired_deg,actual_deg" and len(rows) > 400
    # the board came back with no session: the safe exit sent ESTOP, which it honours anyway
    assert virtual.wait_ticks(5)
    assert virtual.firmware.mode == Mode.IDLE
    assert virtual.firmware.faults & proto.Fault.ESTOP


def test_a_vanished_port_is_reported_and_the_partial_log_kept(virtual, tmp_path) -> None:
    dev = open_device(virtual)
    with pytest.raises(PortVanished, match="went away"), dev:
        dev.configure()
        _fault_during_run(dev, virtual, tmp_path, virtual.vanish)
    assert not dev.is_open
    rows = (tmp_path / "run.partial.csv").read_text().splitlines()
    assert len(rows) > 400


def test_a_board_slower_than_the_timeout_is_no_reset(virtual) -> None:
    """The board answers the handshake after the host's timeout (a busy machine, a slow USB
    bridge): the host sends HELLO again, and the INFO that answers it arrives after the session
    has started. That is the late answer to its own HELLO, not a reset ("sent INFO unasked"):
    the session goes on and a run completes."""
    # INFO 0.7 s late (after the 0.5 s timeout: HELLO is sent again), the INFO answering that
    # HELLO later still: it comes after the session has started, behind the next answers
    virtual.delay_frames(0.7, 0.9)
    with open_device(virtual) as dev:
        assert dev._hellos_sent >= 2
        dev.configure()
        rec = run_profile(dev, short_step(), Mode.OPEN_LOOP)
        assert rec.complete
        assert dev._late_infos == 0  # every late INFO arrived and was recognised


def test_a_board_silent_for_two_seconds_after_the_port_opens_is_waited_for(virtual) -> None:
    """The first answers after the port opens come 2 s late (a virtual board on a loaded
    machine once took longer than 3 HELLOs of 0.5 s): the handshake keeps sending HELLO for
    HANDSHAKE_PATIENCE_S, takes the first INFO, recognises the late ones, and a run completes."""
    assert HANDSHAKE_PATIENCE_S > 2.5
    virtual.delay_frames(2.0, 2.0, 2.0, 2.0)
    with open_device(virtual) as dev:  # tries widening 0.5, 1, 2 s: the third is answered
        assert dev._hellos_sent >= 3  # (3 fixed tries of 0.5 s gave up after 1.5 s)
        dev.configure()
        rec = run_profile(dev, short_step(), Mode.OPEN_LOOP)
        assert rec.complete
        assert dev._late_infos == 0


def test_a_board_thread_left_waiting_catches_up_at_most_a_tenth_of_a_second() -> None:
    """At real-time speed, the ticks a board's thread missed while the machine left it waiting
    run in a burst of at most MAX_CATCH_UP_S; a longer wait makes device time slip instead."""
    from gripper_env.hardware.virtual import MAX_CATCH_UP_S

    vd = VirtualDevice("test2", "ideal", speed=1.0)  # not started: its pacing alone
    vd._t0, vd.ticks = 100.0, 0
    assert vd.due_ticks(100.05) == pytest.approx(50)
    assert vd.due_ticks(103.0) == pytest.approx(1000 * MAX_CATCH_UP_S)  # waited 3 s
    assert vd.slipped_s == pytest.approx(3.0 - MAX_CATCH_UP_S)
    vd.ticks = 100
    assert vd.due_ticks(103.0) == pytest.approx(0, abs=1e-6)


def test_a_board_thread_left_waiting_does_not_trip_its_watchdog_on_a_live_host() -> None:
    """The board's thread waits 2 s (a busy machine) in the middle of a run at real-time
    speed, while the host keeps sending: the board does not squeeze 2 s of ticks into a
    burst that the host could not answer (the watchdog's safe stop in tuners.rig.record)."""
    with VirtualDevice("test2", "actual", speed=1.0, seed=3) as vd:
        with open_device(vd, timeout_s=3.0) as dev:
            dev.configure(decimation=10)  # 100 Hz telemetry: a host that keeps up, even here
            profile = short_step()
            stalled: list[float] = []

            def stall(fraction: float) -> None:
                if not stalled and fraction * profile.duration_s >= 1.0:
                    stalled.append(fraction)
                    vd.stall(2.0)

            rec = run_profile(dev, profile, Mode.OPEN_LOOP, progress=stall)
            assert rec.complete and stalled
        assert vd.slipped_s >= 1.5
