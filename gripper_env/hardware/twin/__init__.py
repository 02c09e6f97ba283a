"""The board without hardware, in Python: the firmware's twin and the simulated gripper behind it.

* :mod:`~gripper_env.hardware.twin.firmware`: the board's state machine (protocol session,
  modes, PID, safety, telemetry), line for line with ``firmware/gripper``;
* :mod:`~gripper_env.hardware.safety` and
  :mod:`~gripper_env.hardware.twin.firmware_config`: the jaw clamp and what CONFIGURE may set;
* :mod:`~gripper_env.hardware.twin.rig`: the simulated servo, jaw and potentiometer (the
  simulation core in open loop), and the twin wired to it (:class:`TwinBoard`).
"""
