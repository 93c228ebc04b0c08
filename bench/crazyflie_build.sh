#!/usr/bin/env bash
# Build bfc's Crazyflie app (python -m bfc.export POLICY DIR --format crazyflie) against a
# crazyflie-firmware checkout and print the firmware image's size and the controller's.
#
#   bash bench/crazyflie_build.sh FIRMWARE_DIR [POLICY]      (POLICY: pretrained/crazyflie.pt)
#
# FIRMWARE_DIR: `git clone --recursive https://github.com/bitcraze/crazyflie-firmware`. Needs
# Debian's gcc-arm-none-eabi (and make, python3). Builds the firmware's default platform (cf2)
# into a temporary folder; the checkout is not changed.
set -euo pipefail
if [ $# -lt 1 ] || [ ! -f "$1/tools/make/oot.mk" ]; then
  echo "error: give a crazyflie-firmware checkout (its tools/make/oot.mk): bash bench/crazyflie_build.sh FIRMWARE_DIR [POLICY]" >&2
  exit 2
fi
FIRMWARE=$(cd "$1" && pwd)
ROOT=$(cd "$(dirname "$0")/.." && pwd)
POLICY=${2:-$ROOT/pretrained/crazyflie.pt}
PYTHON=${PYTHON:-$ROOT/.venv/bin/python}
command -v arm-none-eabi-gcc >/dev/null || { echo "error: no arm-none-eabi-gcc: apt-get install gcc-arm-none-eabi" >&2; exit 2; }
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
APP="$WORK/bfc_app"
(cd "$ROOT" && "$PYTHON" -m bfc.export "$POLICY" "$APP" --format crazyflie)
echo "firmware: $(git -C "$FIRMWARE" log --oneline -1 2>/dev/null || echo "$FIRMWARE")"
echo "compiler: $(arm-none-eabi-gcc --version | head -1)"
START=$(date +%s)
make -C "$APP" CRAZYFLIE_BASE="$FIRMWARE" -j"$(nproc)" > "$WORK/build.log" 2>&1 || { tail -30 "$WORK/build.log"; exit 1; }
echo "built in $(( $(date +%s) - START )) s"
grep -E "^ *(Flash|RAM|CCM)" "$WORK/build.log" || true
if grep -E "warning:" "$WORK/build.log" | grep -E "bfc_(oot|crazyflie|policy)" ; then echo "error: the app's code has warnings" >&2; exit 1; fi
echo "the app's controller, bfc_oot.o (the policy, its maps and the adapter; text data bss, bytes):"
find "$APP" -name bfc_oot.o -exec arm-none-eabi-size {} +
echo "the firmware image:"
arm-none-eabi-size "$APP/build/cf2.elf"
