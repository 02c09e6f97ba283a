#!/usr/bin/env bash
# Create .venv and install the project with every extra, taking a CPU-only build of PyTorch.
#
# PyTorch's default Linux wheels pull several GB of CUDA libraries. We install torch first:
#   1. from a local wheel directory if pip has one configured (find-links), offline;
#   2. otherwise from PyTorch's CPU wheel index (override with TORCH_INDEX_URL).
# Then the project itself; its torch range is already satisfied, so nothing more is pulled.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}
TORCH_INDEX_URL=${TORCH_INDEX_URL:-https://download.pytorch.org/whl/cpu}

if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
PIP=".venv/bin/python -m pip"
$PIP install --quiet --upgrade pip setuptools wheel

if ! .venv/bin/python -c "import torch" 2>/dev/null; then
    if ! $PIP install --quiet --no-index --no-deps "torch==${TORCH_VERSION}" 2>/dev/null; then
        $PIP install --quiet --no-deps "torch==${TORCH_VERSION}" --index-url "$TORCH_INDEX_URL"
    fi
fi
$PIP install --quiet -e ".[all]"
.venv/bin/python -c "import torch; assert not torch.version.cuda, 'a CUDA build of torch was installed'" \
    && echo "setup: .venv ready (torch $(.venv/bin/python -c 'import torch; print(torch.__version__)'))"
# The simulation kernels (numba), compiled once into numba's on-disk cache so that the first tune
# and the first test run load them in seconds (minutes on 2 cores; a warm cache only loads them).
echo "setup: compiling the simulation kernels (minutes on 2 cores, once; later runs load them)"
env -u PYTHONDONTWRITEBYTECODE .venv/bin/python -m tuners.compile --jobs 2
