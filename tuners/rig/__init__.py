"""The rig's command lines: the physical gripper (or a virtual or emulated board) on a serial port.

``python -m tuners.rig.calibrate`` (two-point potentiometer calibration),
``python -m tuners.rig.record`` (an
open-loop identification record), ``python -m tuners.rig.deploy`` (tuned gains on the board's PID,
behind a stability gate, compared with the simulation's prediction). What they share is in
:mod:`tuners.rig.cli`; the device, the protocol and the experiments are the library's
(:mod:`gripper_env.hardware`).
"""
