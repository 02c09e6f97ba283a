"""The compiled Mega 2560 firmware image under simavr, on emulated time.

* :mod:`~gripper_env.hardware.emulator.mega2560`: one emulated ATmega2560 running an image;
* :mod:`~gripper_env.hardware.emulator.board`: :class:`EmulatedBoard`, the image wired to the
  simulated gripper (:mod:`gripper_env.hardware.twin.rig`);
* :mod:`~gripper_env.hardware.emulator.build`: building the image and the simavr harness;
* :mod:`~gripper_env.hardware.emulator.scripted`: a scripted host on emulated time, and the
  agreement of the emulated board, the Python twin and the simulation core;
* :mod:`~gripper_env.hardware.emulator.link_fuzz`: fuzzed host traffic against the image.
"""
