#!/usr/bin/env bash
# Debian packages the full test suite uses: g++ (host build of the firmware's shared header),
# the AVR toolchain and Arduino core (firmware build), simavr's library with libelf and
# pkg-config (the firmware-in-the-loop harness, firmware/emulator), and PostgreSQL (distributed
# Optuna study). Tests that need a missing package skip with a reason, so this is optional for
# a quick start.
set -euo pipefail
PACKAGES="gcc g++ make pkg-config avr-libc gcc-avr binutils-avr arduino-core-avr arduino-mk"
PACKAGES="$PACKAGES simavr libsimavr-dev libelf-dev postgresql"
missing=""
for p in $PACKAGES; do
    dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
if [ -n "$missing" ]; then
    if [ "$(id -u)" -ne 0 ]; then
        echo "system-packages: missing$missing; run as root (or with sudo) to install" >&2
        exit 0
    fi
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends $missing >/dev/null
fi
echo "system-packages: ok"
