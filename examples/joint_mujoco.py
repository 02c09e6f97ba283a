"""Identify an SO-101 joint under gravity on the virtual bus, tune it, export it, run it in MuJoCo.

The virtual SO-101 (:class:`gripper_env.hardware.bus.arm.VirtualArm`: six STS3215s on one
pseudo-terminal, every joint under the weight of the links beyond it, 50 g in the gripper) stands
for the arm. On its elbow:

1. **record** small steps around the pose the elbow holds, at LeRobot's registers and at P
   doubled, the neighbours held by their own servos and never addressed
   (:func:`gripper_env.sysid.bus_load.record_load`; the elbow's registers restored after);
2. **identify** the load from the records: gravity's amplitude and hang angle, the links'
   inertia, the payload, with standard errors (:func:`~gripper_env.sysid.bus_load.identify_load`);
3. **tune** P, I, D and the torque limit against it, 0-100 g
   (:func:`tuners.bus.tune.tune_registers` with :func:`~gripper_env.evaluation.bus_load.
   judge_loaded`), beside LeRobot's P 16;
4. **export** the tuned servo to MuJoCo: the project's MJCF of the SO-101 (no meshes) with the
   elbow driven by the exact runtime (the register loop at 1 kHz, :class:`~gripper_env.mujoco.
   runtime.ExactServo`) and, apart, by the native class (MuJoCo's position actuator, kp and kv
   fitted to the register loop), the other joints fixed at the pose;
5. **compare** the three responses to a step profile (the virtual servo's core, the exact
   runtime, the native class) and plot them with ``--out DIR``.

Run::

    python examples/joint_mujoco.py --out runs/joint-example       # 2-4 minutes (the record
                                                                    # runs in real time)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--payload", type=float, default=0.05, help="kg in the gripper (0.05)")
    parser.add_argument("--trials", type=int, default=60, help="tuner's TPE trials (60)")
    parser.add_argument("--polish", type=int, default=120, help="tuner's local budget (120)")
    parser.add_argument("--out", type=Path, default=None, help="folder for the plot")
    args = parser.parse_args(argv)

    import mujoco

    from gripper_env.evaluation.bus_load import judge_loaded
    from gripper_env.hardware.bus.arm import VirtualArm, arm_registers
    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.model.so101_arm import joint_model, load_arm, q_of_shaft
    from gripper_env.mujoco.arm import arm_mjcf
    from gripper_env.mujoco.runtime import ExactServo
    from gripper_env.mujoco.servo_class import fill_history, fit_native_gains
    from gripper_env.mujoco.verify import recipe_profiles, rms_deg, run_core
    from gripper_env.sim.bus_servo import simulate_bus
    from gripper_env.sysid.bus_load import identify_load, record_load
    from tuners.bus.tune import tune_registers

    servo = load_bus_servo("sts3215")
    arm = load_arm()
    joint = "elbow_flex"

    # 1. record on the virtual arm's bus (ID 3 is the elbow)
    virtual = VirtualArm(servo, payload_kg=args.payload)
    with virtual.bus() as bus:
        records = record_load(bus.path, servo, 3, joint, payload_max_kg=0.1)
        others = sum(n for i, n in bus.packets_to.items() if i not in (3, 254))
    print(f"recorded {len(records)} settings; packets to the other joints: {others}")

    # 2. identify the load (the neighbours' angles are not read: the published pose)
    held = float(records[0].goal_values_deg[0])
    pose = {joint: q_of_shaft(held)}
    links = arm.joint_load(joint, pose, payload_kg=0.0)
    est = identify_load(records, servo, links.with_payload(0.05), links=links)
    v, s = est.values, est.std
    print(f"load: {v['gravity_nm']:.3f} +- {s['gravity_nm']:.3f} N m, payload "
          f"{1e3 * v['payload_kg']:.0f} +- {1e3 * s['payload_kg']:.0f} g (truth "
          f"{1e3 * args.payload:.0f} g)")  # fmt: skip

    # 3. tune against it, 0-100 g
    load = est.load.model_copy(update={
        "payload_range_kg": (0.0, 0.1), "payload_kg": 0.1, "payload_lever_m": links.payload_lever_m,
        "payload_hang_deg": links.payload_hang_deg})  # fmt: skip
    model = joint_model(servo, joint, pose, arm=arm).with_updates(load=load)
    model = model.with_updates(jaw=model.jaw.model_copy(update={"open_deg": held}))
    best, _study = tune_registers(model, trials=args.trials, polish=args.polish, seed=0,
                                  progress=False, judge_fn=judge_loaded)  # fmt: skip
    truth = joint_model(servo, joint, {}, payload_range_kg=(0.0, 0.1))
    mine, lerobot = judge_loaded(truth, [best.registers, arm_registers(servo)])
    print(f"tuned {best.registers.label()}: settled error on the truth "
          f"{mine.tracking.settled_error_deg:.2f} deg (LeRobot's P 16: "
          f"{lerobot.tracking.settled_error_deg:.2f}), Ms {mine.margins.ms:.2f}, "
          f"hold {'trips' if mine.hold.overload else 'holds'}")  # fmt: skip

    # 4. export: the exact runtime and the native class on the arm's elbow in MuJoCo
    regs = best.registers
    goals = list(recipe_profiles(servo).values())
    native = fit_native_gains(servo, regs, goals, [run_core(servo, regs, g) for g in goals])
    step = np.concatenate([np.full(500, 180.0), np.full(1000, 160.0), np.full(1000, 195.0)])
    true_model = joint_model(servo, joint, {}, payload_kg=args.payload, arm=arm)
    truth_y = simulate_bus(true_model, regs, step).position[0] * servo.deg_per_tick

    def run_mujoco(use_native: bool) -> np.ndarray:
        xml = arm_mjcf(servo, payload_kg=args.payload, free=[joint],
                       native=native if use_native else None)  # fmt: skip
        m = mujoco.MjModel.from_xml_string(xml)
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        if not use_native:
            runtime = ExactServo(m, d, servo, regs, joint=joint, actuator=joint, zero_deg=180.0)
            return runtime.run(step) * servo.deg_per_tick
        fill_history(m, d, 0.0)
        out = np.empty(step.size)
        for k, g in enumerate(step):
            out[k] = 180.0 + math.degrees(d.qpos[0])
            d.ctrl[0] = q_of_shaft(g)
            mujoco.mj_step(m, d, nstep=round(1e-3 / m.opt.timestep))
        return out

    exact_y, native_y = run_mujoco(False), run_mujoco(True)
    print(f"RMS against the virtual servo: exact runtime {rms_deg(exact_y, truth_y):.3f} deg, "
          f"native class {rms_deg(native_y, truth_y):.3f} deg")  # fmt: skip

    if args.out is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from gripper_env.io.files import save_figure

        t = np.arange(step.size) * 1e-3
        fig, ax = plt.subplots(figsize=(9, 4))
        ax.plot(t, step, "k:", lw=1, label="goal")
        ax.plot(t, truth_y, lw=1.6, label="virtual servo (simulation core)")
        ax.plot(t, exact_y, "--", lw=1.2, label="exact runtime in MuJoCo")
        ax.plot(t, native_y, lw=1.2, label="native class in MuJoCo")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("elbow shaft angle (deg)")
        ax.set_title(f"SO-101 elbow, {1e3 * args.payload:.0f} g, tuned {regs.label()}",
                     fontsize=9)  # fmt: skip
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = save_figure(fig, args.out / "joint_mujoco.png")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
