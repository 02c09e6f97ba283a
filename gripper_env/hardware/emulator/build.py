"""Building what the emulator runs: the firmware image (``firmware/build.sh``) and the simavr
harness library (``firmware/emulator/build.sh``), with the project's own scripts.

:func:`ensure_built` builds what is missing; :func:`emulator_missing` names the Debian packages
a build needs that are not installed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

__all__ = [
    "DEFAULT_HARNESS",
    "DEFAULT_IMAGE",
    "FIRMWARE_DIR",
    "EmulatorUnavailable",
    "build_harness",
    "build_image",
    "emulator_missing",
    "ensure_built",
]

REPO = Path(__file__).resolve().parents[3]
FIRMWARE_DIR = REPO / "firmware"
DEFAULT_IMAGE = FIRMWARE_DIR / "build-mega" / "gripper.elf"
DEFAULT_HARNESS = FIRMWARE_DIR / "build-emulator" / "libgripper_board.so"


class EmulatorUnavailable(RuntimeError):
    """The emulator cannot run here (a package, the image or the harness is missing)."""


def emulator_missing() -> str | None:
    """Why the emulator cannot be built here (a missing tool or package), or ``None``."""
    needs = {
        "avr-g++": "gcc-avr",
        "avr-size": "binutils-avr",
        "make": "make",
        "gcc": "gcc",
        "pkg-config": "pkg-config",
    }
    missing = [pkg for tool, pkg in needs.items() if shutil.which(tool) is None]
    if not Path("/usr/share/arduino/Arduino.mk").exists():
        missing += ["arduino-mk", "arduino-core-avr"]
    if shutil.which("pkg-config"):
        found = subprocess.run(["pkg-config", "--exists", "simavr"], check=False)
        has_simavr = found.returncode == 0
    else:
        has_simavr = Path("/usr/include/simavr/sim_avr.h").exists()
    if not has_simavr:
        missing += ["libsimavr-dev"]
    if not Path("/usr/include/libelf.h").exists() and not Path("/usr/include/gelf.h").exists():
        missing += ["libelf-dev"]
    if missing:
        return "missing Debian packages: " + " ".join(sorted(set(missing)))
    return None


def _run_script(cmd: list[str], what: str) -> str:
    result = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=600)
    if result.returncode != 0:
        raise EmulatorUnavailable(
            f"{what} failed ({' '.join(cmd)}):\n{result.stdout[-2000:]}{result.stderr[-2000:]}"
        )
    return result.stdout


def build_image(out_dir: str | os.PathLike[str] | None = None) -> Path:
    """Build the firmware with ``firmware/build.sh`` and return the ELF image's path.

    Parameters
    ----------
    out_dir : path, optional
        Build directory (default ``firmware/build-mega``); a separate one lets parallel test
        workers build without racing.
    """
    cmd = [str(FIRMWARE_DIR / "build.sh")]
    if out_dir is not None:
        cmd.append(str(Path(out_dir).resolve()))
    out = _run_script(cmd, "firmware build")
    elf = Path(out_dir).resolve() / "gripper.elf" if out_dir is not None else DEFAULT_IMAGE
    if not elf.exists():
        raise EmulatorUnavailable(f"firmware build wrote no {elf}:\n{out}")
    return elf


def build_harness(out_dir: str | os.PathLike[str] | None = None) -> Path:
    """Build the harness library with ``firmware/emulator/build.sh``; return its path."""
    cmd = [str(FIRMWARE_DIR / "emulator" / "build.sh")]
    if out_dir is not None:
        cmd.append(str(Path(out_dir).resolve()))
    return Path(_run_script(cmd, "emulator harness build").strip().splitlines()[-1])


#: The largest firmware image accepted (bytes): an ELF of the Mega 2560's 256 KiB of flash with
#: its debug sections takes a few hundred KiB.
MAX_IMAGE_BYTES = 16 << 20
#: ELF's machine number of Atmel AVR (``e_machine``).
_EM_AVR = 83


def check_image(image: str | os.PathLike[str], option: str = "--image") -> None:
    """Refuse, in one line naming ``option``, an image that is not an AVR ELF file (a folder,
    a pipe, a device, another file): simavr loaded a folder as an empty program and its CPU
    crashed after 131072 cycles, with a thread's traceback.

    Raises
    ------
    EmulatorUnavailable
    """
    from gripper_env.io.config import ConfigError, check_input

    try:
        check_input(image, MAX_IMAGE_BYTES, "firmware image", option)
        with open(image, "rb") as f:
            head = f.read(20)
    except ConfigError as exc:
        raise EmulatorUnavailable(str(exc)) from None
    except OSError as exc:
        raise EmulatorUnavailable(f"{option} {image}: cannot read: {exc.strerror or exc}") from None
    if len(head) < 20 or head[:4] != b"\x7fELF":
        raise EmulatorUnavailable(f"{option} {image}: not an ELF file (the firmware build's .elf)")
    machine = int.from_bytes(head[18:20], "little" if head[5] == 1 else "big")
    if machine != _EM_AVR:
        raise EmulatorUnavailable(
            f"{option} {image}: an ELF for machine {machine}, not for the AVR (83) of the Mega 2560"
        )


def ensure_built(
    image: str | os.PathLike[str] | None = None, rebuild: bool = False
) -> tuple[Path, Path]:
    """The image and the harness library, built by the project's scripts when missing.

    Parameters
    ----------
    image : path, optional
        An image to use as it is; default ``firmware/build-mega/gripper.elf`` (built if missing
        or if ``rebuild``).
    rebuild : bool
        Rebuild the default image and the harness even if they exist.

    Raises
    ------
    EmulatorUnavailable
        A Debian package is missing (the message names it) or a build failed.
    """
    harness = Path(os.environ.get("GRIPPER_EMULATOR_LIB") or DEFAULT_HARNESS)
    if image is not None and not Path(image).exists():
        raise EmulatorUnavailable(f"no firmware image at {image}")
    if image is not None:
        check_image(image)
    need_image = image is None and (rebuild or not DEFAULT_IMAGE.exists())
    need_harness = rebuild or not harness.exists()
    if (need_image or need_harness) and not FIRMWARE_DIR.is_dir():
        # an installed wheel carries no firmware sources
        raise EmulatorUnavailable(
            f"cannot build the emulator: no firmware sources at {FIRMWARE_DIR} (they are not "
            "installed with the package); run it from a source checkout, or pass --image with "
            "a built image and set GRIPPER_EMULATOR_LIB to a built harness"
        )
    if need_image or need_harness:
        why = emulator_missing()
        if why:
            raise EmulatorUnavailable(
                f"cannot build the emulator: {why} (bash scripts/system-packages.sh installs them)"
            )
    if need_image:
        build_image()
    if need_harness:
        harness = build_harness(harness.parent)
    return (Path(image) if image is not None else DEFAULT_IMAGE), harness
