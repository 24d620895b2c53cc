# shellcheck shell=bash
# Shared pieces of the bench scripts that run inside the vcan rig (source it, do not run it).
#
#   rig_reexec VCAN MEM TIMEOUT "$0" ARGS...   re-runs the script inside the rig unless already there
#   wait_line FILE TEXT [TRIES]                bounded wait for a line (25 ms per try, default 800)
#   kv FILE KEY                                the value of KEY=value in FILE
#   median                                     the median of the numbers on stdin ("-" for none)

# Re-executes the calling script in the vcan rig (user-mode Linux where the host has no CAN),
# passing every CANBRIDGE_* variable through (vcan_rig.sh forwards them to the guest).
rig_reexec() {
  local vcan=$1 mem=$2 timeout=$3
  shift 3
  if [[ -z ${CANBRIDGE_IN_RIG:-} ]]; then
    local root
    root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
    exec "$root/tests/rig/vcan_rig.sh" --vcan "$vcan" --mem "$mem" --timeout "$timeout" -- \
      env CANBRIDGE_IN_RIG=1 "$@"
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
