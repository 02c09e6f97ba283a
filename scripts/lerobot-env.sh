#!/usr/bin/env bash
# Build .lerobot-venv: LeRobot's motors package (FeetechMotorsBus, DynamixelMotorsBus) under
# Python >= 3.12, for tests/hardware/bus/test_bus_lerobot.py, which drives the virtual servos with
# LeRobot's own buses in a subprocess of this interpreter. Nothing of LeRobot enters the project.
#
# LeRobot 0.6 needs Python >= 3.12, and lerobot.motors imports torch (lerobot.utils imports its
# device helpers). torch is installed first: from PyTorch's CPU index when it is reachable
# (TORCH_INDEX_URL), else from PyPI, whose Linux wheels for Python 3.12 are CUDA builds (about
# 3 GB with the nvidia-* libraries; torch imports without them only on CPU builds, so they
# cannot be left out). Then LeRobot itself without its other requirements (torchvision,
# opencv, datasets... which lerobot.motors does not import) and exactly what lerobot.motors
# does import; the script ends by importing both buses, which fails loudly if anything is
# missing. Nothing is stubbed.
#
# Environment: PYTHON312 (an interpreter >= 3.12; default: python3.12 on PATH, else pyenv's),
# LEROBOT_VERSION (default 0.6.1), LEROBOT_VENV (default .lerobot-venv), TORCH_SPEC (default
# LeRobot 0.6's range), TORCH_INDEX_URL (default PyTorch's CPU index).
set -euo pipefail
cd "$(dirname "$0")/.."
LEROBOT_VERSION=${LEROBOT_VERSION:-0.6.1}
VENV=${LEROBOT_VENV:-.lerobot-venv}
TORCH_SPEC=${TORCH_SPEC:-torch>=2.7,<2.12}
TORCH_INDEX_URL=${TORCH_INDEX_URL:-https://download.pytorch.org/whl/cpu}

find_python() {
    # the first that runs and is >= 3.12 (a pyenv shim may exist for a version not selected)
    local candidate
    for candidate in ${PYTHON312:-} python3.12 python3.13 \
        "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.12*/bin/python3 \
        "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.13*/bin/python3; do
        if "$candidate" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null; then
            echo "$candidate"
            return
        fi
    done
}
PY=$(find_python)
if [ -z "$PY" ]; then
    echo "lerobot-env: no Python >= 3.12 found (set PYTHON312)" >&2
    exit 1
fi

if [ ! -x "$VENV/bin/python" ]; then
    "$PY" -m venv "$VENV"
fi
PIP="$VENV/bin/python -m pip --disable-pip-version-check"
$PIP install --quiet --upgrade pip
if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    if ! $PIP install --quiet --timeout 20 --retries 0 "$TORCH_SPEC" --index-url "$TORCH_INDEX_URL" \
        2>/dev/null; then
        echo "lerobot-env: PyTorch's CPU index is out of reach; torch from PyPI (a CUDA build)" >&2
        $PIP install --quiet "$TORCH_SPEC"
    fi
fi
$PIP install --quiet --no-deps "lerobot==${LEROBOT_VERSION}"
# what lerobot.motors imports (its pyproject's base, feetech and dynamixel requirements)
$PIP install --quiet "draccus>=0.11.6,<0.12" "numpy>=2.0,<2.3" "tqdm>=4.66,<5" \
    "pyserial>=3.5,<4" "deepdiff>=7.0.1,<9" "feetech-servo-sdk>=1.0,<2" \
    "dynamixel-sdk>=3.7.31,<3.9" "packaging>=24.2,<26" "termcolor>=2.4,<4" \
    "huggingface-hub>=1.6,<2"
"$VENV/bin/python" -c "
from lerobot.motors.feetech import FeetechMotorsBus
from lerobot.motors.dynamixel import DynamixelMotorsBus
import importlib.metadata as md, sys
print('lerobot-env: $VENV ready (lerobot', md.version('lerobot') + ', Python', sys.version.split()[0] + ')')
"
