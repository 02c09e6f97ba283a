"""Shared fixtures: the paper's numbers as independent truth."""

import os
import shutil
import subprocess
from pathlib import Path

import matplotlib
import pytest

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

from gripper_env.paper import PLANTS as PAPER_PLANTS


@pytest.fixture(params=sorted(PAPER_PLANTS))
def paper_plant_name(request):
    return request.param


@pytest.fixture
def small_disk(tmp_path):
    """A small file system that fills up: ``small_disk(kib)`` mounts a tmpfs of that size on a
    temporary folder and returns it (unmounted after the test). Skips, saying why, where mount
    is missing or not permitted (not root)."""
    mounted = []

    def mount(size_kib: int) -> Path:
        tool = shutil.which("mount")
        if tool is None:
            pytest.skip("a full-disk test needs mount(8) to make a small tmpfs")
        folder = tmp_path / f"disk{len(mounted)}"
        folder.mkdir()
        result = subprocess.run(
            [tool, "-t", "tmpfs", "-o", f"size={size_kib}k", "tmpfs", str(folder)],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        if result.returncode != 0:
            pytest.skip("a full-disk test mounts a small tmpfs, not permitted here: "
                        f"{result.stderr.strip() or result.returncode}")  # fmt: skip
        mounted.append(folder)
        return folder

    yield mount
    for folder in mounted:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True, check=False)


def fill_disk(folder: Path, leave_bytes: int = 0) -> Path:
    """Fill the file system of ``folder`` with one file, leaving about ``leave_bytes`` free;
    the filler's path (delete it to free the space)."""
    filler = folder / "filler"
    stat = os.statvfs(folder)
    remaining = max(0, stat.f_bavail * stat.f_frsize - leave_bytes)
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        block = b"\0" * 4096
        while remaining > 0:
            try:
                remaining -= os.write(fd, block[: min(len(block), remaining)])
            except OSError:
                break
    finally:
        os.close(fd)
    return filler


@pytest.fixture
def filled():
    """``fill_disk`` as a fixture (test modules do not import conftest)."""
    return fill_disk
