#!/bin/sh
# The QEMU runner's verdicts when the guest cannot run, without booting one:
#   no emulator            → 77 and "SKIP: ..." (plain), 1 and "FAIL: ..." (CI=true)
#   an emulator that fails → the same (only when a kernel is cached: nothing is downloaded here)
#   a guest that hangs     → 1, and the message says what timed out: the boot, or the test that was
#                            running (stand-ins for the emulator, which print a console and sleep,
#                            and for the kernel; needs busybox, as the runner does)
#
#   run_can_tests_in_qemu_test.sh RUNNER WORK_DIR KERNEL_CACHE
set -u
[ $# -eq 3 ] || { echo "usage: $0 RUNNER WORK_DIR KERNEL_CACHE" >&2; exit 2; }
runner=$1
work=$2
kcache=$3
mkdir -p "$work" || exit 2
true_bin=/bin/true
[ -x "$true_bin" ] || true_bin=/usr/bin/true
failures=0

# expect WANT_RC WANT_WORD NAME [env assignments...]
expect() {
  want=$1 word=$2 name=$3
  shift 3
  out=$(env -u CI "$@" "$runner" "$true_bin" "$work" 2>&1)
  rc=$?
  if [ "$rc" -ne "$want" ] || ! printf '%s\n' "$out" | grep -q "^$word: "; then
    echo "FAILED: $name: exit $rc (wanted $want), output:"
    printf '%s\n' "$out" | sed 's/^/    /'
    failures=$((failures + 1))
  else
    echo "ok: $name: exit $rc, $(printf '%s\n' "$out" | grep "^$word: " | head -n 1)"
  fi
}

expect 77 SKIP "no QEMU" LANCET_QEMU=/nonexistent/qemu-system-x86_64
expect 1 FAIL "no QEMU, CI=true" LANCET_QEMU=/nonexistent/qemu-system-x86_64 CI=true

cached=""
for d in "$kcache"/*/; do
  if [ -f "$d/ready" ]; then cached=yes; break; fi
done
if [ -n "$cached" ]; then
  expect 77 SKIP "QEMU cannot boot" LANCET_QEMU=false LANCET_CAN_KERNEL_DIR="$kcache"
  expect 1 FAIL "QEMU cannot boot, CI=true" LANCET_QEMU=false LANCET_CAN_KERNEL_DIR="$kcache" CI=true
else
  echo "note: no kernel cached in $kcache yet (the CAN suite fetches one): the boot-failure cases were not run"
fi
# A stand-in kernel cache (the runner only copies these files) and emulators that hang: one
# before the guest's init says it is up, one in the middle of the second test.
if command -v busybox >/dev/null || [ -x /bin/busybox ] || [ -x /usr/bin/busybox ]; then
  fake="$work/fake"
  rm -rf "$fake" && mkdir -p "$fake/kernel/linux-image-fake" || exit 2
  for f in vmlinuz can.ko can-raw.ko can-dev.ko vcan.ko; do : >"$fake/kernel/linux-image-fake/$f"; done
  echo linux-image-fake >"$fake/kernel/linux-image-fake/ready"
  printf '%s\n' '#!/bin/sh' 'echo "SeaBIOS (stand-in)"' 'exec sleep 60' >"$fake/qemu-no-boot"
  printf '%s\n' '#!/bin/sh' \
    'printf "%s\r\n" "=== LANCET CAN GUEST UP ===" "=== LANCET CAN TESTS BEGIN ===" "[ RUN      ] Stand.In" "[       OK ] Stand.In (1 ms)" "[ RUN      ] Stand.Hangs" "  some output of it"' \
    'exec sleep 60' >"$fake/qemu-hangs-in-a-test"
  chmod +x "$fake/qemu-no-boot" "$fake/qemu-hangs-in-a-test"
  # expect_message NAME QEMU TEXT...: exit 1, each TEXT a line or part of one
  expect_message() {
    name=$1 qemu=$2
    shift 2
    out=$(env -u CI LANCET_QEMU="$qemu" LANCET_CAN_KERNEL_DIR="$fake/kernel" LANCET_QEMU_TIMEOUT=2 "$runner" "$true_bin" "$fake/work" 2>&1)
    rc=$?
    missing=""
    for text in "$@"; do printf '%s\n' "$out" | grep -qF -- "$text" || missing="$missing '$text'"; done
    if [ "$rc" -ne 1 ] || [ -n "$missing" ]; then
      echo "FAILED: $name: exit $rc (wanted 1), missing:$missing; output:"
      printf '%s\n' "$out" | sed 's/^/    /'
      failures=$((failures + 1))
    else
      echo "ok: $name: exit $rc, $(printf '%s\n' "$out" | grep -F -- "$1" | head -n 1)"
    fi
  }
  expect_message "a guest that does not boot" "$fake/qemu-no-boot" \
    "timeout: the guest's kernel did not boot to its init within LANCET_QEMU_TIMEOUT=2 s"
  expect_message "a test that hangs" "$fake/qemu-hangs-in-a-test" \
    "timeout: the suite did not finish within LANCET_QEMU_TIMEOUT=2 s (boot included): Stand.Hangs was still running" \
    "  some output of it"
else
  echo "note: no busybox: the timeout cases were not run"
fi
[ "$failures" -eq 0 ]
