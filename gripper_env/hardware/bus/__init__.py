"""Serial bus servos: Feetech STS3215 (SCS/STS protocol), Dynamixel XL330-M288 and XL430-W250
(Protocol 2.0).

* :mod:`~gripper_env.hardware.bus.tables`: the control tables (:data:`TABLES`), field
  encodings, the roles the rest of the project uses (``goal_position``, ``p_gain``...);
* :mod:`~gripper_env.hardware.bus.control_table`: :class:`ControlTable`, a servo's memory with
  the firmware's checks on writes;
* :mod:`~gripper_env.hardware.bus.feetech`, :mod:`~gripper_env.hardware.bus.dynamixel`: the
  two wire protocols (packets, checksum / CRC and byte stuffing, incremental parsers);
* :mod:`~gripper_env.hardware.bus.physics`: :class:`Physics`, what moves a virtual servo;
* :mod:`~gripper_env.hardware.bus.server`: :class:`VirtualBus`, virtual servos on a
  pseudo-terminal;
* :mod:`~gripper_env.hardware.bus.link`: :class:`BusLink`, the host's side through the vendors'
  SDKs (a broadcast scan, one ID only, retries, a vanished port), and its errors
  (:class:`BusError`...);
* :mod:`~gripper_env.hardware.bus.gripper`: :class:`~gripper_env.hardware.bus.gripper.
  BusGripper`, one servo found by its ID on a shared bus, driven inside its calibration and
  limits, its registers snapshot and restored;
* :mod:`~gripper_env.hardware.bus.interrupts`: SIGINT and SIGTERM between bus transactions.
"""

from gripper_env.hardware.bus.control_table import ControlTable
from gripper_env.hardware.bus.link import (
    BusAlertError,
    BusCommError,
    BusCorruptError,
    BusError,
    BusLink,
    BusModelError,
    BusPortError,
    BusPortLostError,
    BusServoError,
    BusTimeoutError,
    BusUnsupportedError,
    BusVerifyError,
)
from gripper_env.hardware.bus.physics import MirrorPhysics, Physics
from gripper_env.hardware.bus.server import VirtualBus
from gripper_env.hardware.bus.tables import (
    ROLES,
    TABLES,
    TICKS_PER_REV,
    Field,
    TableSpec,
    deg_to_ticks,
    get_spec,
    ticks_to_deg,
)

__all__ = [
    "ROLES",
    "TABLES",
    "TICKS_PER_REV",
    "BusAlertError",
    "BusCommError",
    "BusCorruptError",
    "BusError",
    "BusLink",
    "BusModelError",
    "BusPortError",
    "BusPortLostError",
    "BusServoError",
    "BusTimeoutError",
    "BusUnsupportedError",
    "BusVerifyError",
    "ControlTable",
    "Field",
    "MirrorPhysics",
    "Physics",
    "TableSpec",
    "VirtualBus",
    "deg_to_ticks",
    "get_spec",
    "ticks_to_deg",
]
