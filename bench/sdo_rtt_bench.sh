#!/usr/bin/env bash
# SDO round trip through the bridge against a master on the node's own bus, in one boot of the
# vcan rig.
#
#   bench/sdo_rtt_bench.sh [BUILD_DIR] [RUNS] [REQUESTS]     (default: build, 5 runs, 500 requests)
#
# A simulated CiA 301 node (canbridge-sim, local node 2 on vcan1, no heartbeat) answers SDO
# expedited uploads of 1000h:00 and 1018h:01..04 sent one at a time by bench/sdo_rtt_probe, which
# times each request -> response with kernel receive timestamps on its own socket. Per run:
#   direct        probe on vcan1 -> node 2                                          (the ceiling)
#   tcp           probe on vcan0 -> surface -> TCP 127.0.0.1 -> gateway -> vcan1
#                 (module 1: the node is surface node 34 = 2 + 32 x 1)
#   serial        as tcp, but the backbone is a pty pair through canbridge-link-emulator at
#                 115200 bit/s (8N1, 4 KiB line buffer like a UART's), with the slow-line tuning
#                 of tests/system_serial
#   serial-ber    as serial, with --ber 1e-4 (seed 20261200 + run): lost frames are repaired by
#                 resend requests or the retransmit timeout, which shows in the tail
#   tcp+pdo       as tcp, with nominally 1,000 PDOs/s (cangen, 4 COB-IDs) on the module bus
#   serial+pdo    as serial, with nominally 200 PDOs/s (about half the line)
# Environment (it reaches the rig's guest): CANBRIDGE_BENCH_PATHS (default: all six, in the order
# above), CANBRIDGE_BENCH_TCP_PDO_GAP_MS / CANBRIDGE_BENCH_SERIAL_PDO_GAP_MS (default 4 / 20: the
# PDO load, 4 COB-IDs, one frame each per that many ms), CANBRIDGE_BENCH_RETRANSMIT_MS (default
# 1000: retransmit_ms of the serial paths).
# Prints each run and, per path, the medians over the runs, the ratio of the median RTT to the
# direct median, and p99/max pooled over every request of every run.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
build=$(cd "${1:-$root/build}" && pwd)
runs=${2:-5}
requests=${3:-500}

if [[ -z ${CANBRIDGE_IN_RIG:-} ]]; then
  # shellcheck source=bench/rig_common.sh
  source "$here/rig_common.sh"
  # CANBRIDGE_BENCH_RIG=qemu: Debian's kernel in qemu-system instead of user-mode Linux.
  rig=$(rig_script uml)
  exec "$rig" --vcan 2 --mem 1536M --timeout 3000 -- \
    env CANBRIDGE_IN_RIG=1 "$0" "$build" "$runs" "$requests"
fi

probe=$build/bench/sdo_rtt_probe
canbridge=$build/app/canbridge
sim=$build/sim/canbridge-sim
emulator=$build/tools/link_emulator/canbridge-link-emulator
for b in "$probe" "$canbridge" "$sim" "$emulator"; do
  [[ -x $b ]] || { echo "bench: $b is missing (build it first)" >&2; exit 1; }
done
work=$(mktemp -d /tmp/canbridge-sdo-bench.XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$work"' EXIT
read -r -a paths <<<"${CANBRIDGE_BENCH_PATHS:-direct tcp serial serial-ber tcp+pdo serial+pdo}"
timeout_ms=5000
warmup=10
# Bytes the emulated line holds per direction before it stops reading the pty: 4 KiB, as the
# transmit buffer of a Linux serial port (UART_XMIT_SIZE), instead of the emulator's 1 MiB default
# under which a writer never feels the line's pace (see docs/sdo-timing.md, PDO load).
line_buffer=4096
# PDO load: 4 COB-IDs, one frame each per N ms. TCP: 4 ms (~1,000 frames/s). Serial: 20 ms (~200
# frames/s, about half the line when each frame leaves in its own message); 4 there overloads the
# line (docs/sdo-timing.md) and takes ~2 s per request.
tcp_pdo_gap=${CANBRIDGE_BENCH_TCP_PDO_GAP_MS:-4}
serial_pdo_gap=${CANBRIDGE_BENCH_SERIAL_PDO_GAP_MS:-20}

# Bounded wait for a line in a file (a benchmark script may poll; tests may not).
wait_line() {
  local file=$1 text=$2
  for _ in $(seq 800); do grep -q "$text" "$file" 2>/dev/null && return 0; sleep 0.025; done
  echo "bench: timed out waiting for '$text' in $file" >&2; cat "$file" >&2; return 1
}
val() { grep "^$2=" "$work/$1.out" | cut -d= -f2; }

cat >"$work/rig.yaml" <<YAML
rig: sdo-rtt
buses:
  - name: module
    interface: vcan1
    nodes:
      - {name: device, kind: cia301, node_id: 2, heartbeat_ms: 0}
YAML

# Slow-line session tuning (as tests/system_serial and the config samples advise at 115200).
# CANBRIDGE_BENCH_RETRANSMIT_MS overrides retransmit_ms to see what it does to the tail.
slow_line="  keepalive_ms: 200
  dead_after_ms: 1000
  retransmit_ms: ${CANBRIDGE_BENCH_RETRANSMIT_MS:-1000}
  max_write_bytes: 512
  resend_buffer_bytes: 65536"

write_configs() {  # tcp | serial
  if [[ $1 == tcp ]]; then
    cat >"$work/surface.yaml" <<YAML
role: surface
name: bench-surface
bus: vcan0
backbone: {listen: 127.0.0.1:7100, auth: {mode: plain}}
gateways: [{name: bench-gw, modules: [1]}]
log: {level: info, stats_interval_s: 0}
YAML
    cat >"$work/gateway.yaml" <<YAML
role: gateway
name: bench-gw
backbone: {connect: 127.0.0.1:7100, auth: {mode: plain}, reconnect_min_ms: 20}
modules:
  - {id: 1, bus: vcan1}
log: {level: info, stats_interval_s: 0}
YAML
  else
    cat >"$work/surface.yaml" <<YAML
role: surface
name: bench-surface
bus: vcan0
backbone:
  auth: {mode: plain}
  serial:
    - {device: $work/surface.tty, baud: 115200, gateway: bench-gw}
$slow_line
gateways: [{name: bench-gw, modules: [1]}]
log: {level: info, stats_interval_s: 0}
YAML
    cat >"$work/gateway.yaml" <<YAML
role: gateway
name: bench-gw
backbone:
  auth: {mode: plain}
  serial: {device: $work/gw.tty, baud: 115200}
  reconnect_min_ms: 100
$slow_line
modules:
  - {id: 1, bus: vcan1}
log: {level: info, stats_interval_s: 0}
YAML
  fi
}

# start_bridge tcp | serial [emulator args...]: the surface, the gateway and (serial) the emulator.
start_bridge() {
  local kind=$1
  shift
  write_configs "$kind"
  epid=
  if [[ $kind == serial ]]; then
    "$emulator" --a "pty:$work/gw.tty" --b "pty:$work/surface.tty" --baud 115200 \
      --buffer-bytes $line_buffer "$@" \
      >"$work/emulator.log" 2>&1 &
    epid=$!
    wait_line "$work/emulator.log" "link-emulator: ready"
  fi
  "$canbridge" surface --config "$work/surface.yaml" >"$work/surface.log" 2>&1 &
  spid=$!
  [[ $kind == tcp ]] && wait_line "$work/surface.log" listening
  "$canbridge" gateway --config "$work/gateway.yaml" >"$work/gateway.log" 2>&1 &
  gpid=$!
  if [[ $kind == tcp ]]; then
    wait_line "$work/surface.log" "gateway 'bench-gw' ready"
    wait_line "$work/gateway.log" "ready"
  else
    wait_line "$work/gateway.log" "ready over $work/gw.tty"
    wait_line "$work/surface.log" "ready over $work/surface.tty"
  fi
}

stop_bridge() {
  kill -TERM $gpid $spid
  wait $gpid $spid || true
  if [[ -n $epid ]]; then
    kill -TERM $epid
    wait $epid || true
    # final stats: a->b is gateway -> surface (responses), b->a surface -> gateway (requests).
    grep "final stats" "$work/emulator.log" | tail -1 >"$work/emulator.final"
  fi
}

# start_load GAP_MS: PDO load on the module bus, 4 COB-IDs (TPDO1..4 of local node 1), one
# frame each per GAP_MS (cangen -g; the guest may not keep up, so the real rate is measured).
start_load() {
  lpids=()
  for id in 181 281 381 481; do
    cangen vcan1 -g "$1" -I $id -L 8 -D r &
    lpids+=($!)
  done
  load_t0=$(date +%s.%N)
  load_f0=$(cat /sys/class/net/vcan1/statistics/tx_packets)
}
stop_load() {
  local f1 t1
  f1=$(cat /sys/class/net/vcan1/statistics/tx_packets)
  t1=$(date +%s.%N)
  kill "${lpids[@]}"
  wait "${lpids[@]}" 2>/dev/null || true
  # Every frame sent on vcan1 meanwhile, less the SDO requests and responses (2 per request).
  load_fps=$(awk -v f="$((f1 - load_f0 - 2 * (requests + warmup)))" -v t0="$load_t0" -v t1="$t1" \
    'BEGIN{printf "%.0f", f / (t1 - t0)}')
}

# run_probe PATH IF NODE RUN: the probe's key=value output goes to $work/PATH.out.
run_probe() {
  "$probe" --interface "$2" --node "$3" --count "$requests" --warmup $warmup \
    --timeout-ms $timeout_ms --samples "$work/samples.$1.$4" >"$work/$1.out"
}

# print_row RUN PATH [NOTES]: one line of the table (also kept in $work/table for the medians).
print_row() {
  local r=$1 p=$2 notes=${3:-} direct_p50 ratio
  direct_p50=$(awk -v r="$r" '$1 == r && $2 == "direct" {print $8}' "$work/table")
  ratio=$(awk -v a="$(val "$p" rtt_us_p50)" -v b="${direct_p50:-$(val "$p" rtt_us_p50)}" \
    'BEGIN{printf "%.1f", a / b}')
  printf '%-4s %-11s %5s %4s %4s %5s %8s %9s %9s %9s %10s %8s  %s\n' "$r" "$p" \
    "$(val "$p" ok)" "$(val "$p" timeouts)" "$(val "$p" aborts)" "$(val "$p" stale)" \
    "$(val "$p" rtt_us_min)" "$(val "$p" rtt_us_p50)" "$(val "$p" rtt_us_p90)" \
    "$(val "$p" rtt_us_p99)" "$(val "$p" rtt_us_max)" "$ratio" "$notes" | tee -a "$work/table"
}

# From the final stats lines of both processes: frames the surface wrote to its bus (one per
# request: a check that every answer crossed the bridge once) and the session's repairs.
bridge_counters() {
  local g s
  g=$(grep "gateway bench-gw:" "$work/gateway.log" | tail -1 |
    grep -o "resent [0-9]*\|crc-errors [0-9]*" | tr '\n' ' ')
  s=$(grep "surface bench-surface:" "$work/surface.log" | tail -1 |
    grep -o "backbone->bus [0-9]*\|resent [0-9]*" | tr '\n' ' ')
  echo "surface ${s% }; gateway ${g% }"
}

# Line bytes per SDO exchange from the emulator's final stats ("a->b in=N ... b->a in=M ...").
line_bytes() {
  awk -v n="$((requests + warmup))" '{
    for (i = 1; i <= NF; ++i) {
      if ($i == "a->b") d = "ab"; else if ($i == "b->a") d = "ba";
      if ($i ~ /^out=/) { split($i, kv, "="); out[d] = kv[2] }
    }
  } END {
    printf "line B/request gw->surface %.1f surface->gw %.1f", out["ab"] / n, out["ba"] / n
  }' \
    "$work/emulator.final"
}

touch "$work/table"
"$sim" "$work/rig.yaml" --stats-seconds 0 >"$work/sim.log" 2>&1 &
simpid=$!
wait_line "$work/sim.log" "canbridge-sim: ready"

echo "SDO expedited upload round trips: $requests requests per path and run (+$warmup warm-up)," \
  "timeout $timeout_ms ms, kernel receive timestamps; PDO load gaps tcp $tcp_pdo_gap ms," \
  "serial $serial_pdo_gap ms; serial retransmit_ms ${CANBRIDGE_BENCH_RETRANSMIT_MS:-1000};" \
  "$(nproc) CPU, $(uname -r)"
printf '%-4s %-11s %5s %4s %4s %5s %8s %9s %9s %9s %10s %8s  %s\n' run path ok t/o abrt stale \
  min_us p50_us p90_us p99_us max_us x_direct notes
# run_path RUN PATH: one path of one run, one row of the table.
run_path() {
  local r=$1 p=$2 seed=$((20261200 + $1))
  case $p in
    direct)
      run_probe direct vcan1 2 "$r"
      print_row "$r" direct ;;
    tcp)
      start_bridge tcp
      run_probe tcp vcan0 34 "$r"
      stop_bridge
      print_row "$r" tcp "$(bridge_counters)" ;;
    serial)
      start_bridge serial --seed $seed
      run_probe serial vcan0 34 "$r"
      stop_bridge
      print_row "$r" serial "$(line_bytes); $(bridge_counters)" ;;
    serial-ber)
      start_bridge serial --ber 1e-4 --seed $seed
      run_probe serial-ber vcan0 34 "$r"
      stop_bridge
      print_row "$r" serial-ber "$(line_bytes); $(bridge_counters)" ;;
    tcp+pdo)
      start_bridge tcp
      start_load "$tcp_pdo_gap"
      run_probe tcp+pdo vcan0 34 "$r"
      stop_load
      stop_bridge
      print_row "$r" tcp+pdo "pdo load $load_fps frames/s; $(bridge_counters)" ;;
    serial+pdo)
      start_bridge serial --seed $seed
      start_load "$serial_pdo_gap"
      run_probe serial+pdo vcan0 34 "$r"
      stop_load
      stop_bridge
      print_row "$r" serial+pdo "pdo load $load_fps frames/s; $(bridge_counters)" ;;
    *) echo "bench: unknown path '$p'" >&2; exit 2 ;;
  esac
}

for ((r = 1; r <= runs; r++)); do
  for p in "${paths[@]}"; do run_path "$r" "$p"; done
done
kill -TERM $simpid
wait $simpid || true

echo
echo "medians over $runs runs (x_direct = median p50 of the path / median p50 of direct);" \
  "pooled = all $((runs * requests)) requests of the path together; slower than 0.3/1/1.5/2.5 s:"
printf '%-11s %5s %4s %8s %9s %9s %8s | %10s %10s %10s  %s\n' path ok t/o min_us p50_us p90_us \
  x_direct pooled_p99 pooled_p999 pooled_max '>0.3s/1s/1.5s/2.5s'
med() { awk -v p="$1" -v c="$2" '$2 == p {print $c}' "$work/table" | sort -g |
  awk '{a[NR]=$1} END{print a[int((NR+1)/2)]}'; }
direct_med=$(med direct 8)
for p in "${paths[@]}"; do
  cat "$work"/samples."$p".* | sort -g >"$work/pooled"
  pooled() { awk -v q="$1" '{a[NR]=$1} END{r=int(q*NR+0.999999); if(r<1)r=1; print a[r]}' \
    "$work/pooled"; }
  slow=$(awk '{for (i = 1; i <= 4; ++i) if ($1 > t[i]) ++n[i]}
    BEGIN{t[1]=3e5; t[2]=1e6; t[3]=1.5e6; t[4]=2.5e6}
    END{printf "%d/%d/%d/%d", n[1], n[2], n[3], n[4]}' "$work/pooled")
  printf '%-11s %5s %4s %8s %9s %9s %8s | %10s %10s %10s  %s\n' "$p" "$(med "$p" 3)" \
    "$(awk -v p="$p" '$2 == p {s += $4} END{print s}' "$work/table")" \
    "$(med "$p" 7)" "$(med "$p" 8)" "$(med "$p" 9)" \
    "$(awk -v a="$(med "$p" 8)" -v b="${direct_med:-0}" \
      'BEGIN{if (b > 0) printf "%.1f", a / b; else print "-"}')" \
    "$(pooled 0.99)" "$(pooled 0.999)" "$(tail -1 "$work/pooled")" "$slow"
done
echo "(t/o in this table: timeouts summed over the runs)"
