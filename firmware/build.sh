#!/usr/bin/env bash
# Build the Mega 2560 firmware with Debian's arduino-mk and report flash/RAM use (used by CI).
#
#   firmware/build.sh            # -> firmware/build-mega/gripper.hex (and gripper.elf)
#   firmware/build.sh OUTDIR     # -> OUTDIR/gripper.hex: separate build trees do not race
#
# Needs: gcc-avr binutils-avr avr-libc arduino-core-avr arduino-mk (Debian/Ubuntu packages).
# Fails if the sketch or gripper_core.h produce any compiler warning.
set -euo pipefail
cd "$(dirname "$0")"
for tool in avr-g++ avr-size make; do
    command -v "$tool" >/dev/null || { echo "build.sh: $tool not found (apt-get install gcc-avr binutils-avr avr-libc arduino-core-avr arduino-mk)" >&2; exit 2; }
done
ARDMK_DIR=${ARDMK_DIR:-/usr/share/arduino}
[ -f "$ARDMK_DIR/Arduino.mk" ] || { echo "build.sh: $ARDMK_DIR/Arduino.mk not found (apt-get install arduino-mk arduino-core-avr)" >&2; exit 2; }

out=${1:-build-mega}
log=$(mktemp)
trap 'rm -f "$log"' EXIT
make -s OBJDIR="$out" clean >/dev/null 2>&1 || true
if ! make ARDMK_DIR="$ARDMK_DIR" OBJDIR="$out" >"$log" 2>&1; then
    cat "$log" >&2
    echo "build.sh: firmware build FAILED" >&2
    exit 1
fi
# Warnings in the core are Debian's; warnings in our sources are errors.
if grep -E "gripper(\.ino|_core\.h).*(warning|error)" "$log" >&2; then
    echo "build.sh: the firmware sources compile with warnings" >&2
    exit 1
fi
read -r text data bss _ < <(avr-size "$out/gripper.elf" | tail -1)
echo "gripper firmware: flash $((text + data)) of 253952 bytes, static RAM $((data + bss)) of 8192 bytes"
echo "hex: $(cd "$out" && pwd)/gripper.hex"
