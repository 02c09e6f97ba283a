"""The host tools, unchanged, against the compiled firmware under simavr on a pseudo-terminal:
the launcher, tuners.rig.calibrate/record/deploy, the device library through line noise and a
reset, and GripperServoHardware-v0."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np
import pytest
from emulator_support import emulated_device
from virtual_support import REPO, gains_file, open_device, short_step_csv, true_calibration

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.hardware import protocol as proto
from gripper_env.hardware.emulator.mega2560 import EMULATED_DEVICE_ID
from gripper_env.hardware.host.errors import DeviceReset
from gripper_env.hardware.host.experiment import run_profile
from gripper_env.hardware.protocol import Mode
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.references import step_profile
from gripper_env.sim import simulate
from tuners.rig import calibrate, deploy, record
from tuners.rig.virtual import board_parser as virtual_parser
from tuners.rig.virtual import main as virtual_main

GAINS = PIDGains(1.0, 9.0, -0.001)
OPTIONS = PIDOptions(output_limits=(21.0, 92.0))
SHORT = step_profile(hold_s=0.3, grip_s=1.5, ungrip_s=1.5)  # 3.3 s


def _deploy_fit(rec) -> float:
    traj = rec.trajectory()
    sim = simulate("test2", traj.r[0], gains=[GAINS.as_array()], disturbance="actual",
                   pid_options=OPTIONS, y0_deg=float(traj.y[0, 0]))  # fmt: skip
    return float(fit_percent(traj.y[0], sim.y[0]))


@pytest.fixture
def emulated(emulator_build):
    # "max": as fast as the emulation goes, paced by the host (at most 200 ms of device time past
    # its last frame), so a loaded machine slows the board down instead of starving the host
    with emulated_device(emulator_build, speed=0) as vd:
        yield vd


def test_noise_faster_than_the_line_takes_it_is_held_back_not_fatal(emulated) -> None:
    """192 KiB of noise written at once, three times what the emulated line holds and far
    faster than its 1 Mbaud carry it: the board takes what the line can carry and the rest
    waits in the pty (flow control), as with a USB bridge; it used to stop the board."""
    import fcntl

    noise = np.random.default_rng(11).integers(1, 256, 192 * 1024, dtype=np.uint8).tobytes()
    fd = os.open(emulated.path, os.O_RDWR | os.O_NOCTTY)
    try:
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) | os.O_NONBLOCK)
        noise += b"\x00"  # the last byte ends the garbage's frame
        sent, deadline = 0, time.monotonic() + 120
        while sent < len(noise) and time.monotonic() < deadline:
            try:
                sent += os.write(fd, noise[sent : sent + 65536])
            except BlockingIOError:
                time.sleep(0.01)  # the line is full: wait, as a writer to a bridge does
        assert sent == len(noise)
    finally:
        os.close(fd)
    assert emulated.running and emulated.error is None
    with open_device(emulated) as dev:  # the board still answers
        assert dev.info.device_id == EMULATED_DEVICE_ID


def test_random_bytes_mid_run_then_a_normal_deploy(emulated) -> None:
    with open_device(emulated) as dev:
        dev.configure(GAINS, OPTIONS)
        dev.set_setpoint(60.0)
        dev.set_mode(Mode.CLOSED_LOOP)
        dev.wait_telemetry(0.2)
        garbage = np.random.default_rng(7).integers(0, 256, 4096, dtype=np.uint8).tobytes()
        dev._write(garbage)  # 4 KiB of line noise between two frames of a running session
        dev.wait_telemetry(0.3)
        status, _ = dev.heartbeat()
        assert status.bad_frame + status.bad_crc > 0 and status.faults == 0
        rec = run_profile(dev, SHORT, Mode.CLOSED_LOOP)
        assert rec.complete and rec.frames_lost == 0
    assert _deploy_fit(rec) > 90.0


def _reconnect_and_deploy(dev, emulated) -> None:
    """The same host, after a reset: handshake, configure, a whole run that fits the model."""
    info = dev.handshake()
    assert info.device_id == EMULATED_DEVICE_ID
    dev.configure(GAINS, OPTIONS)
    rec = run_profile(dev, SHORT, Mode.CLOSED_LOOP)
    assert rec.complete and rec.frames_lost == 0
    assert _deploy_fit(rec) > 90.0


def test_a_reset_mid_run_is_reported_and_the_host_reconnects(emulated) -> None:
    # The reset is triggered by the run's own progress (a quarter of the profile streamed), so
    # it lands inside the run whatever the machine's load: the emulated board runs at most
    # 200 ms of device time ahead of the host, and the profile lasts 3.3 s.
    done: list[float] = []

    def reset_a_quarter_in(fraction: float) -> None:
        if fraction >= 0.25 and not done:
            done.append(fraction)
            emulated.reset()

    with open_device(emulated) as dev:
        dev.configure(GAINS, OPTIONS)
        with pytest.raises(DeviceReset, match="reset") as raised:
            run_profile(dev, SHORT, Mode.CLOSED_LOOP, progress=reset_a_quarter_in)
        assert done and done[0] < 0.5 and emulated.resets == 1
        assert "Traceback" not in str(raised.value)
        _reconnect_and_deploy(dev, emulated)


def test_a_reset_during_the_configuration_upload_is_reported(emulated) -> None:
    # the board restarts just as the CONFIGURE frame reaches it: it has no session to take it
    with open_device(emulated) as dev:
        emulated.reset_before(proto.Configure.TYPE)
        with pytest.raises(DeviceReset, match="NO_SESSION"):
            dev.configure(GAINS, OPTIONS)
        assert emulated.resets == 1
        _reconnect_and_deploy(dev, emulated)


def test_a_reset_between_runs_is_reported_before_the_next_run_moves(emulated) -> None:
    with open_device(emulated) as dev:
        dev.configure(GAINS, OPTIONS)
        rec = run_profile(dev, SHORT, Mode.CLOSED_LOOP)
        assert rec.complete
        dev.set_mode(Mode.IDLE)
        emulated.reset()
        # the next run's first request (SET_MODE) meets a board without a session
        with pytest.raises(DeviceReset, match="reset"):
            run_profile(dev, SHORT, Mode.CLOSED_LOOP)
        assert emulated.board.mode == Mode.IDLE
        _reconnect_and_deploy(dev, emulated)


def test_the_launcher_and_the_hardware_commands(emulator_build, tmp_path, capsys) -> None:
    # the launcher as a user starts it; the commands' own main(), in this process (their process
    # start-up is tests/hardware/test_hw_cli.py's business)
    image, harness = emulator_build
    env = dict(os.environ, PYTHONPATH=str(REPO), GRIPPER_EMULATOR_LIB=str(harness))
    launcher = subprocess.Popen(
        [sys.executable, "-m", "tuners.rig.virtual", "--emulated", "--image", str(image),
         "--speed", "max", "--seed", "5"],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        port = launcher.stdout.readline().strip()
        assert port.startswith("/dev/"), launcher.stderr.read()
        wait = ("--port", port, "--boot-wait", "0")
        cal = tmp_path / "calibration.json"
        assert (
            calibrate.main([*wait, "--output", str(cal), "--settle", "0.8", "--average", "0.2"])
            == 0
        )
        content = json.loads(cal.read_text())
        assert content["device_id"] == EMULATED_DEVICE_ID
        # 0.264 deg per count on the rig's ADC: the jaw's ends within a few counts of the truth
        assert abs(content["adc_at_21_deg"] - 21 / 0.2639) < 4
        assert abs(content["adc_at_92_deg"] - 92 / 0.2639) < 4
        profile = short_step_csv(tmp_path / "step.csv", 0.3, 1.8, 3.0)
        log = tmp_path / "record.csv"
        argv = [*wait, "--calibration", str(cal), "--profile", profile, "--output", str(log)]
        assert record.main(argv) == 0
        data = np.genfromtxt(log, delimiter=",", names=True)
        assert len(data) >= 2990 and abs(data["actual_deg"][-1] - 92.0) < 2.0
        gains = gains_file(tmp_path / "gains.json", 1.0, 9.0, -0.001)
        argv = ["--gains", gains, *wait, "--calibration", str(cal), "--profile", profile,
                "--output-dir", str(tmp_path / "out"), "--no-plot"]  # fmt: skip
        assert deploy.main(argv) == 0, capsys.readouterr().err
        report = json.loads((tmp_path / "out" / "report.json").read_text())
        assert report["fit_pct"] > 90.0 and report["link"]["frames_lost"] == 0
    finally:
        launcher.send_signal(signal.SIGTERM)
        _out, err = launcher.communicate(timeout=10)
    assert launcher.returncode == 0, err
    assert "firmware image" in err


@pytest.mark.filterwarnings("ignore::gripper_env.envs.servo_hardware.MissedDeadlineWarning")
def test_the_hardware_environment_runs_on_the_emulated_board(emulator_build) -> None:
    # real time, as the environment's 20 ms control period wants; a late step on a loaded
    # machine is the host's lateness (warned), not the firmware's
    with emulated_device(emulator_build, speed=1.0) as vd:
        env = gym.make("gripper_env/GripperServoHardware-v0", port=vd.path,
                       calibration=true_calibration(vd), boot_wait_s=0.0)  # fmt: skip
        obs, _ = env.reset(seed=0)
        assert obs in env.observation_space
        for _ in range(10):
            obs, reward, terminated, _, _ = env.step(np.array([-0.6], np.float32))
            assert not terminated and np.isfinite(reward)
        env.close()
        time.sleep(0.05)
        assert vd.board.mode == Mode.IDLE  # the environment left the board idle (open)


def test_a_missing_image_is_a_clear_error(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        virtual_main(["--image", str(tmp_path / "none.elf")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "no firmware image at" in err and "Traceback" not in err


def test_the_info_of_the_emulated_board_on_the_pty(emulated) -> None:
    with open_device(emulated) as dev:
        assert dev.info.device_id == EMULATED_DEVICE_ID
        status, _ = dev.heartbeat()
        assert status.flags & proto.StatusFlag.SESSION


def test_the_launcher_documents_every_flag() -> None:
    parser = virtual_parser()
    text = parser.format_help()
    assert parser.prog == "python -m tuners.rig.virtual"
    assert {"--emulated", "--image", "--rebuild"} <= set(parser._option_string_actions)
    for action in parser._actions:
        assert action.help, action.option_strings
        for option in action.option_strings:
            assert option in text
    assert {"--image", "--rebuild", "--speed", "--plant"} <= set(parser._option_string_actions)
