#!/bin/sh
# Runs a SocketCAN test binary inside one QEMU boot of Debian's stock kernel with vcan (the host
# kernel may have no CAN at all), prints its output and exits with its status: the shared guest
# runner (tests/qemu/run_in_guest.sh) with the CAN modules, vcan0 and the CANopen arm's config.
#
#   run_can_tests_in_qemu.sh [--with PROGRAM]... TEST_BINARY WORK_DIR [test arguments...]
#
# WORK_DIR keeps the kernel between runs (WORK_DIR/kernel/<package>/, or LANCET_CAN_KERNEL_DIR, or
# LANCET_QEMU_KERNEL_DIR): the first run downloads the package linux-image-amd64 depends on with
# `apt-get download` (about 70 MB, not installed) and extracts vmlinuz and four modules (can,
# can-raw, can-dev, vcan). The guest loads them, creates vcan0 and runs the binary with
# LANCET_CANOPEN_CONFIG (hw_configs/canopen_arm.toml), LANCET_TOOLS_DIR (the --with programs) and
# LANCET_CAN_ENV set; the caller's LANCET_CAN_* variables go in too (e.g. LANCET_CAN_SYNC_US).
#
# Exit status: the binary's; 1 when the guest dies before reporting, or when it does not report
# within LANCET_QEMU_TIMEOUT seconds (boot and the whole suite; default 280; ctest sets 870, just
# under its TIMEOUT of 900, so that the runner, not ctest, says what timed out: the boot, or which
# test was running), several times what the suite takes under TCG on a loaded 2-core host; the tests
# inside have their own hang deadlines (30 s each). When QEMU, busybox or the kernel package is not
# available or cannot run: 77 (skip) with the reason on stdout, or, with CI=true in the
# environment, 1 (a CI machine must run the CAN suite, not skip it).
set -u
here=$(cd "$(dirname "$0")" && pwd)
with=""
while [ $# -gt 0 ] && [ "$1" = "--with" ]; do
  [ $# -ge 2 ] || { echo "run_can_tests_in_qemu: --with needs a program" >&2; exit 1; }
  with="$with --with $2"
  shift 2
done
[ $# -ge 2 ] || { echo "usage: $0 [--with PROGRAM]... TEST_BINARY WORK_DIR [test arguments...]" >&2; exit 1; }
bin=$1
work=$2
shift 2
config="$here/../../../hw_configs/canopen_arm.toml"
[ -f "$config" ] || { echo "run_can_tests_in_qemu: no $config" >&2; exit 1; }
mkdir -p "$work" || exit 1
setup="$work/can-setup.sh"
cat >"$setup" <<'SETUP'
ip link add dev vcan0 type vcan && ip link set vcan0 up || return 1
export LANCET_CANOPEN_CONFIG=/canopen_arm.toml
export LANCET_CAN_ENV="QEMU guest: $LANCET_GUEST"
SETUP
if [ -n "${LANCET_CAN_KERNEL_DIR:-}" ]; then
  LANCET_QEMU_KERNEL_DIR=$LANCET_CAN_KERNEL_DIR
  export LANCET_QEMU_KERNEL_DIR
fi
LANCET_GUEST_RUNNER_NAME=run_can_tests_in_qemu
export LANCET_GUEST_RUNNER_NAME
# shellcheck disable=SC2086 # $with is pairs of words
exec "$here/../../qemu/run_in_guest.sh" --name CAN --kernel linux-image-amd64 \
  --module net/can/can --module net/can/can-raw --module drivers/net/can/dev/can-dev --module drivers/net/can/vcan \
  --file "$config" --setup "$setup" --env-prefix LANCET_CAN_ $with "$work" "$bin" --gtest_color=no "$@"
