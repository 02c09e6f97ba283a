"""The bus commands' fixtures (the helpers are in ``bus_arm``)."""

from __future__ import annotations

from pathlib import Path

import pytest
from bus_arm import CLOSED, GRIPPER, OPEN

from gripper_env.hardware.bus.server import VirtualBus


@pytest.fixture
def jaw_file(tmp_path: Path):
    """Write the jaw calibration of ID 6 of a bus (given positions; nothing is written to the
    servo) and return its path."""
    from tuners.bus import calibrate

    def write(bus: VirtualBus, family: str) -> Path:
        path = tmp_path / f"jaw_{family}.json"
        code = calibrate.main(["--port", bus.path, "--id", str(GRIPPER), "--model", family,
                               "--closed-ticks", str(CLOSED), "--open-ticks", str(OPEN),
                               "--out", str(path)])  # fmt: skip
        assert code == 0
        return path

    return write
