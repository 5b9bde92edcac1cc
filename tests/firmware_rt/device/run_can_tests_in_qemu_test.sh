#!/bin/sh
# The QEMU runner's verdicts when the guest cannot run, without booting one:
#   no emulator            → 77 and "SKIP: ..." (plain), 1 and "FAIL: ..." (CI=true)
#   an emulator that fails → the same
#   a guest that hangs     → 1, and the message says what timed out: the boot, or the test that was
#                            running, with that test's output so far
# Past the emulator check, the runner builds an initramfs (it needs busybox) from a kernel cache and
# boots it: here the kernel is a stand-in (the runner only copies its files), apt-cache a stand-in
# that names no package (so the runner takes the cached one, and nothing is downloaded), and the
# emulators that hang are scripts that print a console and sleep. Those four cases run side by side
# (each in its own work directory): on a loaded host each waits mostly for a core.
#
#   run_can_tests_in_qemu_test.sh RUNNER WORK_DIR KERNEL_CACHE
# (KERNEL_CACHE, the suite's cache, is not used: every case runs on the stand-ins.)
set -u
[ $# -eq 3 ] || { echo "usage: $0 RUNNER WORK_DIR KERNEL_CACHE" >&2; exit 2; }
runner=$1
work=$2
mkdir -p "$work" || exit 2
work=$(cd "$work" && pwd)
true_bin=/bin/true
[ -x "$true_bin" ] || true_bin=/usr/bin/true
failures=0

# expect WANT_RC WANT_WORD NAME [env assignments...]: prints "ok: ..." or "FAILED: ..."
expect() {
  want=$1 word=$2 name=$3
  shift 3
  dir=$work/run-$(printf '%s' "$name" | tr -c 'A-Za-z0-9' '_')
  out=$(env -u CI "$@" "$runner" "$true_bin" "$dir" 2>&1)
  rc=$?
  if [ "$rc" -ne "$want" ] || ! printf '%s\n' "$out" | grep -q "^$word: "; then
    echo "FAILED: $name: exit $rc (wanted $want), output:"
    printf '%s\n' "$out" | sed 's/^/    /'
  else
    echo "ok: $name: exit $rc, $(printf '%s\n' "$out" | grep "^$word: " | head -n 1)"
  fi
}
# count RESULT...: prints the results, adds their failures to `failures`
count() {
  cat "$@"
  failures=$((failures + $(cat "$@" | grep -c '^FAILED: ')))
}

expect 77 SKIP "no QEMU" LANCET_QEMU=/nonexistent/qemu-system-x86_64 >"$work/result-1"
expect 1 FAIL "no QEMU, CI=true" LANCET_QEMU=/nonexistent/qemu-system-x86_64 CI=true >"$work/result-2"
count "$work/result-1" "$work/result-2"

if ! command -v busybox >/dev/null && [ ! -x /bin/busybox ] && [ ! -x /usr/bin/busybox ]; then
  echo "note: no busybox: the cases past the emulator check were not run"
  [ "$failures" -eq 0 ]
  exit
fi
fake="$work/fake"
rm -rf "$fake" && mkdir -p "$fake/kernel/linux-image-stand-in" "$fake/bin" || exit 2
for f in vmlinuz can.ko can-raw.ko can-dev.ko vcan.ko; do : >"$fake/kernel/linux-image-stand-in/$f"; done
echo linux-image-stand-in >"$fake/kernel/linux-image-stand-in/ready"
printf '%s\n' '#!/bin/sh' 'exit 0' >"$fake/bin/apt-cache"
printf '%s\n' '#!/bin/sh' 'echo "SeaBIOS (stand-in)"' 'exec sleep 60' >"$fake/qemu-no-boot"
printf '%s\n' '#!/bin/sh' \
  'printf "%s\r\n" "=== LANCET CAN GUEST UP ===" "=== LANCET CAN TESTS BEGIN ===" "[ RUN      ] Stand.In" "[       OK ] Stand.In (1 ms)" "[ RUN      ] Stand.Hangs" "  some output of it"' \
  'exec sleep 60' >"$fake/qemu-hangs-in-a-test"
chmod +x "$fake/bin/apt-cache" "$fake/qemu-no-boot" "$fake/qemu-hangs-in-a-test"
stand_ins="PATH=$fake/bin:$PATH LANCET_CAN_KERNEL_DIR=$fake/kernel"

# expect_message NAME QEMU TEXT...: exit 1, each TEXT a line or part of one
expect_message() {
  name=$1 qemu=$2
  shift 2
  dir=$work/run-$(printf '%s' "$name" | tr -c 'A-Za-z0-9' '_')
  # shellcheck disable=SC2086 # stand_ins is two assignments
  out=$(env -u CI $stand_ins LANCET_QEMU="$qemu" LANCET_QEMU_TIMEOUT=1 "$runner" "$true_bin" "$dir" 2>&1)
  rc=$?
  missing=""
  for text in "$@"; do printf '%s\n' "$out" | grep -qF -- "$text" || missing="$missing '$text'"; done
  if [ "$rc" -ne 1 ] || [ -n "$missing" ]; then
    echo "FAILED: $name: exit $rc (wanted 1), missing:$missing; output:"
    printf '%s\n' "$out" | sed 's/^/    /'
  else
    echo "ok: $name: exit $rc, $(printf '%s\n' "$out" | grep -F -- "$1" | head -n 1)"
  fi
}

# shellcheck disable=SC2086
expect 77 SKIP "QEMU cannot boot" $stand_ins LANCET_QEMU=false >"$work/result-3" &
# shellcheck disable=SC2086
expect 1 FAIL "QEMU cannot boot, CI=true" $stand_ins LANCET_QEMU=false CI=true >"$work/result-4" &
expect_message "a guest that does not boot" "$fake/qemu-no-boot" \
  "timeout: the guest's kernel did not boot to its init within LANCET_QEMU_TIMEOUT=1 s" >"$work/result-5" &
expect_message "a test that hangs" "$fake/qemu-hangs-in-a-test" \
  "timeout: the suite did not finish within LANCET_QEMU_TIMEOUT=1 s (boot included): Stand.Hangs was still running" \
  "  some output of it" >"$work/result-6" &
wait
count "$work/result-3" "$work/result-4" "$work/result-5" "$work/result-6"
[ "$failures" -eq 0 ]
