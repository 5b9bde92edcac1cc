#!/bin/sh
# Runs a SocketCAN test binary inside one QEMU boot of a Debian kernel with vcan (the host kernel
# may have no CAN at all), prints its output and exits with its status.
#
#   run_can_tests_in_qemu.sh [--with PROGRAM]... TEST_BINARY WORK_DIR [test arguments...]
#
# WORK_DIR keeps the kernel between runs (WORK_DIR/kernel/<package>/, or LANCET_CAN_KERNEL_DIR):
# the first run downloads the package linux-image-amd64 depends on with `apt-get download` (about
# 70 MB, not installed) and extracts vmlinuz and four modules (can, can-raw, can-dev, vcan). Each
# run builds an initramfs (busybox, the modules, the binary, each --with program in /test/ (the
# guest's LANCET_TOOLS_DIR), the shared libraries ldd lists, hw_configs/canopen_arm.toml; binaries
# without their debug information) and boots it with `qemu-system-x86_64 -accel tcg` (LANCET_QEMU
# overrides the emulator); the guest's init loads the modules, creates vcan0, mounts /dev/shm and
# /tmp, runs the binary with LANCET_CANOPEN_CONFIG, LANCET_TOOLS_DIR and LANCET_CAN_ENV set, and
# reports its status through the isa-debug-exit port (QEMU exits with status·2 + 1).
#
# Exit status: the binary's; 1 when the guest dies before reporting, or when it does not report
# within LANCET_QEMU_TIMEOUT seconds (boot and the whole suite; default 280; ctest sets 870, just
# under its TIMEOUT of 900, so that this script, not ctest, says what timed out: the boot, or which
# test was running), several times what the suite takes under TCG on a loaded 2-core host; the tests
# inside have their own hang deadlines (30 s each). When QEMU, busybox or
# the kernel package is not available or cannot run: 77 (skip) with the reason on stdout, or, with
# CI=true in the environment, 1 (a CI machine must run the CAN suite, not skip it).
# Needs: qemu-system-x86, busybox-static, dpkg-deb, gzip, apt (first run only); strip (optional).
set -u

SKIP=77
skip() {
  if [ "${CI:-}" = "true" ]; then
    echo "FAIL: $*"
    echo "run_can_tests_in_qemu: CI=true: the CAN suite must run here, so this is a failure, not a skip" >&2
    exit 1
  fi
  echo "SKIP: $*"
  exit "$SKIP"
}
die() {
  echo "run_can_tests_in_qemu: $*" >&2
  exit 1
}

tools=""
while [ $# -gt 0 ] && [ "$1" = "--with" ]; do
  [ $# -ge 2 ] || die "--with needs a program"
  [ -x "$2" ] || die "no executable program at $2 (--with)"
  tools="$tools $2"
  shift 2
done
[ $# -ge 2 ] || die "usage: $0 [--with PROGRAM]... TEST_BINARY WORK_DIR [test arguments...]"
bin=$1
work=$2
shift 2
[ -x "$bin" ] || die "no executable test binary at $bin"
here=$(cd "$(dirname "$0")" && pwd)
config="$here/../../../hw_configs/canopen_arm.toml"
[ -f "$config" ] || die "no $config"
mkdir -p "$work" || die "cannot create $work"
work=$(cd "$work" && pwd)

qemu_name=${LANCET_QEMU:-qemu-system-x86_64}
qemu=$(command -v "$qemu_name") || skip "$qemu_name is not installed (apt-get install -y --no-install-recommends qemu-system-x86 busybox-static)"
busybox=""
for b in /bin/busybox /usr/bin/busybox "$(command -v busybox 2>/dev/null)"; do
  if [ -n "$b" ] && [ -x "$b" ]; then busybox=$b; break; fi
done
[ -n "$busybox" ] || skip "busybox is not installed (apt-get install -y --no-install-recommends busybox-static)"
command -v dpkg-deb >/dev/null || skip "dpkg-deb is not available to unpack the kernel package"

# ---- the kernel: vmlinuz + can, can-raw, can-dev, vcan, cached in WORK_DIR ----
modules="net/can/can.ko net/can/can-raw.ko drivers/net/can/dev/can-dev.ko drivers/net/can/vcan.ko"
kcache=${LANCET_CAN_KERNEL_DIR:-$work/kernel}
mkdir -p "$kcache"
kdir=""
if command -v apt-cache >/dev/null; then
  pkg=$(apt-cache depends linux-image-amd64 2>/dev/null | awk '/Depends: linux-image-[0-9]/ { print $2; exit }')
  [ -n "$pkg" ] && kdir="$kcache/$pkg"
fi
if [ -z "$kdir" ] || [ ! -f "$kdir/ready" ]; then
  # Offline or no apt: any kernel extracted before will do.
  for d in "$kcache"/*/; do
    if [ -f "$d/ready" ]; then kdir=${d%/}; break; fi
  done
fi
if [ -z "$kdir" ]; then
  skip "cannot resolve the kernel package (apt-cache depends linux-image-amd64 gave nothing) and none is cached in $kcache"
fi
if [ ! -f "$kdir/ready" ]; then
  pkg=$(basename "$kdir")
  ver=${pkg#linux-image-}
  echo "run_can_tests_in_qemu: fetching $pkg into $kdir (once)"
  rm -rf "$kdir" && mkdir -p "$kdir/dl" || die "cannot create $kdir"
  (cd "$kdir/dl" && apt-get download "$pkg" >/dev/null 2>"$kdir/dl/apt.log") ||
    { cat "$kdir/dl/apt.log"; rm -rf "$kdir"; skip "apt-get download $pkg failed (no network or no apt lists: run apt-get update)"; }
  deb=$(ls "$kdir"/dl/*.deb 2>/dev/null | head -n 1)
  [ -n "$deb" ] || { rm -rf "$kdir"; skip "apt-get download $pkg left no .deb"; }
  # The wanted members as the package names them (modules may be compressed).
  members="./boot/vmlinuz-$ver"
  for m in $modules; do
    found=$(dpkg-deb -c "$deb" | awk '{ print $NF }' | grep -E "^\./(usr/)?lib/modules/$ver/kernel/$m(\.xz|\.zst)?\$" | head -n 1)
    [ -n "$found" ] || { rm -rf "$kdir"; skip "$pkg has no $m: this kernel cannot do vcan"; }
    members="$members $found"
  done
  mkdir -p "$kdir/x"
  # shellcheck disable=SC2086
  dpkg-deb --fsys-tarfile "$deb" | tar -x -C "$kdir/x" $members || { rm -rf "$kdir"; die "cannot extract $members from $deb"; }
  cp "$kdir/x/boot/vmlinuz-$ver" "$kdir/vmlinuz" || die "no vmlinuz in $deb"
  for m in $modules; do
    name=$(basename "$m")
    src=$(find "$kdir/x" -name "$name*" | head -n 1)
    case "$src" in
      *.xz) xz -dc "$src" >"$kdir/$name" || skip "cannot decompress $src (xz missing?)" ;;
      *.zst) zstd -dc "$src" >"$kdir/$name" || skip "cannot decompress $src (zstd missing?)" ;;
      *) cp "$src" "$kdir/$name" ;;
    esac
  done
  rm -rf "$kdir/x" "$kdir/dl"
  echo "$pkg" >"$kdir/ready"
fi

# ---- the initramfs ----
root="$work/initramfs"
rm -rf "$root"
mkdir -p "$root/bin" "$root/proc" "$root/sys" "$root/dev" "$root/tmp" "$root/modules" "$root/test" || die "cannot create $root"
cp "$busybox" "$root/bin/busybox"
for tool in sh mount mkdir insmod ip poweroff dd printf echo cat sleep grep; do ln -s busybox "$root/bin/$tool"; done
for m in $modules; do cp "$kdir/$(basename "$m")" "$root/modules/"; done
# Without debug information the initramfs is a tenth of the size (and unpacks faster under TCG).
put_binary() {
  if command -v strip >/dev/null && strip --strip-debug -o "$2" "$1" 2>/dev/null; then return 0; fi
  cp "$1" "$2"
}
put_binary "$bin" "$root/test/tests" || die "cannot copy $bin"
for t in $tools; do put_binary "$t" "$root/test/$(basename "$t")" || die "cannot copy $t"; done
cp "$config" "$root/canopen_arm.toml"
# Shared libraries of the test binary (and of busybox, should it not be the static one).
copy_libs() {
  ldd "$1" 2>/dev/null | awk '{ for (i = 1; i <= NF; ++i) if ($i ~ /^\//) print $i }' | while read -r lib; do
    [ -f "$root$lib" ] && continue
    mkdir -p "$root$(dirname "$lib")" && cp -L "$lib" "$root$lib"
  done
}
copy_libs "$bin"
for t in $tools; do copy_libs "$t"; done
copy_libs "$busybox"
# The test's arguments, one per line (no spaces inside one).
: >"$root/args"
for a in "$@"; do printf '%s\n' "$a" >>"$root/args"; done
# One vCPU: with two, every wake-up across vCPUs costs milliseconds under TCG.
cpus=${LANCET_QEMU_CPUS:-1}
# LANCET_CAN_* variables of the caller go into the guest (e.g. LANCET_CAN_SYNC_US).
env | grep -E '^LANCET_CAN_[A-Z0-9_]*=[-A-Za-z0-9_.,:/]*$' | sed 's/^/export /' >"$root/env"
cat >"$root/init" <<EOF
#!/bin/sh
export PATH=/bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
echo "=== LANCET CAN GUEST UP ==="
report() { printf "\\\\\$(printf %o "\$1")" | dd of=/dev/port bs=1 seek=244 count=1 2>/dev/null; poweroff -f; }
for m in can can-raw can-dev vcan; do insmod /modules/\$m.ko || { echo "=== LANCET CAN SETUP FAILED: insmod \$m ==="; report $SKIP; }; done
ip link add dev vcan0 type vcan && ip link set vcan0 up || { echo "=== LANCET CAN SETUP FAILED: vcan0 ==="; report $SKIP; }
mkdir -p /dev/shm && mount -t tmpfs shm /dev/shm && mount -t tmpfs tmp /tmp || { echo "=== LANCET CAN SETUP FAILED: tmpfs ==="; report $SKIP; }
echo "=== LANCET CAN TESTS BEGIN ==="
. /env
LANCET_CANOPEN_CONFIG=/canopen_arm.toml LANCET_TOOLS_DIR=/test LANCET_CAN_ENV="QEMU TCG guest (emulated CPU, no KVM), $cpus vCPU" /test/tests --gtest_color=no \$(cat /args)
rc=\$?
echo "=== LANCET CAN TESTS END rc=\$rc ==="
[ \$rc -gt 100 ] && rc=100
report \$rc
EOF
chmod +x "$root/init"
(cd "$root" && find . | "$busybox" cpio -o -H newc 2>/dev/null) | gzip -1 >"$work/initrd.gz" || die "cannot pack the initramfs"

# ---- boot ----
log="$work/console.log"
limit=${LANCET_QEMU_TIMEOUT:-280}
t0=$(date +%s)
timeout "$limit" "$qemu" -accel tcg -nographic -no-reboot -m 512 -smp "$cpus" -net none \
  -device isa-debug-exit,iobase=0xf4,iosize=0x04 -kernel "$kdir/vmlinuz" -initrd "$work/initrd.gz" \
  -append "console=ttyS0 panic=-1 quiet" </dev/null >"$log" 2>&1
qrc=$?
t1=$(date +%s)
tr -d '\r' <"$log" | sed -n '/=== LANCET CAN TESTS BEGIN ===/,/=== LANCET CAN TESTS END/p' | grep -av '=== LANCET CAN TESTS'
echo "run_can_tests_in_qemu: guest ran $((t1 - t0)) s ($(cat "$kdir/ready"), $cpus vCPU, TCG)"

if ! grep -aq "=== LANCET CAN GUEST UP ===" "$log"; then
  tail -n 20 "$log"
  [ "$qrc" -eq 124 ] && die "timeout: the guest's kernel did not boot to its init within LANCET_QEMU_TIMEOUT=$limit s (no test ran; console: $log)"
  skip "QEMU could not boot the guest (exit $qrc): see $log"
fi
if grep -aq "=== LANCET CAN SETUP FAILED" "$log"; then
  grep -a "=== LANCET CAN SETUP FAILED" "$log"
  skip "the guest kernel could not set up vcan0 (see $log)"
fi
if ! grep -aq "=== LANCET CAN TESTS END" "$log"; then
  # The test that was running: the last one started that neither passed nor failed.
  running=$(tr -d '\r' <"$log" | awk '
    /^\[ RUN      \] / { name = $4 }
    /^\[       OK \] / || /^\[  FAILED  \] / || /^\[  SKIPPED \] / { if ($4 == name) name = "" }
    END { print name }')
  if [ "$qrc" -eq 124 ]; then
    if ! grep -aq "=== LANCET CAN TESTS BEGIN ===" "$log"; then
      die "timeout: the guest came up but did not start the tests within LANCET_QEMU_TIMEOUT=$limit s (setting up vcan0; console: $log)"
    elif [ -n "$running" ]; then
      die "timeout: the suite did not finish within LANCET_QEMU_TIMEOUT=$limit s (boot included): $running was still running (its output so far is above; console: $log)"
    else
      die "timeout: the suite did not finish within LANCET_QEMU_TIMEOUT=$limit s (boot included), between two tests (console: $log)"
    fi
  fi
  [ -n "$running" ] && die "the guest stopped during $running (QEMU exit $qrc; console: $log)"
  die "the guest stopped before the tests finished (QEMU exit $qrc; console: $log)"
fi
rc=$(tr -d '\r' <"$log" | sed -n 's/.*=== LANCET CAN TESTS END rc=\([0-9]*\) ===.*/\1/p' | tail -n 1)
if [ $((qrc % 2)) -eq 1 ] && [ $((qrc / 2)) -ne "$(( rc > 100 ? 100 : rc ))" ]; then
  echo "run_can_tests_in_qemu: note: QEMU reported status $((qrc / 2)), the console rc=$rc"
fi
exit "$rc"
