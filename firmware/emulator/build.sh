#!/usr/bin/env bash
# Build the firmware-in-the-loop harness: a shared library over Debian's libsimavr.
#
#   firmware/emulator/build.sh [OUTDIR]   # -> OUTDIR/libgripper_board.so (default firmware/build-emulator)
#
# Needs: gcc, pkg-config, libsimavr-dev, libelf-dev (Debian/Ubuntu packages). The Python side
# (gripper_env/hardware/emulator/mega2560.py) loads the library with ctypes.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-$here/../build-emulator}"
for tool in gcc pkg-config; do
    command -v "$tool" >/dev/null || { echo "emulator/build.sh: $tool not found (apt-get install gcc pkg-config)" >&2; exit 2; }
done
pkg-config --exists simavr || { echo "emulator/build.sh: libsimavr not found (apt-get install libsimavr-dev libelf-dev)" >&2; exit 2; }
mkdir -p "$out"
tmp="$(mktemp "$out/.libgripper_board.XXXXXX")"
trap 'rm -f "$tmp"' EXIT
# -fPIC shared object; libsimavr.so carries the AVR cores, libelf reads the ELF image.
gcc -std=gnu11 -O2 -g -fPIC -shared -Wall -Wextra -Werror \
    $(pkg-config --cflags simavr) "$here/board.c" -o "$tmp" \
    $(pkg-config --libs simavr) -lelf
mv -f "$tmp" "$out/libgripper_board.so"
echo "$out/libgripper_board.so"
