"""The Mega 2560 firmware builds with Debian's avr-gcc and arduino-mk (firmware/build.sh)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware"
ARDUINO_MK = Path("/usr/share/arduino/Arduino.mk")

missing = [tool for tool in ("avr-g++", "avr-size", "make") if shutil.which(tool) is None]
if not ARDUINO_MK.exists():
    missing.append(str(ARDUINO_MK))


@pytest.mark.skipif(
    bool(missing),
    reason=f"AVR toolchain not installed ({', '.join(missing)}): apt-get install gcc-avr "
    "binutils-avr avr-libc arduino-core-avr arduino-mk",
)
def test_firmware_builds_and_fits_the_mega() -> None:
    result = subprocess.run(
        [str(FIRMWARE / "build.sh")], capture_output=True, text=True, timeout=300, check=False
    )
    assert result.returncode == 0, result.stdout + result.stderr
    match = re.search(r"flash (\d+) of 253952 bytes, static RAM (\d+) of 8192 bytes", result.stdout)
    assert match, result.stdout
    flash, ram = int(match[1]), int(match[2])
    assert 4000 < flash < 64 * 1024  # a real image, far below the 248 KiB available
    assert ram < 4096  # leaves at least half of the RAM for the stack
    hex_file = FIRMWARE / "build-mega" / "gripper.hex"
    assert hex_file.read_text().startswith(":")
