#!/usr/bin/env bash
# Installs what tools/cross-build.sh needs to cross-build canbridge for a Debian ARM architecture
# and run its unit tests under qemu-user (as root): usage tools/install-cross-deps.sh ARCH...
# with ARCH armhf or arm64. Does nothing for an ARCH that is already complete.
#
# Host side (packages of the build machine): Debian's cross compiler for ARCH, qemu-user and
# protoc (the generator runs on the build machine; only libprotobuf is the target's).
#
# Target side: the target's libraries from Debian's ARCH archive, unpacked into a sysroot
# (/opt/canbridge-sysroot/ARCH, or $CANBRIDGE_SYSROOT_BASE/ARCH) instead of installed as
# multiarch packages (libfoo-dev:ARCH). Multiarch would put them beside the host's, but on
# bookworm that does not work cleanly (docs/cross-build.md): libyaml-cpp-dev is not
# Multi-Arch: same, so installing libyaml-cpp-dev:armhf removes the host's libyaml-cpp-dev; and
# Multi-Arch: same packages must have the same version for every architecture, so installing
# linux-libc-dev:ARCH, libssl-dev:ARCH or zlib1g-dev:ARCH upgrades the host's copies when the
# archive is ahead of them -- new kernel headers under every native build tree, which then
# rebuilds from scratch. The sysroot leaves dpkg's state and the host's headers untouched.
set -euo pipefail

sysroot_base=${CANBRIDGE_SYSROOT_BASE:-/opt/canbridge-sysroot}
# The target's build dependencies (tools/install-deps.sh lists the host's) and the run-time
# libraries their .so links resolve to. libc, libstdc++ and the kernel headers come with the
# cross compiler (/usr/<triplet>), so they are not in here.
target_packages=(
  libboost1.81-dev
  libprotobuf-dev libprotobuf32 libprotobuf-lite32 zlib1g zlib1g-dev
  libyaml-cpp-dev libyaml-cpp0.7
  libspdlog-dev libspdlog1.10 libfmt-dev libfmt9
  libssl-dev libssl3
  liburing-dev liburing2
  libgtest-dev libgmock-dev
)
# Architecture: all (headers only): the same package for every target, but the target's CMake
# looks for headers in the sysroot only.
target_packages_all=(libcli11-dev)

sudo=""
[[ $(id -u) -ne 0 ]] && sudo=sudo
apt_updated=0
apt_update() {
  if ((!apt_updated)); then
    $sudo apt-get update -qq
    apt_updated=1
  fi
}

install_host_packages() {
  local missing=() p
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if ((${#missing[@]})); then
    echo "install-cross-deps: installing ${missing[*]}"
    apt_update
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
  fi
}

# populate_sysroot ARCH TRIPLET: downloads the target packages for ARCH and unpacks them into
# the sysroot; a stamp file with the package versions makes a second run a no-op.
populate_sysroot() {
  local arch=$1 triplet=$2
  local root=$sysroot_base/$arch
  if ! dpkg --print-foreign-architectures | grep -qx "$arch"; then
    echo "install-cross-deps: adding dpkg architecture $arch (for apt-get download only)"
    $sudo dpkg --add-architecture "$arch"
    apt_updated=0
  fi
  local wanted=() p
  for p in "${target_packages[@]}"; do wanted+=("$p:$arch"); done
  wanted+=("${target_packages_all[@]}")
  local versions
  versions=$(apt-cache policy "${wanted[@]}" 2>/dev/null | awk '/^[^ ]/{p=$1} /Candidate:/{print p, $2}')
  # apt-cache prints nothing for a package it does not know (an architecture just added, whose
  # lists apt has not fetched yet), so a short list means the lists are stale, like "(none)".
  if grep -q "(none)" <<<"$versions" || (($(grep -c . <<<"$versions") < ${#wanted[@]})); then
    apt_update
    versions=$(apt-cache policy "${wanted[@]}" | awk '/^[^ ]/{p=$1} /Candidate:/{print p, $2}')
  fi
  if [[ -f $root/.canbridge-packages ]] && [[ $(cat "$root/.canbridge-packages") == "$versions" ]]; then
    return
  fi
  echo "install-cross-deps: unpacking ${#wanted[@]} $arch packages into $root"
  local download
  download=$(mktemp -d)
  chmod 755 "$download"
  # apt-get download runs as the _apt user where it can; the folder must be writable for it.
  chown _apt "$download" 2>/dev/null || true
  (cd "$download" && apt-get download -qq "${wanted[@]}")
  $sudo mkdir -p "$root"
  local deb
  for deb in "$download"/*.deb; do
    $sudo dpkg-deb -x "$deb" "$root"
  done
  rm -r "$download"
  # Absolute symlinks (/usr/lib/<triplet>/libfoo.so -> /lib/...) would point at the host.
  local link target
  while IFS= read -r link; do
    target=$(readlink "$link")
    $sudo ln -sfn "$root$target" "$link"
  done < <(find "$root" -type l -lname '/*')
  echo "$versions" | $sudo tee "$root/.canbridge-packages" >/dev/null
}

if (($# == 0)); then
  echo "usage: $0 ARCH... (armhf, arm64)" >&2
  exit 2
fi
for arch in "$@"; do
  case $arch in
    armhf) triplet=arm-linux-gnueabihf ;;
    arm64) triplet=aarch64-linux-gnu ;;
    *) echo "install-cross-deps: unknown architecture $arch (armhf, arm64)" >&2; exit 2 ;;
  esac
  install_host_packages "g++-$triplet" qemu-user protobuf-compiler cmake ninja-build ccache
  populate_sysroot "$arch" "$triplet"
done
