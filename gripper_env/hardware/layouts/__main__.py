"""``python -m gripper_env.hardware.layouts`` (see :mod:`gripper_env.hardware.layouts.cli`)."""

import sys

from gripper_env.hardware.layouts.cli import main

sys.exit(main())
