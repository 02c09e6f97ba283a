"""The protocol's message layouts from their one description, ``firmware/protocol.toml``.

The description lists the constants, enumerations and messages of the serial protocol (ids,
fields, wire types, units). From it this package

* writes the firmware's ``firmware/gripper/gripper_messages.h`` (message structs with their
  little-endian codecs, the enums, the constants), which the sketch and the host harness compile;
* writes the layout tables of ``firmware/PROTOCOL.md`` (between its ``GENERATED`` markers);
* checks the Python twin, :mod:`gripper_env.hardware.protocol`, against it: type ids, field names
  and order, wire types, enum values, constants.

Its modules: :mod:`~.description` (the description and its loading), :mod:`~.header` (the C++
header), :mod:`~.markdown` (the tables), :mod:`~.twin` (the check of the Python twin) and
:mod:`~.cli` (the command line).

``python -m gripper_env.hardware.layouts`` regenerates both files; ``--check`` only reports
what is out of date (exit status 1), which the test suite runs.

Examples
--------
>>> desc = load_description()
>>> desc.messages["CONFIGURE"].size
50
"""

from gripper_env.hardware.layouts.cli import main
from gripper_env.hardware.layouts.description import (
    DESCRIPTION,
    FIRMWARE,
    HEADER,
    PROTOCOL_MD,
    WIRE_TYPES,
    Description,
    LayoutError,
    load_description,
)
from gripper_env.hardware.layouts.header import render_header
from gripper_env.hardware.layouts.markdown import render_markdown, update_markdown
from gripper_env.hardware.layouts.twin import check_python

__all__ = [
    "DESCRIPTION",
    "FIRMWARE",
    "HEADER",
    "PROTOCOL_MD",
    "WIRE_TYPES",
    "Description",
    "LayoutError",
    "check_python",
    "load_description",
    "main",
    "render_header",
    "render_markdown",
    "update_markdown",
]
