#!/usr/bin/env bash
# The vcan test rig: runs one command where real SocketCAN vcan interfaces vcan0..vcan<N-1> exist,
# and returns that command's real exit status and output.
#
# On a kernel with CAN support the command runs on the host. On a kernel without it (this
# project's build machines) the rig boots user-mode Linux, whose kernel has CAN: the guest sees the
# host filesystem (hostfs), loads the CAN modules, creates the interfaces, runs the command in the
# same working directory and reports the exit status through a file, because a UML guest's own
# exit status does not come back to the host.
#
# Usage: vcan_rig.sh [--vcan N] [--mem SIZE] [--timeout SECONDS] [--uml] -- COMMAND [ARGS...]
#   --vcan N        interfaces to create (default 3)
#   --mem SIZE      guest memory (default 1G)
#   --timeout S     kill the guest after S seconds (default 600)
#   --uml           use user-mode Linux even if the host kernel has CAN
# Environment variables named GTEST_*, CANBRIDGE_*, ASAN_*, UBSAN_*, LSAN_* reach the command.
set -euo pipefail

vcan_count=3
mem=1G
timeout_s=600
force_uml=${CANBRIDGE_RIG_FORCE_UML:-0}
while [[ $# -gt 0 ]]; do
  case "$1" in
    --vcan) vcan_count=$2; shift 2 ;;
    --mem) mem=$2; shift 2 ;;
    --timeout) timeout_s=$2; shift 2 ;;
    --uml) force_uml=1; shift ;;
    --) shift; break ;;
    *) echo "vcan_rig: unknown option '$1'" >&2; exit 2 ;;
  esac
done
if [[ $# -eq 0 ]]; then
  echo "usage: vcan_rig.sh [--vcan N] [--mem SIZE] [--timeout S] [--uml] -- COMMAND [ARGS...]" >&2
  exit 2
fi

host_has_vcan() {
  local probe="cbprobe$$"
  ip link add dev "$probe" type vcan 2>/dev/null || return 1
  ip link del dev "$probe" 2>/dev/null || true
  return 0
}

if [[ $force_uml != 1 ]] && host_has_vcan; then
  for ((i = 0; i < vcan_count; i++)); do
    ip link show "vcan$i" >/dev/null 2>&1 || ip link add dev "vcan$i" type vcan
    ip link set "vcan$i" up
  done
  exec "$@"
fi

uml=$(command -v linux.uml || command -v linux || true)
if [[ -z $uml ]]; then
  echo "vcan_rig: this kernel has no CAN and user-mode Linux is not installed (apt-get install user-mode-linux)" >&2
  exit 1
fi

work=$(mktemp -d /tmp/canbridge-rig.XXXXXX)
trap 'rm -rf "$work"' EXIT

{
  echo '#!/bin/bash'
  echo 'export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin'
  echo 'mount -t proc proc /proc; mount -t sysfs sysfs /sys; mount -t tmpfs tmpfs /run'
  echo 'mount -t tmpfs tmpfs /dev/shm; mkdir -p /dev/pts; mount -t devpts devpts /dev/pts'
  echo "exec >$work/guest.log 2>&1"
  # Modules live under the guest kernel's own version: found at boot, never hard-coded.
  echo 'mods=/usr/lib/uml/modules/$(uname -r)/kernel'
  echo 'for m in net/can/can.ko net/can/can-raw.ko net/can/can-gw.ko drivers/net/can/dev/can-dev.ko drivers/net/can/vcan.ko; do'
  echo '  insmod "$mods/$m" || echo "vcan_rig: insmod $m failed"'
  echo 'done'
  echo 'ip link set lo up'
  echo "for ((i = 0; i < $vcan_count; i++)); do ip link add dev vcan\$i type vcan && ip link set vcan\$i up; done"
  export -p | grep -E '^declare -x (GTEST_|CANBRIDGE_|ASAN_|UBSAN_|LSAN_|HOME=|TERM=)' || true
  printf 'cd %q\n' "$PWD"
  printf '%q ' "$@" ; printf '>%q 2>&1 </dev/null\n' "$work/output"
  printf 'echo $? >%q\n' "$work/status"
  echo 'sync'
  echo 'poweroff -f'
} >"$work/init"
chmod +x "$work/init"

# UML 6.1 cannot restore FPU state on hosts with AMX without this shim (see its comment).
preload=()
shim_src=$(dirname "${BASH_SOURCE[0]}")/uml_xstate_shim.c
if command -v cc >/dev/null && cc -O2 -shared -fPIC -o "$work/uml_xstate_shim.so" "$shim_src" -ldl; then
  preload=(env "LD_PRELOAD=$work/uml_xstate_shim.so")
else
  echo "vcan_rig: could not build $shim_src; booting UML without it" >&2
fi

rc=0
timeout --kill-after=10 "$timeout_s" "${preload[@]}" "$uml" mem="$mem" root=/dev/root rootfstype=hostfs rootflags=/ rw \
  init="$work/init" con=null con0=fd:0,fd:1 </dev/null >"$work/console.log" 2>&1 || rc=$?

[[ -f $work/output ]] && cat "$work/output"
if [[ ! -f $work/status ]]; then
  echo "vcan_rig: the guest reported no exit status (uml exit $rc; timeout ${timeout_s}s)" >&2
  echo "--- guest log" >&2; cat "$work/guest.log" >&2 2>/dev/null || true
  echo "--- console (tail)" >&2; tail -n 30 "$work/console.log" >&2 || true
  exit 1
fi
status=$(cat "$work/status")
if grep -q 'vcan_rig:' "$work/guest.log" 2>/dev/null; then cat "$work/guest.log" >&2; fi
exit "$status"
