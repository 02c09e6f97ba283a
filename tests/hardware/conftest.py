"""Fixtures for the hardware-link tests: the host build of firmware/gripper_core.h."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from gripper_env.hardware.virtual import VirtualDevice

REPO = Path(__file__).resolve().parents[2]
FIRMWARE = REPO / "firmware"
HARNESS_SOURCE = FIRMWARE / "host" / "harness.cpp"


class Harness:
    """A running firmware/host/harness.cpp: one command line in, one answer line out."""

    def __init__(self, executable: Path) -> None:
        self.proc = subprocess.Popen(
            [str(executable)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )

    def __call__(self, *args: object) -> str:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(" ".join(str(a) for a in args) + "\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline()
        if not answer:
            raise RuntimeError(f"harness exited (code {self.proc.poll()}) on {args[:2]!r}")
        return answer.strip()

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait(timeout=10)


def _build(tmp: Path, real: str) -> Path:
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("g++ is not installed: cannot build the host harness of gripper_core.h")
    exe = tmp / f"harness_{real}"
    cmd = [
        gxx,
        "-std=c++17",
        "-O2",
        "-Wall",
        "-Wextra",
        "-Wpedantic",
        "-Werror",
        "-ffp-contract=off",  # no fused multiply-add: same rounding as the Python PID
        f"-DGRIPPER_REAL={real}",
        f"-I{FIRMWARE / 'gripper'}",
        str(HARNESS_SOURCE),
        "-o",
        str(exe),
    ]
    result = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise AssertionError(f"harness build failed:\n{' '.join(cmd)}\n{result.stderr}")
    return exe


@pytest.fixture(scope="session")
def harness(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Harness]:
    """The harness built with double arithmetic (parity with the Python PID)."""
    h = Harness(_build(tmp_path_factory.mktemp("harness"), "double"))
    yield h
    h.close()


@pytest.fixture(scope="session")
def harness_f32(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Harness]:
    """The harness built with float arithmetic, as on the board."""
    h = Harness(_build(tmp_path_factory.mktemp("harness_f32"), "float"))
    yield h
    h.close()


@pytest.fixture
def virtual_twin() -> Iterator[VirtualDevice]:
    """The Python twin of the firmware on a pseudo-terminal, device time at ``SPEED``."""
    from virtual_support import SPEED

    with VirtualDevice("test2", "actual", speed=SPEED, seed=2) as vd:
        yield vd


@pytest.fixture(scope="session")
def emulator_build(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The firmware image and the simavr harness, built by the project's scripts into this
    session's own directory (parallel workers do not share a build tree)."""
    from gripper_env.hardware.emulator.build import build_harness, build_image, emulator_missing

    why = emulator_missing()
    if why:
        pytest.skip(f"the firmware-in-the-loop tests need simavr and the AVR toolchain: {why}")
    out = tmp_path_factory.mktemp("emulator")
    return build_image(out / "image"), build_harness(out / "harness")
