# shellcheck shell=bash
# Shared pieces of the bench scripts that run inside the vcan rig (source it, do not run it).
#
#   rig_script DEFAULT                         the rig script CANBRIDGE_BENCH_RIG (qemu|uml) or DEFAULT names
#   rig_reexec VCAN MEM TIMEOUT "$0" ARGS...   re-runs the script inside the rig unless already there
#   wait_line FILE TEXT [TRIES]                bounded wait for a line (25 ms per try, default 800)
#   kv FILE KEY                                the value of KEY=value in FILE
#   median                                     the median of the numbers on stdin ("-" for none)
#   four_bus_configs SRC DEST                  the four-bus scenario's configs from SRC's

# The rig a bench boots, by CANBRIDGE_BENCH_RIG, else DEFAULT: qemu (tests/rig/qemu_rig.sh, Debian's
# own kernel in qemu-system: system calls cost ~1 us, as on hardware) or uml (tests/rig/vcan_rig.sh:
# user-mode Linux, ~65 us per system call, or the host itself where its kernel has CAN).
rig_script() {
  local root kind=${CANBRIDGE_BENCH_RIG:-$1}
  root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
  case $kind in
    qemu) echo "$root/tests/rig/qemu_rig.sh" ;;
    uml) echo "$root/tests/rig/vcan_rig.sh" ;;
    *) echo "bench: CANBRIDGE_BENCH_RIG=$kind: qemu or uml" >&2; return 2 ;;
  esac
}

# Re-executes the calling script in the rig (rig_script, default uml), passing every CANBRIDGE_*
# variable through (both rigs forward them to the guest).
rig_reexec() {
  local vcan=$1 mem=$2 timeout=$3 rig
  shift 3
  if [[ -z ${CANBRIDGE_IN_RIG:-} ]]; then
    rig=$(rig_script uml)
    exec "$rig" --vcan "$vcan" --mem "$mem" --timeout "$timeout" -- env CANBRIDGE_IN_RIG=1 "$@"
  fi
}

# Bounded wait for a line in a file (a benchmark script may poll; tests may not).
wait_line() {
  local file=$1 text=$2 tries=${3:-800}
  for _ in $(seq "$tries"); do grep -q -- "$text" "$file" 2>/dev/null && return 0; sleep 0.025; done
  echo "bench: timed out waiting for '$text' in $file" >&2
  tail -20 "$file" >&2
  return 1
}

kv() { { grep "^$2=" "$1" 2>/dev/null | tail -1 | cut -d= -f2; } || true; }

median() {
  sort -g | awk '$1 != "-" && $1 != "" {a[n++] = $1} END {if (n == 0) print "-"; else print a[int((n - 1) / 2)]}'
}

# The four-bus scenario's configs: SRC/gateway.yaml with modules 0 (vcan3) and 3 (vcan4) added to
# the sample's 1 (vcan1) and 2 (vcan2), SRC/surface.yaml serving all four; written to DEST. A
# sample whose lines no longer match would silently give a two-bus run: that is refused.
four_bus_configs() {
  local src=$1 dest=$2
  mkdir -p "$dest"
  sed -e '/^    bus: vcan2$/a\  - id: 0\n    bus: vcan3\n  - id: 3\n    bus: vcan4' \
    "$src/gateway.yaml" >"$dest/gateway.yaml"
  sed -e 's|^    modules: \[1, 2\]$|    modules: [0, 1, 2, 3]|' \
    -e 's|^    surface_nodes: \[33-63, 65-95\]$|    surface_nodes: [1-31, 33-63, 65-95, 97-127]|' \
    "$src/surface.yaml" >"$dest/surface.yaml"
  if ! grep -q '^    bus: vcan4$' "$dest/gateway.yaml" ||
    ! grep -q 'modules: \[0, 1, 2, 3\]' "$dest/surface.yaml"; then
    echo "bench: the four-bus lines no longer apply to $src/*.yaml" >&2
    return 1
  fi
}
