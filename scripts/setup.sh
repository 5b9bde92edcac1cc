#!/usr/bin/env bash
# Installs every Debian package Lancet needs (Debian 12). Idempotent: skips what is installed.
# Works as root or through sudo; never asks questions.
set -euo pipefail

PACKAGES=(
  # toolchain and build
  g++ make cmake ninja-build ccache pkg-config git
  # device backends (umockdev: the USB backend's tests without hardware)
  libusb-1.0-0-dev libmodbus-dev umockdev libumockdev-dev
  # a foreign Modbus server for the cross-check (run by Debian's /usr/bin/python3); a QEMU guest
  # with vcan for the CANopen tests (this kernel has no CAN)
  python3-pymodbus qemu-system-x86 busybox-static
  # visualizer
  libglfw3-dev libglm-dev libepoxy-dev libgl-dev libgl1-mesa-dri libimgui-dev libstb-dev libopenmesh-dev
  # headless GL without an X server (EGL, Mesa surfaceless)
  libegl-dev libegl1 libegl-mesa0
  # configuration, command lines, logging
  libtomlplusplus-dev libcli11-dev libspdlog-dev
  # volume files (compressed MetaImage, gzip NRRD, DICOM series)
  zlib1g-dev libgdcm-dev
  # tests and benchmarks (python3-vtk9: the marching-cubes cross-check against VTK, run by
  # Debian's /usr/bin/python3, and the ray caster's side-by-side with VTK, whose GPU mapper
  # renders only through GLX: xvfb for that benchmark alone)
  libgtest-dev libgmock-dev libbenchmark-dev rt-tests python3-vtk9 xvfb
  # a crashed lancet-viz's core read into the two-process tests' failure (every thread's stack)
  gdb
  # session recording (HDF5: readable by h5py, MATLAB, HDFView; h5py reads it back in a test)
  # and the report's test in a real browser (headless Chromium renders it to a PNG)
  libhdf5-dev python3-h5py chromium
  # training records (lancet-records): an SQLite file or a PostgreSQL server, attempts keyed by
  # SHA-256 (OpenSSL's libcrypto); the server for the records' tests, started by the tests themselves
  libsqlite3-dev libpq-dev libssl-dev postgresql
)

missing=()
for p in "${PACKAGES[@]}"; do
  if [ "$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null)" != "install ok installed" ]; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} packages are installed"
  exit 0
fi

if [ "$(id -u)" -eq 0 ]; then
  SUDO=()
elif command -v sudo >/dev/null 2>&1; then
  SUDO=(sudo)
else
  echo "setup: missing packages (${missing[*]}) and neither root nor sudo is available; install them as root" >&2
  exit 1
fi

echo "setup: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq
"${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "setup: done"
