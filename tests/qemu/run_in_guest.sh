#!/bin/sh
# Boots a Debian kernel in QEMU with a busybox initramfs, runs one program in it, prints what it
# printed and exits with its status. The CAN suite (vcan in the stock kernel) and the PREEMPT_RT
# suite (lancet-rt on the real-time kernel) both run through it.
#
#   run_in_guest.sh [options] WORK_DIR PROGRAM [arguments...]
#
# Options:
#   --name TAG        names the console markers (=== LANCET TAG GUEST UP ===, ... TESTS BEGIN/END)
#                     and this script's messages; default GUEST
#   --kernel PACKAGE  the Debian metapackage whose kernel boots: linux-image-amd64 (default) or
#                     linux-image-rt-amd64 (PREEMPT_RT)
#   --module PATH     a module of that kernel (its path under lib/modules/VERSION/kernel/, without
#                     .ko's compression suffix) to load before the program; repeatable
#   --with PROGRAM    copied into /test/ (the guest's LANCET_TOOLS_DIR) with its shared libraries
#   --file FILE       copied into / under its base name; repeatable
#   --setup FILE      a shell fragment the guest's init sources after loading the modules (e.g. it
#                     creates vcan0); a non-zero status there is reported as a skip
#   --append ARGS     added to the kernel command line (e.g. "isolcpus=1 nohz_full=1 rcu_nocbs=1")
#   --cpus N          vCPUs (default: LANCET_QEMU_CPUS, else 1: with two, every wake-up across vCPUs
#                     costs milliseconds under TCG)
#   --memory MB       guest memory (default 512)
#   --env-prefix P    the caller's variables whose names start with P go into the guest; repeatable
#
# The kernel: the first run resolves the metapackage to its versioned package (apt-cache depends),
# downloads it with `apt-get download` (not installed) and keeps vmlinuz and the named modules in
# LANCET_QEMU_KERNEL_DIR (default WORK_DIR/kernel)/<package>/; offline, any kernel of that kind
# extracted before will do. The initramfs: busybox, the modules, PROGRAM as /test/<its name>, each
# --with program, each --file, the shared libraries ldd lists (binaries without debug information).
# The guest's init mounts /proc, /sys, /dev, /dev/shm and /tmp, loads the modules, sources the
# setup, runs PROGRAM with LANCET_TOOLS_DIR=/test and LANCET_GUEST="<what boots, how emulated>",
# and reports its status through the isa-debug-exit port.
#
# The emulator: LANCET_QEMU (default qemu-system-x86_64). LANCET_QEMU_ACCEL: tcg (default), kvm, or
# auto: KVM where /dev/kvm opens and a probe boot of this kernel reaches its init within
# LANCET_QEMU_KVM_DEADLINE seconds (default 60), else TCG. A Linux guest under nested KVM was seen
# to stall right after its first lines on the development VMs; the probe's verdict is kept beside
# the kernel (kvm-verdict), so only the first run pays for it. Either way the script says which.
#
# Exit status: the program's; 1 when the guest dies before reporting, or does not report within
# LANCET_QEMU_TIMEOUT seconds (boot and program; default 280), with what was still running (the
# boot, or the gtest test that had started and not ended); 77 (skip) with the reason on stdout when
# QEMU, busybox or the kernel cannot be had or run, or, with CI=true, 1 (a CI machine must run
# these suites, not skip them).
# Needs: qemu-system-x86, busybox-static, dpkg-deb, gzip, apt (first run only); strip (optional).
set -u

SKIP=77
tag=GUEST
pkg_meta=linux-image-amd64
modules=""
tools=""
files=""
setup=""
append=""
cpus=${LANCET_QEMU_CPUS:-1}
memory=512
env_prefixes=""
me=${LANCET_GUEST_RUNNER_NAME:-run_in_guest}

skip() {
  if [ "${CI:-}" = "true" ]; then
    echo "FAIL: $*"
    echo "$me: CI=true: this suite must run here, so this is a failure, not a skip" >&2
    exit 1
  fi
  echo "SKIP: $*"
  exit "$SKIP"
}
die() {
  echo "$me: $*" >&2
  exit 1
}

while [ $# -gt 0 ]; do
  case "$1" in
    --name) [ $# -ge 2 ] || die "--name needs a tag"; tag=$2; shift 2 ;;
    --kernel) [ $# -ge 2 ] || die "--kernel needs a package"; pkg_meta=$2; shift 2 ;;
    --module) [ $# -ge 2 ] || die "--module needs a path"; modules="$modules $2"; shift 2 ;;
    --with)
      [ $# -ge 2 ] || die "--with needs a program"
      [ -x "$2" ] || die "no executable program at $2 (--with)"
      tools="$tools $2"; shift 2 ;;
    --file)
      [ $# -ge 2 ] || die "--file needs a file"
      [ -f "$2" ] || die "no file at $2 (--file)"
      files="$files $2"; shift 2 ;;
    --setup)
      [ $# -ge 2 ] || die "--setup needs a file"
      [ -f "$2" ] || die "no file at $2 (--setup)"
      setup=$2; shift 2 ;;
    --append) [ $# -ge 2 ] || die "--append needs arguments"; append="$append $2"; shift 2 ;;
    --cpus) [ $# -ge 2 ] || die "--cpus needs a count"; cpus=$2; shift 2 ;;
    --memory) [ $# -ge 2 ] || die "--memory needs MB"; memory=$2; shift 2 ;;
    --env-prefix) [ $# -ge 2 ] || die "--env-prefix needs a prefix"; env_prefixes="$env_prefixes $2"; shift 2 ;;
    --) shift; break ;;
    -*) die "unknown option $1" ;;
    *) break ;;
  esac
done
[ $# -ge 2 ] || die "usage: $0 [options] WORK_DIR PROGRAM [arguments...]"
work=$1
bin=$2
shift 2
[ -x "$bin" ] || die "no executable program at $bin"
case "$cpus" in '' | *[!0-9]*) die "--cpus: not a count: $cpus" ;; esac
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

# ---- the kernel: vmlinuz + the modules, cached ----
kcache=${LANCET_QEMU_KERNEL_DIR:-$work/kernel}
mkdir -p "$kcache"
kind=stock
case "$pkg_meta" in *-rt-*) kind=rt ;; esac
kdir=""
if command -v apt-cache >/dev/null; then
  pkg=$(apt-cache depends "$pkg_meta" 2>/dev/null | awk '/Depends: linux-image-[0-9]/ { print $2; exit }')
  [ -n "$pkg" ] && kdir="$kcache/$pkg"
fi
# A cached kernel must hold every module asked for (a cache made for another suite may not).
has_modules() {
  for m in $modules; do [ -f "$1/$(basename "$m").ko" ] || return 1; done
  return 0
}
if [ -z "$kdir" ] || [ ! -f "$kdir/ready" ] || ! has_modules "$kdir"; then
  # Offline or no apt: any kernel of this kind extracted before, with the modules, will do.
  for d in "$kcache"/*/; do
    [ -f "$d/ready" ] || continue
    case "$(basename "$d")" in *-rt-*) dkind=rt ;; *) dkind=stock ;; esac
    if [ "$dkind" = "$kind" ] && has_modules "${d%/}"; then kdir=${d%/}; break; fi
  done
fi
if [ -z "$kdir" ]; then
  skip "cannot resolve the kernel package (apt-cache depends $pkg_meta gave nothing) and none is cached in $kcache"
fi
if [ ! -f "$kdir/ready" ] || ! has_modules "$kdir"; then
  pkg=$(basename "$kdir")
  ver=${pkg#linux-image-}
  echo "$me: fetching $pkg into $kdir (once)"
  rm -rf "$kdir" && mkdir -p "$kdir/dl" || die "cannot create $kdir"
  (cd "$kdir/dl" && apt-get download "$pkg" >/dev/null 2>"$kdir/dl/apt.log") ||
    { cat "$kdir/dl/apt.log"; rm -rf "$kdir"; skip "apt-get download $pkg failed (no network or no apt lists: run apt-get update)"; }
  deb=$(ls "$kdir"/dl/*.deb 2>/dev/null | head -n 1)
  [ -n "$deb" ] || { rm -rf "$kdir"; skip "apt-get download $pkg left no .deb"; }
  # The wanted members as the package names them (modules may be compressed).
  members="./boot/vmlinuz-$ver"
  for m in $modules; do
    found=$(dpkg-deb -c "$deb" | awk '{ print $NF }' | grep -E "^\./(usr/)?lib/modules/$ver/kernel/$m\.ko(\.xz|\.zst)?\$" | head -n 1)
    [ -n "$found" ] || { rm -rf "$kdir"; skip "$pkg has no module $m"; }
    members="$members $found"
  done
  mkdir -p "$kdir/x"
  # shellcheck disable=SC2086
  dpkg-deb --fsys-tarfile "$deb" | tar -x -C "$kdir/x" $members || { rm -rf "$kdir"; die "cannot extract $members from $deb"; }
  cp "$kdir/x/boot/vmlinuz-$ver" "$kdir/vmlinuz" || die "no vmlinuz in $deb"
  for m in $modules; do
    name=$(basename "$m").ko
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
kernel_name=$(cat "$kdir/ready")

# ---- the initramfs ----
root="$work/initramfs"
rm -rf "$root"
mkdir -p "$root/bin" "$root/proc" "$root/sys" "$root/dev" "$root/tmp" "$root/modules" "$root/test" || die "cannot create $root"
cp "$busybox" "$root/bin/busybox"
ln -s busybox "$root/bin/sh"  # the init makes the other applets' links (busybox --install)
: >"$root/modules/order"  # loaded in the order given (a module after those it needs)
for m in $modules; do
  cp "$kdir/$(basename "$m").ko" "$root/modules/" && echo "$(basename "$m").ko" >>"$root/modules/order"
done
# Without debug information the initramfs is a tenth of the size (and unpacks faster under TCG).
put_binary() {
  if command -v strip >/dev/null && strip --strip-debug -o "$2" "$1" 2>/dev/null; then return 0; fi
  cp "$1" "$2"
}
program=$(basename "$bin")
put_binary "$bin" "$root/test/$program" || die "cannot copy $bin"
for t in $tools; do put_binary "$t" "$root/test/$(basename "$t")" || die "cannot copy $t"; done
for f in $files; do cp "$f" "$root/$(basename "$f")" || die "cannot copy $f"; done
if [ -n "$setup" ]; then cp "$setup" "$root/setup" || die "cannot copy $setup"; else : >"$root/setup"; fi
# Shared libraries of the program, the tools (and busybox, should it not be the static one).
copy_libs() {
  ldd "$1" 2>/dev/null | awk '{ for (i = 1; i <= NF; ++i) if ($i ~ /^\//) print $i }' | while read -r lib; do
    [ -f "$root$lib" ] && continue
    mkdir -p "$root$(dirname "$lib")" && cp -L "$lib" "$root$lib"
  done
}
copy_libs "$bin"
for t in $tools; do copy_libs "$t"; done
copy_libs "$busybox"
# The program's arguments, one per line (no spaces inside one).
: >"$root/args"
for a in "$@"; do printf '%s\n' "$a" >>"$root/args"; done
# The caller's variables with the given prefixes (plain values only).
: >"$root/env"
for p in $env_prefixes; do
  env | grep -E "^${p}[A-Z0-9_]*=[-A-Za-z0-9_.,:/]*\$" | sed 's/^/export /' >>"$root/env"
done

# ---- the emulator's accelerator ----
accel=${LANCET_QEMU_ACCEL:-tcg}
accel_note=""
verdict="$kdir/kvm-verdict"
if [ "$accel" = "auto" ]; then
  if [ -f "$verdict" ]; then
    accel=$(head -n 1 "$verdict")
    accel_note=" ($(sed -n 2p "$verdict"))"
  elif [ -r /dev/kvm ] && [ -w /dev/kvm ]; then
    accel=probe
  else
    accel=tcg
    accel_note=" (no usable /dev/kvm)"
  fi
fi
case "$accel" in tcg | kvm | probe) ;; *) die "LANCET_QEMU_ACCEL: tcg, kvm or auto, not $accel" ;; esac

cat >"$root/init" <<EOF
#!/bin/sh
/bin/busybox --install -s /bin
export PATH=/bin:/test
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
echo "=== LANCET $tag GUEST UP ==="
report() { printf "\\\\\$(printf %o "\$1")" | dd of=/dev/port bs=1 seek=244 count=1 2>/dev/null; poweroff -f; }
grep -q lancet_probe /proc/cmdline && report 0
mkdir -p /dev/shm && mount -t tmpfs shm /dev/shm && mount -t tmpfs tmp /tmp || { echo "=== LANCET $tag SETUP FAILED: tmpfs ==="; report $SKIP; }
for m in \$(cat /modules/order); do insmod "/modules/\$m" || { echo "=== LANCET $tag SETUP FAILED: insmod \$m ==="; report $SKIP; }; done
export LANCET_TOOLS_DIR=/test
export LANCET_GUEST="$kernel_name, CPUs \$(cat /sys/devices/system/cpu/online) online, QEMU \$(cat /lancet_accel)"
. /setup || { echo "=== LANCET $tag SETUP FAILED: the setup ==="; report $SKIP; }
. /env
echo "=== LANCET $tag TESTS BEGIN ==="
/test/$program \$(cat /args)
rc=\$?
echo "=== LANCET $tag TESTS END rc=\$rc ==="
[ \$rc -gt 100 ] && rc=100
report \$rc
EOF
chmod +x "$root/init"

log="$work/console.log"
# boot ACCEL LIMIT [EXTRA_APPEND]: one guest, its console in $log; sets qrc.
boot() {
  if [ "$1" = "kvm" ]; then set -- "-accel kvm -cpu host" "$2" "${3:-}"; else set -- "-accel tcg" "$2" "${3:-}"; fi
  # shellcheck disable=SC2086 # $1 is the accelerator's words
  timeout "$2" "$qemu" $1 -nographic -no-reboot -m "$memory" -smp "$cpus" -net none \
    -device isa-debug-exit,iobase=0xf4,iosize=0x04 -kernel "$kdir/vmlinuz" -initrd "$work/initrd.gz" \
    -append "console=ttyS0 panic=-1 quiet$append${3:+ $3}" </dev/null >"$log" 2>&1
  qrc=$?
}
pack() {
  echo "$1" >"$root/lancet_accel"
  (cd "$root" && find . | "$busybox" cpio -o -H newc 2>/dev/null) | gzip -1 >"$work/initrd.gz" || die "cannot pack the initramfs"
}
if [ "$accel" = "probe" ]; then
  deadline=${LANCET_QEMU_KVM_DEADLINE:-60}
  pack "KVM (probe)"
  boot kvm "$deadline" lancet_probe
  if grep -aq "=== LANCET $tag GUEST UP ===" "$log"; then
    accel=kvm
    printf 'kvm\n%s\n' "a probe boot under KVM reached its init within $deadline s" >"$verdict"
  elif [ "$qrc" -eq 124 ]; then
    accel=tcg
    printf 'tcg\n%s\n' "a probe boot under KVM did not reach its init within $deadline s" >"$verdict"
  else
    accel=tcg
    why=$(tr -d '\r' <"$log" | grep -ai 'error' | head -n 1 | cut -c1-160)
    [ -n "$why" ] || why=$(tr -d '\r' <"$log" | grep -a . | tail -n 1 | cut -c1-160)
    printf 'tcg\n%s\n' "a probe boot under KVM failed (QEMU exit $qrc: $why)" >"$verdict"
  fi
  accel_note=" ($(sed -n 2p "$verdict"))"
fi
if [ "$accel" = "kvm" ]; then accel_words="KVM, -cpu host"; else accel_words="TCG (emulated CPU, no KVM)"; fi
pack "$accel_words"

# ---- boot ----
limit=${LANCET_QEMU_TIMEOUT:-280}
t0=$(date +%s)
boot "$accel" "$limit"
t1=$(date +%s)
tr -d '\r' <"$log" | sed -n "/=== LANCET $tag TESTS BEGIN ===/,/=== LANCET $tag TESTS END/p" | grep -av "=== LANCET $tag TESTS"
echo "$me: guest ran $((t1 - t0)) s ($kernel_name, $cpus vCPU, $accel_words$accel_note${append:+, boot line:$append})"

if ! grep -aq "=== LANCET $tag GUEST UP ===" "$log"; then
  tail -n 20 "$log"
  [ "$qrc" -eq 124 ] && die "timeout: the guest's kernel did not boot to its init within LANCET_QEMU_TIMEOUT=$limit s (nothing ran; console: $log)"
  skip "QEMU could not boot the guest (exit $qrc): see $log"
fi
if grep -aq "=== LANCET $tag SETUP FAILED" "$log"; then
  grep -a "=== LANCET $tag SETUP FAILED" "$log"
  skip "the guest could not be set up (see $log)"
fi
if ! grep -aq "=== LANCET $tag TESTS END" "$log"; then
  # The test that was running: the last gtest one started that neither passed nor failed.
  running=$(tr -d '\r' <"$log" | awk '
    /^\[ RUN      \] / { name = $4 }
    /^\[       OK \] / || /^\[  FAILED  \] / || /^\[  SKIPPED \] / { if ($4 == name) name = "" }
    END { print name }')
  if [ "$qrc" -eq 124 ]; then
    if ! grep -aq "=== LANCET $tag TESTS BEGIN ===" "$log"; then
      die "timeout: the guest came up but did not start the program within LANCET_QEMU_TIMEOUT=$limit s (setting up; console: $log)"
    elif [ -n "$running" ]; then
      die "timeout: the suite did not finish within LANCET_QEMU_TIMEOUT=$limit s (boot included): $running was still running (its output so far is above; console: $log)"
    else
      die "timeout: the suite did not finish within LANCET_QEMU_TIMEOUT=$limit s (boot included), between two tests (console: $log)"
    fi
  fi
  [ -n "$running" ] && die "the guest stopped during $running (QEMU exit $qrc; console: $log)"
  die "the guest stopped before the program finished (QEMU exit $qrc; console: $log)"
fi
rc=$(tr -d '\r' <"$log" | sed -n "s/.*=== LANCET $tag TESTS END rc=\([0-9]*\) ===.*/\1/p" | tail -n 1)
if [ $((qrc % 2)) -eq 1 ] && [ $((qrc / 2)) -ne "$((rc > 100 ? 100 : rc))" ]; then
  echo "$me: note: QEMU reported status $((qrc / 2)), the console rc=$rc"
fi
exit "$rc"
