"""``tuners.rig.virtual --emulated --image``: an image that is not an AVR ELF file is refused in
one line, exit 2, before simavr loads it (issue 45, item 8: a folder ran as an empty program,
the emulated CPU crashed after 131072 cycles and the board's thread printed a traceback)."""

from __future__ import annotations

import os
import struct

import pytest

from gripper_env.hardware.emulator.build import EmulatorUnavailable, check_image
from tuners.rig.virtual import main as virtual_main


def _elf(path, machine):
    """The first 20 bytes of a 32-bit little-endian ELF for ``machine``."""
    path.write_bytes(b"\x7fELF" + bytes([1, 1, 1, 0]) + bytes(8) + struct.pack("<HH", 2, machine))
    return path


@pytest.mark.parametrize("kind", ["folder", "fifo", "device", "text", "x86 elf"])
def test_a_bad_image_is_one_line_and_status_2(kind, tmp_path, capsys):
    image = {
        "folder": lambda: tmp_path,
        "fifo": lambda: (os.mkfifo(tmp_path / "pipe"), tmp_path / "pipe")[1],
        "device": lambda: "/dev/zero",
        "text": lambda: (tmp_path / "a.elf").write_text("not an image") and tmp_path / "a.elf",
        "x86 elf": lambda: _elf(tmp_path / "x.elf", 62),
    }[kind]()
    with pytest.raises(SystemExit) as caught:
        virtual_main(["--emulated", "--image", str(image)])
    assert caught.value.code == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    assert f"error: --image {image}: " in lines[0]
    assert captured.out == ""  # no pty was offered


def test_an_avr_elf_passes_the_check(tmp_path):
    check_image(_elf(tmp_path / "gripper.elf", 83))
    with pytest.raises(EmulatorUnavailable, match="machine 62, not for the AVR"):
        check_image(_elf(tmp_path / "x.elf", 62))
