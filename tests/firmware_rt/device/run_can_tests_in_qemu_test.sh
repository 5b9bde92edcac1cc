#!/bin/sh
# The QEMU runner's verdicts when the guest cannot run, without booting one:
#   no emulator            → 77 and "SKIP: ..." (plain), 1 and "FAIL: ..." (CI=true)
#   an emulator that fails → the same (only when a kernel is cached: nothing is downloaded here)
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
[ "$failures" -eq 0 ]
