"""A bus servo's identified model in MuJoCo: the exported actuator classes, the exact runtime
that runs the servo's register loop inside MuJoCo, their verification, and the SO-101's MJCF.

* :mod:`~gripper_env.mujoco.servo_class`: the **native** class (MuJoCo's own position
  actuator and joint: armature, damping, frictionloss, forcerange, kp, kv, delay) and the
  **exact** class (a motor whose command the register loop computes), and the MJCF they are
  written in, with a one-joint test model;
* :mod:`~gripper_env.mujoco.runtime`: the exact runtime (the servo's firmware loop at 1 kHz
  through a step wrapper or ``mjcb_control``: profile, integer PID, output limit, dead band,
  delays, protection, Karnopp friction on MuJoCo's joint);
* :mod:`~gripper_env.mujoco.verify`: the recipe's goal profiles in the simulation core, the
  native class, the exact runtime and a Menagerie-style class, against the virtual servo's
  truth, and a ``mujoco.sysid`` fit of MuJoCo's position actuator on the same records;
* :mod:`~gripper_env.mujoco.arm`: the SO-101's MJCF without meshes, from the published masses.

MuJoCo is an optional dependency (``pip install gripper-env[mujoco]``); :func:`require_mujoco`
imports it or says how to install it.
"""

from __future__ import annotations

from types import ModuleType

__all__ = ["require_mujoco"]


def require_mujoco() -> ModuleType:
    """The ``mujoco`` module.

    Raises
    ------
    ImportError
        With the install command, when MuJoCo is not installed.
    """
    try:
        import mujoco
    except ImportError as exc:  # pragma: no cover - the test environment has it
        raise ImportError(
            "MuJoCo is not installed: pip install 'gripper-env[mujoco]' (or mujoco==4.0.1)"
        ) from exc
    return mujoco
