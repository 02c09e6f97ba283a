"""Deploy PID gains to the virtual board and measure the response, host in the loop.

:class:`gripper_env.hardware.virtual.VirtualDevice` is a board on a pseudo-terminal: the firmware's
Python twin (same frames, modes, watchdog, 1 kHz telemetry, PID) driving the simulated actual
gripper. The host side is what talks to the real Arduino too:

1. :class:`gripper_env.hardware.host.device.GripperDevice` opens the port (handshake, version
   check) with a calibration (here the virtual rig's exact one);
2. the stability gate (:func:`gripper_env.evaluation.stability.stability_report`): the loop as
   the board runs it, PID at 1 ms and the servo's command held 20 ms;
3. ``configure`` sends the gains and limits, and
   :func:`gripper_env.hardware.host.experiment.run_profile` streams a short grip/un-grip step in
   closed loop on the board's PID and records the telemetry;
4. the measured response is scored with the project's metrics and compared with the
   simulation's prediction, as ``python -m tuners.rig.deploy`` does.

Run::

    python examples/deploy_virtual.py                      # the paper's tuned gains on test2
    python examples/deploy_virtual.py --gains out/test2/optuna.json   # a gains file
    python examples/deploy_virtual.py --speed 1            # device time at wall-clock speed

At ``--speed 0`` device time runs as fast as the host keeps up, so where the host's 50 Hz
setpoints land depends on its scheduling and the numbers vary a little from run to run (as on a
real board). For a real board, give ``GripperDevice`` its port (``/dev/ttyACM0``), a measured
calibration (``python -m tuners.rig.calibrate``) and ``boot_wait_s=2``.
"""

from __future__ import annotations

import argparse
import math

from gripper_env.evaluation.metrics import compute_metrics
from gripper_env.evaluation.stability import stability_report
from gripper_env.hardware.host.calibration import Calibration
from gripper_env.hardware.host.device import GripperDevice
from gripper_env.hardware.host.experiment import run_profile
from gripper_env.hardware.protocol import Mode
from gripper_env.hardware.virtual import VirtualDevice
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.gains_file import load_gains_file
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import step_profile
from gripper_env.paper import PID_GAINS
from tuners.rig.deploy import prediction


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--gains", default=None, help="a gains file (default: the paper's tuned gains on test2)"
    )
    parser.add_argument(
        "--speed", type=float, default=0.0, help="device time per wall time (0: as fast as it goes)"
    )
    parser.add_argument("--seed", type=int, default=3, help="noise seed of the virtual rig")
    args = parser.parse_args(argv)

    if args.gains is None:
        plant, gains = "test2", PIDGains(*PID_GAINS["tuned_tf"])
        options = PIDOptions(output_limits=(21.0, 92.0), anti_windup="clamping")
        label, model = "the paper's tuned gains", load_plant(plant)
    else:
        loaded = load_gains_file(args.gains)
        plant, gains, options, label = loaded.plant, loaded.gains, loaded.options, args.gains
        model = loaded.plant_model()  # the transfer function the gains were tuned on

    # the gate: refuse gains whose loop, as the board runs it (the actual servo's 20 ms command
    # hold and sensor delay), is unstable
    report = stability_report(model, gains, options.sign, disturbance=load_disturbance("actual"))
    gm = report.gain_margin_db
    print(
        f"gate: {label} on {plant} are {'stable' if report.stable else 'UNSTABLE'} with the "
        f"servo's hold (GM {'inf' if gm is None else f'{gm:.1f}'} dB, Ms {report.ms:.2f})"
    )
    if not report.stable:
        return 1

    reference = step_profile(hold_s=0.5, grip_s=3.0, ungrip_s=3.0)  # 6.5 s grip and un-grip
    with VirtualDevice(plant, "actual", speed=args.speed, seed=args.seed) as board:
        low, high = board.rig.true_calibration  # ADC counts at the jaw's two ends
        calibration = Calibration(low, high, port=board.path)
        with GripperDevice(board.path, calibration=calibration, boot_wait_s=0.0) as device:
            info = device.info
            assert info is not None
            print(
                f"board at {board.path}: firmware {info.fw_major}.{info.fw_minor}."
                f"{info.fw_patch}, protocol {info.protocol_version}, tick "
                f"{info.tick_period_us} us"
            )
            device.configure(gains, options)
            recording = run_profile(device, reference, Mode.CLOSED_LOOP)
        # leaving the block stopped the board at its safe (open) position

    measured = recording.trajectory()
    _, fit = prediction(model, measured, gains, options, "actual")  # the simulation's view
    m = compute_metrics(measured).as_dict()
    print(
        f"run: {len(recording.samples)} samples, complete {recording.complete}, "
        f"{recording.frames_lost} frames lost"
    )
    for move in ("grip", "ungrip"):
        settling = m[move]["settling_time_s"]  # inf: not within the band by the move's end
        print(
            f"{move}: overshoot {m[move]['overshoot_pct']:.1f} %, rise {m[move]['rise_time_s']:.3f}"
            f" s, {'not settled' if math.isinf(settling) else f'settled in {settling:.2f} s'}"
        )
    print(f"IAE {m['iae']:.2f} deg*s, SD gap {m['sd_gap_deg']:.2f} deg; fit {fit:.1f} % to the "
          "simulation's prediction")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
