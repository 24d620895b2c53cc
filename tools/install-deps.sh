#!/usr/bin/env bash
# Installs the Debian 12 packages canbridge needs to build, test and benchmark (as root).
# Does nothing when everything is already there.
set -euo pipefail
packages=(
  cmake ninja-build g++ clang clang-format libclang-rt-14-dev
  lld  # LLVM's linker: links the sanitizer tree's test programs in CI (tools/test.sh)
  libboost1.81-dev protobuf-compiler libprotobuf-dev
  libgtest-dev libgmock-dev libyaml-cpp-dev libspdlog-dev libssl-dev liburing-dev
  can-utils iproute2 kmod user-mode-linux
  libcli11-dev tshark
  dpkg-dev  # dpkg-shlibdeps: the .deb's library dependencies (cpack -G DEB, tests/package)
  help2man  # the manual pages, from each executable's --help (cmake/packaging.cmake)
  lintian   # Debian's package checker, run on the .deb by tests/package
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "install-deps: installing ${missing[*]}"
  sudo=""
  [[ $(id -u) -ne 0 ]] && sudo=sudo
  $sudo apt-get update -qq
  # tshark reads the captures `canbridge capture` writes (tests); it never captures here, so
  # no group may capture either.
  echo "wireshark-common wireshark-common/install-setuid boolean false" | $sudo debconf-set-selections
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
