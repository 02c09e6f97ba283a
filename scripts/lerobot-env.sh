#!/usr/bin/env bash
# Build .lerobot-venv: LeRobot's motors package (FeetechMotorsBus, DynamixelMotorsBus) under
# Python >= 3.12, for tests/hardware/bus/test_bus_lerobot.py, which drives the virtual servos with
# LeRobot's own buses in a subprocess of this interpreter. Nothing of LeRobot enters the project.
#
# LeRobot 0.6 needs Python >= 3.12 and lists torch (< 2.12) and torchvision among its base
# requirements. Its motors package imports neither (it needs draccus, numpy, tqdm, pyserial,
# deepdiff and the two vendors' SDKs), and on a machine that reaches only PyPI the torch wheels
# for Python 3.12 are CUDA builds of several GB (PyTorch's CPU index is another host). So LeRobot
# is installed without its dependencies, then exactly what lerobot.motors imports; the script
# ends by importing both buses, which fails loudly if a dependency is missing. Nothing is stubbed.
#
# Environment: PYTHON312 (an interpreter >= 3.12; default: python3.12 on PATH, else pyenv's),
# LEROBOT_VERSION (default 0.6.1), LEROBOT_VENV (default .lerobot-venv).
set -euo pipefail
cd "$(dirname "$0")/.."
LEROBOT_VERSION=${LEROBOT_VERSION:-0.6.1}
VENV=${LEROBOT_VENV:-.lerobot-venv}

find_python() {
    if [ -n "${PYTHON312:-}" ]; then echo "$PYTHON312"; return; fi
    for candidate in python3.13 python3.12; do
        if command -v "$candidate" >/dev/null 2>&1; then command -v "$candidate"; return; fi
    done
    for candidate in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.1[2-9]*/bin/python3; do
        if [ -x "$candidate" ]; then echo "$candidate"; return; fi
    done
}
PY=$(find_python)
if [ -z "$PY" ] || ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 12))'; then
    echo "lerobot-env: no Python >= 3.12 found (set PYTHON312)" >&2
    exit 1
fi

if [ ! -x "$VENV/bin/python" ]; then
    "$PY" -m venv "$VENV"
fi
PIP="$VENV/bin/python -m pip --disable-pip-version-check"
$PIP install --quiet --upgrade pip
$PIP install --quiet --no-deps "lerobot==${LEROBOT_VERSION}"
# what lerobot.motors imports (its pyproject's base, feetech and dynamixel requirements)
$PIP install --quiet "draccus>=0.11.6,<0.12" "numpy>=2.0,<2.3" "tqdm>=4.66,<5" \
    "pyserial>=3.5,<4" "deepdiff>=7.0.1,<9" "feetech-servo-sdk>=1.0,<2" \
    "dynamixel-sdk>=3.7.31,<3.9" "packaging>=24.2,<26" "termcolor>=2.4,<4"
"$VENV/bin/python" -c "
from lerobot.motors.feetech import FeetechMotorsBus
from lerobot.motors.dynamixel import DynamixelMotorsBus
import importlib.metadata as md, sys
print('lerobot-env: $VENV ready (lerobot', md.version('lerobot') + ', Python', sys.version.split()[0] + ')')
"
