"""The host's side of a board (the real Mega 2560, or any of the stand-ins on a pseudo-terminal).

* :mod:`~gripper_env.hardware.host.device`: :class:`GripperDevice`, the host's session with a
  board, over :mod:`~gripper_env.hardware.host.serial_port` (the pyserial port), with
  :mod:`~gripper_env.hardware.host.command_log` (what the board reported lost, what to resend);
* :mod:`~gripper_env.hardware.host.errors`: :class:`DeviceError` and its kinds;
* :mod:`~gripper_env.hardware.host.telemetry`: telemetry as arrays on one device clock;
* :mod:`~gripper_env.hardware.host.configuration`: the CONFIGURE for gains and a calibration;
* :mod:`~gripper_env.hardware.host.calibration`: the two-point ADC calibration and its file;
* :mod:`~gripper_env.hardware.host.experiment`: run a profile host-in-the-loop and record it.
"""
