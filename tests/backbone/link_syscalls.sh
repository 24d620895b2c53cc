#!/usr/bin/env bash
# Syscalls per backbone message on each side of the tunnel: a measurement, not a test (issue 17).
#
#   tests/backbone/link_syscalls.sh [BUILD_DIR] [FRAMES] [EXECUTABLE...]
#
# In one boot of the vcan rig, for each canbridge executable (default: BUILD_DIR/app/canbridge),
# a gateway (module bus vcan1, conflate_pdos: false so that a single-id burst forms real batches)
# and a surface (bus vcan0) are connected over TCP on loopback, `strace -c -f` is attached to
# both, FRAMES frames (default 20,000, one id, `cangen -g 0`) are sent on vcan1, and the counts
# are printed with the gateway's own counters: backbone messages = its "batches".
# strace slows every syscall, so frames/s here mean nothing; the counts per message do.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
frames=${2:-20000}
shift $(($# > 2 ? 2 : $#))
exes=("$@")
[[ ${#exes[@]} -eq 0 ]] && exes=("$build/app/canbridge")

if [[ -z ${CANBRIDGE_IN_RIG:-} ]]; then
  exec "$root/tests/rig/vcan_rig.sh" --vcan 2 --mem 1536M --timeout 1500 -- \
    env CANBRIDGE_IN_RIG=1 "$0" "$build" "$frames" "${exes[@]}"
fi

work=$(mktemp -d /tmp/canbridge-syscalls.XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT

wait_line() {  # a measurement script may poll; tests may not
  local file=$1 text=$2
  for _ in $(seq 800); do grep -q "$text" "$file" 2>/dev/null && return 0; sleep 0.025; done
  echo "link_syscalls: timed out waiting for '$text' in $file" >&2; cat "$file" >&2; return 1
}

cat >"$work/surface.yaml" <<YAML
role: surface
name: bench-surface
bus: vcan0
backbone:
  listen: 127.0.0.1:7000
  auth: {mode: plain}
gateways: [{name: bench-gw, modules: [0]}]
log: {level: info, stats_interval_s: 0}
YAML
cat >"$work/gateway.yaml" <<YAML
role: gateway
name: bench-gw
backbone:
  connect: 127.0.0.1:7000
  auth: {mode: plain}
  reconnect_min_ms: 20
modules:
  - {id: 0, bus: vcan1, conflate_pdos: false}
log: {level: info, stats_interval_s: 0}
YAML

# summary FILE: calls (errors) of the most frequent syscalls, and the total
summary() {
  awk '$NF != "syscall" && $NF != "total" && $4 ~ /^[0-9]+$/ {
         e = (NF == 6 ? "[" $5 "err]" : ""); print $4, $NF e}' "$1" |
    sort -nr | head -8 | awk '{printf "%s=%s ", $2, $1}'
  awk '$NF == "total" {print "total=" $4}' "$1"
}

for exe in "${exes[@]}"; do
  "$exe" surface --config "$work/surface.yaml" >"$work/surface.log" 2>&1 &
  spid=$!
  wait_line "$work/surface.log" listening
  "$exe" gateway --config "$work/gateway.yaml" >"$work/gateway.log" 2>&1 &
  gpid=$!
  wait_line "$work/surface.log" "gateway 'bench-gw' ready"
  wait_line "$work/gateway.log" "ready"
  # The idle link's own cost (ticks, keepalives) over 5 s, to tell it from the burst's.
  strace -c -f -o "$work/gateway.idle" -p "$gpid" 2>/dev/null &
  gs=$!
  strace -c -f -o "$work/surface.idle" -p "$spid" 2>/dev/null &
  ss=$!
  sleep 5
  kill -INT $gs $ss; wait $gs $ss || true
  strace -c -f -o "$work/gateway.strace" -p "$gpid" 2>"$work/gateway.strace.err" &
  gs=$!
  strace -c -f -o "$work/surface.strace" -p "$spid" 2>"$work/surface.strace.err" &
  ss=$!
  sleep 1  # strace attaches asynchronously
  start=$(date +%s.%N)
  timeout 120 candump -n "$frames" vcan0 >/dev/null &
  dump=$!
  cangen vcan1 -g 0 -n "$frames" -I 181 -L 8 -D i -p 100
  wait $dump || echo "link_syscalls: not all $frames frames reached vcan0 within 120 s" >&2
  end=$(date +%s.%N)
  kill -INT $gs $ss; wait $gs $ss || true
  kill -TERM $gpid $spid; wait $gpid $spid || true
  batches=$(grep -o 'bus->backbone [0-9]* frames ([0-9]* batches)' "$work/gateway.log" | tail -1)
  nbatches=$(sed 's/.*(\([0-9]*\) batches)/\1/' <<<"$batches")
  echo "== $exe"
  echo "gateway: $batches; dead-links $(grep -o 'dead-links [0-9]*' "$work/gateway.log" | tail -1)"
  echo "burst: $(awk -v a="$start" -v b="$end" 'BEGIN {printf "%.1f", b - a}') s under strace"
  for side in gateway surface; do
    total=$(awk '$NF == "total" {print $4}' "$work/$side.strace")
    idle=$(awk '$NF == "total" {print $4}' "$work/$side.idle")
    echo "$side idle (5 s): $(summary "$work/$side.idle")"
    echo "$side burst: $(summary "$work/$side.strace")"
    awk -v t="$total" -v i="$idle" -v b="$nbatches" -v s="$side" -v a="$start" -v e="$end" \
      'BEGIN {d = e - a; x = t - i / 5 * d; if (x < 0) x = 0
              printf "%s: %.2f syscalls per backbone message (%.2f less the idle rate)\n", s,
                     (b > 0 ? t / b : 0), (b > 0 ? x / b : 0)}'
  done
  grep -h "link dead\|stale" "$work/gateway.log" "$work/surface.log" | head -3 || true
done
