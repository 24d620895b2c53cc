#!/usr/bin/env bash
# PDO Packets through the gateway (issue 6, docs/pdop.md): backbone bytes per packet and packets/s
# when the gateway reassembles TPDOP packets, against forwarding their fragments frame by frame,
# all in one boot of the vcan rig.
#
#   bench/pdop_bench.sh [BUILD_DIR] [RUNS]      (default: build, 5 runs)
#
# One pdop node (local id 1, TPDO1, COB-IDs 0x181/0x1A1/0x1C1/0x1E1) streams packets of BYTES bytes
# (bench/pdop_source); bench/pdop_sink reassembles them on vcan0 (surface id 1: module 0 maps
# {1: 1}) and counts the complete, intact ones. Per run:
#   raw         source vcan0 -> sink vcan0                                (the ceiling)
#   reassemble  source vcan1 -> gateway, pdop: {reassemble: true}  -> TCP -> surface -> vcan0
#   frames      source vcan1 -> gateway, pdop: {reassemble: false} -> TCP -> surface -> vcan0
#               (fragments forwarded one by one, as on any other module; conflate_pdos: false)
# Each bridge path runs twice:
#   burst  BURST packets as fast as the socket takes them, over TCP loopback: intact packets/s,
#          from the first fragment on vcan1 to the last intact packet on vcan0 (kernel
#          timestamps), and "carried" packets/s (fragments reaching vcan0 per second / fragments
#          per packet, intact or not), each as a ratio to raw of the same run.
#   paced  PACED packets at RATE packets/s, the TCP backbone routed through canbridge-link-emulator
#          (no impairment): backbone bytes gateway -> surface per packet carried, from the
#          emulator's A->B byte count over the burst (a periodic line just before it, the final line
#          after it), less the idle keepalive rate measured just before it times the idle part of
#          that window. When the gateway's stats line carries `backbone-tx-bytes`, its own count is
#          shown beside it as a cross-check. The rate is one both paths carry without backlog, so
#          that conflation or drops do not distort the byte count; also gives the packet latency.
# The bytes are divided by the packets carried (fragments on vcan0 / fragments per packet),
# intact or not, so that a damaged packet's bytes still count. The paced rows show the intact
# count beside it. Both paths keep a packet's fragments in bus order, so the two should agree.
# Prints each run, the medians over the runs, the byte ratio reassemble/frames and what one packet
# costs on a 115200 bit/s serial line (8N1: bytes x 10 / 115200).
# Environment (it reaches the rig's guest): CANBRIDGE_BENCH_PDOP_BYTES (default 256: 32
# fragments), CANBRIDGE_BENCH_PDOP_BURST (2000 packets), CANBRIDGE_BENCH_PDOP_PACED (1000 packets),
# CANBRIDGE_BENCH_PDOP_RATE (100 packets/s), CANBRIDGE_BENCH_PDOP_FRAGMENT_GAP_US (default 0:
# each paced packet's fragments back to back; N spaces them N µs apart, as a CAN bus would, which
# leaves the gateway fewer fragments per backbone message frame by frame),
# CANBRIDGE_BENCH_PATHS (default "raw reassemble frames").
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
build=$(cd "${1:-$root/build}" && pwd)
runs=${2:-5}

if [[ -z ${CANBRIDGE_IN_RIG:-} ]]; then
  # shellcheck source=bench/rig_common.sh
  source "$here/rig_common.sh"
  # CANBRIDGE_BENCH_RIG=qemu: Debian's kernel in qemu-system instead of user-mode Linux.
  rig=$(rig_script uml)
  exec "$rig" --vcan 2 --mem 1536M --timeout 3000 -- \
    env CANBRIDGE_IN_RIG=1 "$0" "$build" "$runs"
fi

source_bin=$build/bench/pdop_source
sink_bin=$build/bench/pdop_sink
canbridge=$build/app/canbridge
emulator=$build/tools/link_emulator/canbridge-link-emulator
for b in "$source_bin" "$sink_bin" "$canbridge" "$emulator"; do
  [[ -x $b ]] || { echo "bench: $b is missing (build it first)" >&2; exit 1; }
done
work=$(mktemp -d /tmp/canbridge-pdop-bench.XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$work"' EXIT
bytes=${CANBRIDGE_BENCH_PDOP_BYTES:-256}
burst=${CANBRIDGE_BENCH_PDOP_BURST:-2000}
paced=${CANBRIDGE_BENCH_PDOP_PACED:-1000}
rate=${CANBRIDGE_BENCH_PDOP_RATE:-100}
gap_us=${CANBRIDGE_BENCH_PDOP_FRAGMENT_GAP_US:-0}
read -r -a paths <<<"${CANBRIDGE_BENCH_PATHS:-raw reassemble frames}"
fragments=$(((bytes + 7) / 8))

# Bounded wait for a line in a file (a benchmark script may poll; tests may not).
wait_line() {
  local file=$1 text=$2
  for _ in $(seq 800); do grep -q "$text" "$file" 2>/dev/null && return 0; sleep 0.025; done
  echo "bench: timed out waiting for '$text' in $file" >&2; cat "$file" >&2; return 1
}
# Bounded wait until FILE has at least N lines matching TEXT.
wait_count() {
  local file=$1 text=$2 n=$3
  for _ in $(seq 800); do
    (($(grep -c "$text" "$file" 2>/dev/null || true) >= n)) && return 0
    sleep 0.025
  done
  echo "bench: timed out waiting for $n x '$text' in $file" >&2; cat "$file" >&2; return 1
}
val() { grep "^$2=" "$work/$1.out" | cut -d= -f2; }
now() { date +%s.%N; }
# The emulator's A->B (gateway -> surface) bytes in the last line of FILE matching TEXT.
emulator_in() { grep "$2" "$1" | tail -1 | grep -o 'a->b in=[0-9]*' | cut -d= -f2; }
# The gateway's backbone-tx-bytes in its last stats line, or nothing when the line has none.
gateway_tx() { grep "gateway bench-gw:" "$1" | tail -1 | grep -o 'backbone-tx-bytes [0-9]*' |
  awk '{print $2}' || true; }

cat >"$work/surface.yaml" <<YAML
role: surface
name: bench-surface
bus: vcan0
backbone: {listen: 127.0.0.1:7300, auth: {mode: plain}}
gateways: [{name: bench-gw, modules: [0], surface_nodes: [1]}]
log: {level: info, stats_interval_s: 1}
YAML
# write_gateway MODE PORT: module 0 with the pdop profile, node 1 shown as surface node 1.
write_gateway() {
  local reassemble=true
  [[ $1 == frames ]] && reassemble=false
  cat >"$work/gateway.yaml" <<YAML
role: gateway
name: bench-gw
backbone: {connect: 127.0.0.1:$2, auth: {mode: plain}, reconnect_min_ms: 20}
modules:
  - id: 0
    bus: vcan1
    profile: pdop
    nodes: {1: 1}
    conflate_pdos: false
    pdop: {reassemble: $reassemble}
log: {level: info, stats_interval_s: 1}
YAML
}

# start_bridge MODE direct|emulated: surface, (emulator,) gateway; waits until the gateway is ready.
start_bridge() {
  local port=7300
  epid=
  "$canbridge" surface --config "$work/surface.yaml" >"$work/surface.log" 2>&1 &
  spid=$!
  wait_line "$work/surface.log" listening
  if [[ $2 == emulated ]]; then
    port=7301
    "$emulator" --a tcp-listen:127.0.0.1:$port --b tcp-connect:127.0.0.1:7300 --stats-seconds 1 \
      >"$work/emulator.log" 2>&1 &
    epid=$!
    wait_line "$work/emulator.log" "link-emulator: ready"
  fi
  write_gateway "$1" $port
  "$canbridge" gateway --config "$work/gateway.yaml" >"$work/gateway.log" 2>&1 &
  gpid=$!
  wait_line "$work/surface.log" "gateway 'bench-gw' ready"
  wait_line "$work/gateway.log" "ready"
}
stop_bridge() {
  if [[ -n $epid ]]; then
    kill -TERM $epid
    wait $epid || true
  fi
  kill -TERM $gpid $spid
  wait $gpid $spid || true
}

# measure NAME SOURCE_IF COUNT RATE [GAP_US]: sink on vcan0, source on SOURCE_IF; sink output in
# NAME.out.
measure() {
  local name=$1 src=$2 count=$3 pace=$4 gap=${5:-0}
  "$sink_bin" --source "$src" --sink vcan0 --count "$count" --bytes "$bytes" --node 1 \
    --idle-ms 10000 >"$work/$name.out" &
  local pid=$!
  wait_line "$work/$name.out" ready
  t_start=$(now)
  "$source_bin" --interface "$src" --count "$count" --bytes "$bytes" --node 1 --rate "$pace" \
    --fragment-gap-us "$gap" >"$work/$name.source"
  wait $pid
}

# Gateway figures from its final stats line: frames and batches, or packets, it put on the backbone.
gateway_notes() {
  grep "gateway bench-gw:" "$work/gateway.log" | tail -1 |
    grep -o "bus->backbone [0-9]* frames ([0-9]* batches)\|conflated [0-9]*\|process-dropped [0-9]*\|pdop packets [0-9]* ([0-9]* bytes, [0-9]* fragments) discarded [0-9]*\|vcan1 rx [0-9]*\|kernel-drops [0-9]*" |
    tr '\n' ' ' || true
}

# The surface's: packets and frames it wrote to vcan0, frames the bus refused (queue full).
surface_notes() {
  grep "surface bench-surface:" "$work/surface.log" | tail -1 |
    grep -o "backbone->bus [0-9]*\|bus-refused [0-9]*\|pdop packets [0-9]* ([0-9]* bytes) discarded [0-9]*\|vcan0 rx [0-9]* tx [0-9]*" |
    tr '\n' ' ' || true
}

# paced_bytes MODE RUN: the paced run through the emulator; appends a row to $work/bytes.
# Bytes are divided by the packets that reached vcan0 as fragments (fragments on the sink /
# fragments per packet), intact or not; the row's intact column shows whether the two differ.
paced_bytes() {
  local mode=$1 r=$2 n0 b0 b1 idle_bps t_b0 t_term g0 g1
  start_bridge "$mode" emulated
  # Two periodic lines after ready: the idle rate between them, and the count at the burst's start.
  n0=$(grep -c "link-emulator: stats" "$work/emulator.log" || true)
  wait_count "$work/emulator.log" "link-emulator: stats" $((n0 + 2))
  idle_bps=$(($(emulator_in "$work/emulator.log" "link-emulator: stats") -
    $(grep "link-emulator: stats" "$work/emulator.log" | tail -2 | head -1 |
      grep -o 'a->b in=[0-9]*' | cut -d= -f2)))
  b0=$(emulator_in "$work/emulator.log" "link-emulator: stats")
  g0=$(gateway_tx "$work/gateway.log")
  t_b0=$(now)
  measure "$mode.paced" vcan1 "$paced" "$rate" "$gap_us"
  t_term=$(now)
  stop_bridge
  b1=$(emulator_in "$work/emulator.log" "final stats")
  g1=$(gateway_tx "$work/gateway.log")
  # Idle seconds inside the window: before the first fragment and after the last one.
  awk -v r="$r" -v m="$mode" -v b0="$b0" -v b1="$b1" -v idle="$idle_bps" -v tb0="$t_b0" \
    -v ts="$t_start" -v tt="$t_term" -v last="$(val "$mode.paced" last_frame_ns)" \
    -v f="$(val "$mode.paced" frames_sink)" -v n="$fragments" \
    -v d="$(val "$mode.paced" delivered)" -v g0="${g0:-}" -v g1="${g1:-}" \
    -v lost="$(val "$mode.paced" lost)" -v p50="$(val "$mode.paced" latency_us_p50)" \
    -v p99="$(val "$mode.paced" latency_us_p99)" 'BEGIN{
      idle_s = (ts - tb0) + (last > 0 ? tt - last / 1e9 : tt - ts);
      if (idle_s < 0) idle_s = 0;
      bytes = b1 - b0 - idle * idle_s;
      carried = f / n;
      gw = (g0 != "" && g1 != "" && carried > 0) ? sprintf("%.1f", (g1 - g0) / carried) : "-";
      printf("%-4s %-10s %7.1f %6d %5d %9.1f %8s %8.1f %8d %9.1f %9.1f\n", r, m, carried, d,
        lost, (carried > 0 ? bytes / carried : 0), gw, idle * idle_s, idle, p50, p99)
    }' | tee -a "$work/bytes"
  echo "     paced: $(gateway_notes); $(surface_notes)"
}

# burst_rate MODE RUN: the max-rate burst over direct TCP (raw: no bridge); a row to $work/rates.
burst_rate() {
  local mode=$1 r=$2
  if [[ $mode == raw ]]; then
    measure raw vcan0 "$burst" 0
  else
    start_bridge "$mode" direct
    measure "$mode" vcan1 "$burst" 0
    stop_bridge
  fi
  awk -v r="$r" -v m="$mode" -v pps="$(val "$mode" rate_pps)" \
    -v fps="$(val "$mode" frames_per_s)" -v n="$fragments" \
    -v raw="$(awk -v r="$r" '$1 == r && $2 == "raw" {print $3, $5}' "$work/rates")" \
    -v d="$(val "$mode" delivered)" -v lost="$(val "$mode" lost)" \
    -v corrupt="$(val "$mode" corrupt)" -v err="$(val "$mode" errors_sink)" \
    -v p50="$(val "$mode" latency_us_p50)" -v p99="$(val "$mode" latency_us_p99)" \
    -v drops="$(val "$mode" kernel_drops_sink)/$(val "$mode" kernel_drops_source)" 'BEGIN{
      carried = fps / n;
      if (raw == "") raw = pps " " carried;
      split(raw, base, " ");
      printf("%-4s %-10s %8.1f %6.3f %8.1f %6.3f %6d %5d %7d %6d %9.1f %9.1f %9s\n", r, m, pps,
        (base[1] > 0 ? pps / base[1] : 0), carried, (base[2] > 0 ? carried / base[2] : 0), d, lost,
        corrupt, err, p50, p99, drops)
    }' | tee -a "$work/rates"
  [[ $mode == raw ]] || echo "     burst: $(gateway_notes); $(surface_notes)"
}

touch "$work/rates" "$work/bytes"
echo "PDO Packets of $bytes bytes ($fragments fragments), node 1 TPDO1; burst $burst packets at" \
  "full speed, paced $paced packets at $rate packets/s (fragment gap $gap_us us); $(nproc) CPU," \
  "$(uname -r)"
for ((r = 1; r <= runs; r++)); do
  echo "run $r: burst. pkts/s: intact packets; carried: fragments on vcan0 per second / $fragments;" \
    "ratios to raw of this run; latency: last fragment on vcan0 - on the source bus; errors: sink" \
    "reassembly errors"
  printf '%-4s %-10s %8s %6s %8s %6s %6s %5s %7s %6s %9s %9s %9s\n' run path pkts/s ratio carried \
    ratio intact lost corrupt errors p50_us p99_us drops
  for p in "${paths[@]}"; do burst_rate "$p" "$r"; done
  echo "run $r: paced. B/pkt: backbone bytes gateway -> surface per packet carried, keepalive bytes" \
    "of the idle part of the window subtracted (idle_B); gw_B/pkt: the gateway's own count"
  printf '%-4s %-10s %7s %6s %5s %9s %8s %8s %8s %9s %9s\n' run path carried intact lost B/pkt \
    gw_B/pkt idle_B idle_B/s p50_us p99_us
  for p in "${paths[@]}"; do [[ $p == raw ]] || paced_bytes "$p" "$r"; done
done

med() { awk -v p="$2" -v c="$3" '$2 == p {print $c}' "$1" | sort -g |
  awk '{a[NR]=$1} END{if (NR) print a[int((NR+1)/2)]; else print "-"}'; }
echo
echo "medians over $runs runs ($bytes-byte packets, $fragments fragments; ratios to raw of the same" \
  "run; lost: intact packets lost in the bursts, summed; 115200 line time = B/pkt x 10 / 115200):"
printf '%-10s %8s %6s %8s %6s %6s %8s %8s %7s %8s %10s %9s\n' path pkts/s ratio carried ratio \
  lost B/pkt gw_B/pkt B/frag line_ms line_pkts/s paced_p50
for p in "${paths[@]}"; do
  awk -v p="$p" -v pps="$(med "$work/rates" "$p" 3)" -v ratio="$(med "$work/rates" "$p" 4)" \
    -v carried="$(med "$work/rates" "$p" 5)" -v cratio="$(med "$work/rates" "$p" 6)" \
    -v lost="$(awk -v p="$p" '$2 == p {s += $8} END{print s + 0}' "$work/rates")" \
    -v b="$(med "$work/bytes" "$p" 6)" -v gw="$(med "$work/bytes" "$p" 7)" -v f="$fragments" \
    -v lat="$(med "$work/bytes" "$p" 10)" 'BEGIN{
      if (b == "-" || b <= 0) {
        printf("%-10s %8s %6s %8s %6s %6s %8s %8s %7s %8s %10s %9s\n", p, pps, ratio, carried,
          cratio, lost, "-", "-", "-", "-", "-", "-")
        exit
      }
      printf("%-10s %8s %6s %8s %6s %6s %8.1f %8s %7.2f %8.2f %10.1f %9s\n", p, pps, ratio,
        carried, cratio, lost, b, gw, b / f, b * 10 / 115200 * 1000, 115200 / 10 / b, lat)
    }'
done
re=$(med "$work/bytes" reassemble 6)
fr=$(med "$work/bytes" frames 6)
if [[ $re != - && $fr != - ]]; then
  awk -v a="$re" -v b="$fr" 'BEGIN{printf("backbone bytes per packet, reassemble / frames: %.3f" \
    " (%.1f vs %.1f B; %.1f B less per packet)\n", a / b, a, b, b - a)}'
fi
