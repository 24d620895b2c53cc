#!/usr/bin/env bash
# Issue 17's one table: the tunnel against raw vcan and the kernel's can-gw, with the sample
# configs as shipped, all in one boot of the vcan rig.
#
#   bench/speed_bench.sh [--uml] [BUILD_DIR] [RUNS]   (default: build, 1 run; medians over RUNS)
#   --uml (or CANBRIDGE_BENCH_RIG=uml): in user-mode Linux (tests/rig/vcan_rig.sh) instead of
#   Debian's own kernel in qemu-system (tests/rig/qemu_rig.sh, the default: two guest CPUs, system
#   calls of ~1 us as on hardware, where UML's ~65 us dominated the latency columns).
#   CANBRIDGE_BASELINE=/work/baseline17/canbridge bench/speed_bench.sh ...   (before/after)
#   CANBRIDGE_BENCH_TUNE="key=value ..." bench/speed_bench.sh ...            (the tcp-tuned row)
#   CANBRIDGE_BENCH_ROWS=serial bench/speed_bench.sh ...     (only the canbridge rows matching it)
#   CANBRIDGE_BENCH_PERF=/var/tmp/perf bench/speed_bench.sh ...  (perf reports of the 1k/s run)
#
# Rows (paths), each run:
#   raw             cangen vcan0 -> receiver on vcan0 (the ceiling)
#   can-gw          module bus vcan1 -> kernel can-gw -> surface bus vcan0
#   tcp-default     canbridge gateway + surface over TCP with config/gateway.yaml and
#                   config/surface.yaml as shipped; only key paths and the command socket path are
#                   rewritten (printed at the start). Module 1 is vcan1, so TPDO 0x181 of its node
#                   1 arrives on the surface as 0x1A1 (surface node 33).
#   tcp-plain       the same with auth mode plain in both roles (what TLS costs, same boot)
#   tcp-tuned       the same with CANBRIDGE_BENCH_TUNE applied (row left out while it is empty):
#                   space-separated KEY=VALUE (every uncommented or commented-out 'KEY:' line of
#                   both configs), gateway.KEY=VALUE / surface.KEY=VALUE (one role),
#                   module.KEY=VALUE (added to every module of the gateway).
#   serial-115200   the shipped configs with the backbone on a pty pair through
#   serial-1M       canbridge-link-emulator at 115200 / 1000000 bit/s (4 KiB line buffer, as a
#                   UART's): 'connect:' and 'listen:' replaced by 'serial:' lines (printed).
#   before-*        with CANBRIDGE_BASELINE, the canbridge rows again with that executable.
# Columns:
#   fps, x          frames/s of a CANBRIDGE_BENCH_BURST-frame (100,000) `cangen -g 0` burst of id
#                   0x181 and its ratio to raw in the same run; serial rows send
#                   CANBRIDGE_BENCH_SERIAL_BURST (20,000) frames and x is the ratio to the line's
#                   payload capacity for 8-byte frames (baud / 10 / 8 frames/s).
#   lost, reord     frames of the burst that never arrived / arrived out of order.
#   p50/p99_1k      one-way latency (kernel receive timestamps on both buses, us) of 2,000 frames
#                   paced at 1,000 frames/s by bench/bus_pacer (1 frame per 1 ms tick).
#   p50/p99_max     the same at the highest paced rate: CANBRIDGE_BENCH_MAX_PER_TICK (8) frames per
#                   1 ms tick, one sendmmsg (16,000 frames; the rate reached is printed per run).
#   B/fr            gateway backbone-tx-bytes / bus->backbone frames over the burst and both paced
#                   runs (the gateway's final stats line; includes keepalives and headers).
#   4b_fps, 4b_lost TCP rows: the four-bus scenario. The shipped gateway config plus modules 0
#                   (vcan3) and 3 (vcan4) (surface: modules [0, 1, 2, 3], surface_nodes widened),
#                   bus_pacer sending 8 frames per 1 ms tick on each of the four buses (nominally
#                   8,000 frames/s each) for CANBRIDGE_BENCH_FOURBUS_SECONDS (5): frames/s per bus
#                   reached and frames lost over all four buses.
#   gw/sf_cpu, _rss CPU % of one core (utime+stime from /proc/PID/stat over the pacer's interval)
#                   and VmRSS (MB) at its end, of the gateway and the surface.
#   sdo_x           32 KiB SDO block download (remote_sdo_probe master on vcan0, canbridge-sim node
#                   2 on vcan1, object 2100h): can-gw's time / the tunnel's time (>= 0.8 wanted).
#   sc_gw, sc_sf    TCP rows: system calls per forwarded frame of the gateway / the surface
#                   (strace -c -f -p over a 20,000-frame burst, calls / frames delivered); the
#                   notes add the same over the 2,000 frames paced at 1,000 frames/s.
#   us1k_gw, us1k_sf  CPU time (utime + stime) per frame of the gateway / the surface over the
#                   2,000 frames paced at 1,000 frames/s: what a frame costs when every frame is
#                   its own wake (the latency path; 10 ms clock ticks, so +-5 us here).
# '-' marks a column a row does not measure. Ends with the medians over RUNS.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
if [[ ${1:-} == --uml ]]; then
  CANBRIDGE_BENCH_RIG=uml
  shift
fi
# Exported: it reaches the guest (a CANBRIDGE_* variable), whose first line names the rig.
export CANBRIDGE_BENCH_RIG=${CANBRIDGE_BENCH_RIG:-qemu}
build=$(cd "${1:-$root/build}" && pwd)
runs=${2:-1}
# shellcheck source=bench/rig_common.sh
source "$here/rig_common.sh"
rig_reexec 5 1536M 5400 "$0" "$build" "$runs"
[[ -n ${CANBRIDGE_BENCH_XTRACE:-} ]] && set -x

canbridge=$build/app/canbridge
counter=$build/bench/can_counter
pacer=$build/bench/bus_pacer
probe=$build/bench/remote_sdo_probe
sim=$build/sim/canbridge-sim
emulator=$build/tools/link_emulator/canbridge-link-emulator
baseline=${CANBRIDGE_BASELINE:-}
for b in "$canbridge" "$counter" "$pacer" "$probe" "$sim" "$emulator" $baseline; do
  [[ -x $b ]] || { echo "bench: $b is missing (build it first)" >&2; exit 1; }
done
burst=${CANBRIDGE_BENCH_BURST:-100000}
serial_burst=${CANBRIDGE_BENCH_SERIAL_BURST:-20000}
paced=2000
max_per_tick=${CANBRIDGE_BENCH_MAX_PER_TICK:-8}
max_count=16000
fourbus_seconds=${CANBRIDGE_BENCH_FOURBUS_SECONDS:-5}
strace_burst=20000
sdo_size=32768
tune=${CANBRIDGE_BENCH_TUNE:-}
clk_tck=$(getconf CLK_TCK)

work=$(mktemp -d /tmp/canbridge-speed-bench.XXXXXX)
cleanup() {
  local pids
  pids=$(jobs -p)
  # shellcheck disable=SC2086  # one pid per word
  [[ -n $pids ]] && kill $pids 2>/dev/null
  wait 2>/dev/null
  cangw -F 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT

# ---- configs: the shipped samples, rewritten only where the rig differs ----
mkdir -p "$work/keys"
(umask 077 && openssl rand -hex 32 >"$work/keys/tool-gateway.key")
mkdir -p "$work/tcp"
# Uncommented lines only: key paths (the rig's fresh key) and the command socket (no /run/canbridge).
sed -e "/^ *#/!s|/etc/canbridge/keys/|$work/keys/|" "$root/config/gateway.yaml" >"$work/tcp/gateway.yaml"
sed -e "/^ *#/!s|/etc/canbridge/keys/|$work/keys/|" \
  -e "/^ *#/!s|unix_socket: /run/canbridge/surface.sock|unix_socket: $work/surface.sock|" \
  "$root/config/surface.yaml" >"$work/tcp/surface.yaml"

# derive_serial DIR BAUD: DIR-serial-BAUD, the backbone on the emulator's pty pair.
derive_serial() {
  local d=$1-serial-$2
  mkdir -p "$d"
  sed -e "s|^  connect: 127.0.0.1:7000$|  serial: {device: $work/gw-$2.tty, baud: $2}|" \
    "$1/gateway.yaml" >"$d/gateway.yaml"
  sed -e "s|^  listen: 127.0.0.1:7000$|  serial: [{device: $work/surface-$2.tty, baud: $2, gateway: tool-gateway}]|" \
    "$1/surface.yaml" >"$d/surface.yaml"
}

# apply_tune DIR: CANBRIDGE_BENCH_TUNE's overrides, in place.
apply_tune() {
  local item key value role files f
  for item in $tune; do
    key=${item%%=*}
    value=${item#*=}
    case $key in
      module.*)
        sed -i "/^    bus: vcan[0-9]*$/a\\    ${key#module.}: $value" "$1/gateway.yaml"
        continue ;;
      gateway.* | surface.*) role=${key%%.*}; key=${key#*.}; files="$1/$role.yaml" ;;
      *) files="$1/gateway.yaml $1/surface.yaml" ;;
    esac
    for f in $files; do
      if grep -q "^ *$key: " "$f"; then
        sed -i "s|^\( *\)$key: .*|\1$key: $value|" "$f"
      elif grep -q "^ *# $key: " "$f"; then
        sed -i "0,/^\( *\)# $key: .*/s||\1$key: $value|" "$f"
      else
        echo "bench: CANBRIDGE_BENCH_TUNE: no '$key:' line in $(basename "$f")" >&2
        exit 2
      fi
    done
  done
}

four_bus_configs "$work/tcp" "$work/tcp-4bus"
# tcp-plain: the shipped configs with auth mode plain in both roles (no TLS, no MAC), so that the
# table shows what psk TLS costs in the same boot (issue 29: psk >= 0.9 of plain's throughput).
derive_plain() {
  mkdir -p "$2"
  for r in gateway surface; do
    sed -e 's|^    mode: psk$|    mode: plain|' "$1/$r.yaml" >"$2/$r.yaml"
    grep -q '^    mode: plain$' "$2/$r.yaml" || {
      echo "bench: no '    mode: psk' line left in $1/$r.yaml for tcp-plain" >&2
      return 1
    }
  done
}
derive_plain "$work/tcp" "$work/tcp-plain"
derive_plain "$work/tcp-4bus" "$work/tcp-plain-4bus"
for baud in 115200 1000000; do derive_serial "$work/tcp" $baud; done
if [[ -n $tune ]]; then
  mkdir -p "$work/tuned" "$work/tuned-4bus"
  cp "$work/tcp/gateway.yaml" "$work/tcp/surface.yaml" "$work/tuned/"
  cp "$work/tcp-4bus/gateway.yaml" "$work/tcp-4bus/surface.yaml" "$work/tuned-4bus/"
  apply_tune "$work/tuned"
  apply_tune "$work/tuned-4bus"
fi

show_diff() {  # the lines of a derived config that differ from the shipped sample
  diff "$1" "$2" | grep '^[<>]' | sed "s|^|    $(basename "$2"): |" || true
}
echo "speed_bench: $CANBRIDGE_BENCH_RIG rig, $(nproc) CPU, $(uname -r), runs $runs, burst $burst (serial $serial_burst)," \
  "paced $paced at 1 ms and $max_count at $max_per_tick per 1 ms, four-bus ${fourbus_seconds} s," \
  "SDO block download $sdo_size B, strace burst $strace_burst; baseline ${baseline:-none}"
echo "config lines rewritten from config/*.yaml (< shipped, > used):"
echo "  tcp-default:"
# The baseline rows run the same configs without the keys the baseline does not know yet
# (CANBRIDGE_BASELINE_DROP_KEYS, default: conflate_after_ms, new with issue 17), so they show the
# old executable with its own defaults for those settings.
if [[ -n $baseline ]]; then
  mkdir -p "$work/before"
  for d in "$work"/tcp* "$work"/tuned*; do
    [[ -d $d ]] || continue
    cp -r "$d" "$work/before/"
    for key in ${CANBRIDGE_BASELINE_DROP_KEYS:-conflate_after_ms}; do
      sed -i "/^ *$key:/d" "$work/before/$(basename "$d")"/*.yaml
    done
  done
fi
for r in gateway surface; do show_diff "$root/config/$r.yaml" "$work/tcp/$r.yaml"; done
echo "  tcp-plain (besides the above):"
for r in gateway surface; do show_diff "$work/tcp/$r.yaml" "$work/tcp-plain/$r.yaml"; done
echo "  serial-BAUD (besides the above; BAUD 115200 shown):"
for r in gateway surface; do show_diff "$work/tcp/$r.yaml" "$work/tcp-serial-115200/$r.yaml"; done
echo "  four-bus (besides the above):"
for r in gateway surface; do show_diff "$work/tcp/$r.yaml" "$work/tcp-4bus/$r.yaml"; done
if [[ -n $tune ]]; then
  echo "  tcp-tuned (CANBRIDGE_BENCH_TUNE='$tune', besides the above):"
  for r in gateway surface; do show_diff "$work/tcp/$r.yaml" "$work/tuned/$r.yaml"; done
else
  echo "  tcp-tuned: left out (CANBRIDGE_BENCH_TUNE is empty)"
fi

# ---- measuring ----
# measure NAME SOURCE SINK SINK_ID COUNT burst|paced1k|pacedmax: can_counter's key=value lines
# in $work/NAME.out, the sender's in $work/NAME.send.
measure() {
  local name=$1 src=$2 sink=$3 sink_id=$4 count=$5 mode=$6
  timeout 600 "$counter" --source "$src" --sink "$sink" --id 181 --sink-id "$sink_id" \
    --count "$count" --idle-ms 3000 >"$work/$name.out" &
  local pid=$!
  wait_line "$work/$name.out" ready
  case $mode in
    burst) cangen "$src" -g 0 -n "$count" -I 181 -L 8 -D i -p 100 >"$work/$name.send" ;;
    paced1k) "$pacer" --interfaces "$src" --id 181 --per-tick 1 --count "$count" >"$work/$name.send" ;;
    pacedmax) "$pacer" --interfaces "$src" --id 181 --per-tick "$max_per_tick" --count "$count" \
      >"$work/$name.send" ;;
  esac
  wait $pid || true
}
out() { kv "$work/$1.out" "$2"; }

# sdo_download NAME INTERFACE NODE: the 32 KiB block download's milliseconds into $work/NAME.sdo.
sdo_download() {
  local rig=$work/sim.yaml
  cat >"$rig" <<YAML
rig: speed-bench
buses:
  - name: module
    interface: vcan1
    nodes:
      - {name: device, kind: cia301, node_id: 2, heartbeat_ms: 0,
         objects: [{index: 0x2100, type: domain, size: 0}]}
YAML
  "$sim" "$rig" --stats-seconds 0 >"$work/$1.sim.log" 2>&1 &
  local simpid=$!
  wait_line "$work/$1.sim.log" "canbridge-sim: ready"
  "$probe" master --interface "$2" --node "$3" --op blockdown --size $sdo_size --timeout-ms 5000 \
    >"$work/$1.sdo" 2>&1 || true
  kill -TERM $simpid
  wait $simpid || true
  [[ $(kv "$work/$1.sdo" ok) == 1 ]] || echo "     $1: SDO download failed: $(kv "$work/$1.sdo" error)"
}
sdo_ms() { [[ $(kv "$work/$1.sdo" ok) == 1 ]] && kv "$work/$1.sdo" ms || echo -; }

# start_bridge NAME EXE CONFDIR [BAUD]: emulator (with BAUD), surface and gateway, until ready.
start_bridge() {
  local name=$1 exe=$2 conf=$3 baud=${4:-}
  epid=
  if [[ -n $baud ]]; then
    "$emulator" --a "pty:$work/gw-$baud.tty" --b "pty:$work/surface-$baud.tty" --baud "$baud" \
      --buffer-bytes 4096 >"$work/$name.emulator.log" 2>&1 &
    epid=$!
    wait_line "$work/$name.emulator.log" "link-emulator: ready"
  fi
  "$exe" surface --config "$conf/surface.yaml" >"$work/$name.surface.log" 2>&1 &
  spid=$!
  [[ -z $baud ]] && wait_line "$work/$name.surface.log" listening
  "$exe" gateway --config "$conf/gateway.yaml" >"$work/$name.gateway.log" 2>&1 &
  gpid=$!
  if [[ -z $baud ]]; then
    wait_line "$work/$name.surface.log" "gateway 'tool-gateway' ready"
    wait_line "$work/$name.gateway.log" "ready"
  else
    wait_line "$work/$name.gateway.log" "ready over $work/gw-$baud.tty" 1200
    wait_line "$work/$name.surface.log" "ready over $work/surface-$baud.tty" 1200
  fi
}
stop_bridge() {
  kill -TERM $gpid $spid
  wait $gpid $spid || true
  if [[ -n $epid ]]; then kill -TERM $epid; wait $epid || true; fi
}

cpu_ticks() { awk '{print $14 + $15}' "/proc/$1/stat"; }
rss_mb() { awk '/^VmRSS:/ {printf "%.1f", $2 / 1024}' "/proc/$1/status"; }
cpu_us_per_frame() {  # TICKS FRAMES
  awk -v d="$1" -v f="$2" -v t="$clk_tck" 'BEGIN{if (f + 0 > 0) printf "%.0f", 1e6 * d / t / f; else print "-"}'
}
cpu_pct() { awk -v d="$1" -v s="$2" -v t="$clk_tck" 'BEGIN{printf "%.1f", 100 * d / t / s}'; }

# bytes_per_frame NAME: the gateway's backbone-tx-bytes / bus->backbone frames (final stats).
bytes_per_frame() {
  grep "gateway tool-gateway:" "$work/$1.gateway.log" | tail -1 |
    awk '{ for (i = 1; i <= NF; ++i) { if ($i == "bus->backbone") f = $(i + 1);
                                        if ($i == "backbone-tx-bytes") b = $(i + 1) }
           gsub(/[^0-9]/, "", b); gsub(/[^0-9]/, "", f)
           if (f > 0) printf "%.2f", b / f; else print "-" }' || true
}
# counters NAME: the counters that explain loss, from both final stats lines.
counters() {
  local g s
  g=$(grep "gateway tool-gateway:" "$work/$1.gateway.log" | tail -1 |
    grep -o "bus->backbone [0-9]* frames ([0-9]* batches)\|conflated [0-9]*\|process-dropped [0-9]*\|dead-links [0-9]*" |
    awk '!seen[$1]++' | tr '\n' ',' | sed 's/,$//; s/,/, /g' || true)
  s=$(grep "surface surface:" "$work/$1.surface.log" | tail -1 |
    grep -o "backbone->bus [0-9]*\|bus-refused [0-9]*\|dead-links [0-9]*" | head -3 |
    tr '\n' ',' | sed 's/,$//; s/,/, /g' || true)
  echo "gateway: $g; surface: $s"
}

# strace_calls PID FILE: total system calls in strace -c's summary.
strace_total() { awk '$NF == "total" {print $4}' "$1" 2>/dev/null | tail -1; }
# strace_breakdown FILE FRAMES: the most frequent system calls of strace -c's summary, per frame
# ("epoll_wait 1.02 recvmmsg 1.00 ..."): at 1,000 frames/s each frame is a wake of its own, so
# this is what one wake costs, call by call (epoll_wait counts the wakes).
strace_breakdown() {
  awk -v d="$2" '$4 ~ /^[0-9]+$/ && $NF != "total" && d > 0 {print $4 / d, $NF}' "$1" 2>/dev/null |
    sort -rn | head -8 | awk '{printf "%s %.2f ", $2, $1}'
}

# fourbus NAME: the four-bus scenario against the running bridge (four-module configs).
fourbus() {
  local name=$1 per_bus=$((8 * 1000 * fourbus_seconds)) i pids=() g0 s0 g1 s1 t0 t1
  local buses=(vcan1 vcan2 vcan3 vcan4) sink_ids=(1a1 1c1 181 1e1)
  for i in 0 1 2 3; do
    timeout 600 "$counter" --source "${buses[$i]}" --sink vcan0 --id 181 --sink-id "${sink_ids[$i]}" \
      --count $per_bus --idle-ms 3000 >"$work/$name.4bus$i.out" &
    pids+=($!)
    wait_line "$work/$name.4bus$i.out" ready
  done
  g0=$(cpu_ticks "$gpid"); s0=$(cpu_ticks "$spid"); t0=$(date +%s.%N)
  "$pacer" --interfaces vcan1,vcan2,vcan3,vcan4 --id 181 --per-tick 8 --count $per_bus \
    >"$work/$name.4bus.send"
  g1=$(cpu_ticks "$gpid"); s1=$(cpu_ticks "$spid"); t1=$(date +%s.%N)
  # Where the gateway's resident memory is: its heap and stacks (anonymous) against mapped files
  # (code and data of the executable and its shared libraries, shared with other processes).
  awk '/^(Rss|Anonymous|Pss_File|Pss_Anon):/ {printf "%s %.1f ", $1, $2 / 1024}' \
    "/proc/$gpid/smaps_rollup" >"$work/$name.4bus.mem" 2>/dev/null || true
  local secs
  secs=$(awk -v a="$t0" -v b="$t1" 'BEGIN{print b - a}')
  echo "$(cpu_pct $((g1 - g0)) "$secs") $(rss_mb "$gpid") $(cpu_pct $((s1 - s0)) "$secs") $(rss_mb "$spid")" \
    >"$work/$name.4bus.res"
  wait "${pids[@]}" || true
  local lost=0 l sinks=""
  for i in 0 1 2 3; do
    l=$(kv "$work/$name.4bus$i.out" lost)
    lost=$((lost + ${l:-$per_bus}))
    # Where a lost frame went: the meter's own socket drops, or a sink that stopped early (3 s
    # without a frame) against the seconds the sender took.
    sinks+="${buses[$i]} delivered $(kv "$work/$name.4bus$i.out" delivered) kernel-drops $(kv "$work/$name.4bus$i.out" kernel_drops_sink) in $(kv "$work/$name.4bus$i.out" seconds) s; "
  done
  echo "$lost $(kv "$work/$name.4bus.send" rate_fps_per_bus)" >>"$work/$name.4bus.res"
  echo "${sinks}sender $(kv "$work/$name.4bus.send" seconds) s" >"$work/$name.4bus.sinks"
}

# syscalls NAME: strace -c -f on both roles over a burst on module 1; calls per delivered frame.
syscalls() {
  local name=$1 st1 st2
  strace -c -f -p "$gpid" -o "$work/$name.strace.gw" 2>"$work/$name.strace.gw.err" &
  st1=$!
  strace -c -f -p "$spid" -o "$work/$name.strace.sf" 2>"$work/$name.strace.sf.err" &
  st2=$!
  sleep 1  # strace attaches asynchronously; a benchmark may wait (tests may not)
  measure "$name.strace" vcan1 vcan0 1a1 $strace_burst burst
  kill -INT $st1 $st2
  wait $st1 $st2 || true
  local d
  d=$(out "$name.strace" delivered)
  for side in gw sf; do
    awk -v c="$(strace_total "$work/$name.strace.$side")" -v d="${d:-0}" \
      'BEGIN{if (c > 0 && d > 0) printf "%.1f ", c / d; else printf "- "}'
  done >"$work/$name.sc"
  [[ -s $work/$name.strace.gw ]] || echo "     $name: strace gave nothing: $(head -2 "$work/$name.strace.gw.err")"
  # The same at 1,000 frames/s: what each frame costs when nothing batches (the latency path).
  strace -c -f -p "$gpid" -o "$work/$name.strace1k.gw" 2>/dev/null &
  st1=$!
  strace -c -f -p "$spid" -o "$work/$name.strace1k.sf" 2>/dev/null &
  st2=$!
  sleep 1
  measure "$name.strace1k" vcan1 vcan0 1a1 $paced paced1k
  kill -INT $st1 $st2
  wait $st1 $st2 || true
  d=$(out "$name.strace1k" delivered)
  for side in gw sf; do
    awk -v c="$(strace_total "$work/$name.strace1k.$side")" -v d="${d:-0}" \
      'BEGIN{if (c > 0 && d > 0) printf "%.1f ", c / d; else printf "- "}'
  done >"$work/$name.sc1k"
  echo "gw: $(strace_breakdown "$work/$name.strace1k.gw" "${d:-0}")sf: $(strace_breakdown \
    "$work/$name.strace1k.sf" "${d:-0}")" >"$work/$name.sc1k.calls"
}

table=$work/table
touch "$table"
header() {
  printf '%-4s %-20s %6s %6s %6s %5s %7s %7s %7s %8s %6s %6s %7s %6s %6s %6s %6s %6s %6s %6s %7s %7s\n' \
    "$@" | tee -a "$work/print"
}
row() {  # RUN PATH then 20 values
  printf '%-4s %-20s %6s %6s %6s %5s %7s %7s %7s %8s %6s %6s %7s %6s %6s %6s %6s %6s %6s %6s %7s %7s\n' "$@" |
    tee -a "$table"
}
columns=(run path fps x lost reord p50_1k p99_1k p50_mx p99_max B/fr 4b_fps 4b_lost gw_cpu gw_rss
  sf_cpu sf_rss sdo_x sc_gw sc_sf us1k_gw us1k_sf)

# tunnel_row RUN LABEL EXE CONFDIR [BAUD]: every measurement of one canbridge path, one row.
tunnel_row() {
  local r=$1 label=$2 exe=$3 conf=$4 baud=${5:-} name="$1.$2" count=$burst x t0=$SECONDS
  # CANBRIDGE_BENCH_ROWS: a regular expression; only matching canbridge rows run (default all).
  [[ $label =~ ${CANBRIDGE_BENCH_ROWS:-.} ]] || return 0
  [[ -n $baud ]] && count=$serial_burst
  start_bridge "$name" "$exe" "$conf" "$baud"
  # Each role's CPU over the burst, % of one guest CPU: whether a role is the bottleneck (near
  # 100) or the pipeline waits (both well below).
  local gb sb burst_cpu
  gb=$(cpu_ticks "$gpid"); sb=$(cpu_ticks "$spid")
  measure "$name" vcan1 vcan0 1a1 "$count" burst
  burst_cpu="$(cpu_pct $(($(cpu_ticks "$gpid") - gb)) "$(out "$name" seconds)") $(cpu_pct $(($(cpu_ticks "$spid") - sb)) "$(out "$name" seconds)")"
  # CPU per frame on the latency path: each role's CPU time over the 1k/s run / frames delivered.
  local g0 s0 us1k=(- -)
  g0=$(cpu_ticks "$gpid"); s0=$(cpu_ticks "$spid")
  # CANBRIDGE_BENCH_PERF=DIR: both roles profiled over the 1k/s run (perf record, call graphs),
  # each report in DIR/NAME.{gw,sf}.perf.txt (where a frame's CPU goes when nothing batches),
  # with task clock and context switches in DIR/NAME.{gw,sf}.stat.txt.
  local perf_pids=()
  if [[ -n ${CANBRIDGE_BENCH_PERF:-} ]]; then
    mkdir -p "$CANBRIDGE_BENCH_PERF"
    perf record -F 4999 -g -p "$gpid" -o "$CANBRIDGE_BENCH_PERF/$name.gw.perf.data" \
      >/dev/null 2>&1 &
    perf_pids+=($!)
    perf record -F 4999 -g -p "$spid" -o "$CANBRIDGE_BENCH_PERF/$name.sf.perf.data" \
      >/dev/null 2>&1 &
    perf_pids+=($!)
    # Task clock and context switches of each role over the same window.
    perf stat -e task-clock,context-switches,cpu-migrations -p "$gpid" \
      -o "$CANBRIDGE_BENCH_PERF/$name.gw.stat.txt" >/dev/null 2>&1 &
    perf_pids+=($!)
    perf stat -e task-clock,context-switches,cpu-migrations -p "$spid" \
      -o "$CANBRIDGE_BENCH_PERF/$name.sf.stat.txt" >/dev/null 2>&1 &
    perf_pids+=($!)
    sleep 1  # perf attaches asynchronously; a benchmark may wait (tests may not)
  fi
  measure "$name.p1k" vcan1 vcan0 1a1 $paced paced1k
  if ((${#perf_pids[@]})); then
    kill -INT "${perf_pids[@]}"
    wait "${perf_pids[@]}" || true
    for side in gw sf; do
      perf report -i "$CANBRIDGE_BENCH_PERF/$name.$side.perf.data" --stdio --no-children \
        --sort dso,sym 2>/dev/null | grep -v '^$' | head -80 >"$CANBRIDGE_BENCH_PERF/$name.$side.perf.txt" || true
    done
  fi
  us1k[0]=$(cpu_us_per_frame $(($(cpu_ticks "$gpid") - g0)) "$(out "$name.p1k" delivered)")
  us1k[1]=$(cpu_us_per_frame $(($(cpu_ticks "$spid") - s0)) "$(out "$name.p1k" delivered)")
  measure "$name.pmax" vcan1 vcan0 1a1 $max_count pacedmax
  [[ -n $baud ]] && sdo_download "$name" vcan0 34
  stop_bridge
  local bpf notes fb=(- - - - - - -) sc=(- -)
  bpf=$(bytes_per_frame "$name")
  notes="$(counters "$name"); burst CPU % gw sf: $burst_cpu over $(out "$name" seconds) s"
  if [[ -z $baud ]]; then
    start_bridge "$name.4" "$exe" "$conf-4bus"
    fourbus "$name.4"
    sdo_download "$name" vcan0 34
    syscalls "$name.4"
    stop_bridge
    read -r -a fb <<<"$(tr '\n' ' ' <"$work/$name.4.4bus.res")"
    read -r -a sc <"$work/$name.4.sc" || true
    notes="$notes; four-bus $(counters "$name.4"); syscalls/frame at 1k gw sf: $(cat "$work/$name.4.sc1k")($(cat "$work/$name.4.sc1k.calls")); gateway MB $(cat "$work/$name.4.4bus.mem"); four-bus sinks: $(cat "$work/$name.4.4bus.sinks")"
  fi
  if [[ -n $baud ]]; then
    x=$(awk -v a="$(out "$name" rate_fps)" -v b="$baud" 'BEGIN{printf "%.3f", a / (b / 80)}')
  else
    x=$(awk -v a="$(out "$name" rate_fps)" -v b="$raw_fps" 'BEGIN{printf "%.3f", a / b}')
  fi
  local sdo_x
  sdo_x=$(awk -v a="$(sdo_ms "$r.cangw")" -v b="$(sdo_ms "$name")" \
    'BEGIN{if (a + 0 > 0 && b + 0 > 0) printf "%.2f", a / b; else print "-"}')
  row "$r" "$label" "$(out "$name" rate_fps)" "$x" "$(out "$name" lost)" "$(out "$name" reordered)" \
    "$(out "$name.p1k" latency_us_p50)" "$(out "$name.p1k" latency_us_p99)" \
    "$(out "$name.pmax" latency_us_p50)" "$(out "$name.pmax" latency_us_p99)" "${bpf:--}" \
    "${fb[5]}" "${fb[4]}" "${fb[0]}" "${fb[1]}" "${fb[2]}" "${fb[3]}" "$sdo_x" "${sc[0]}" "${sc[1]}" "${us1k[0]}" "${us1k[1]}"
  echo "     $label: $notes; $((SECONDS - t0)) s" | tee -a "$work/notes"
}

header "${columns[@]}"
for ((r = 1; r <= runs; r++)); do
  run_t0=$(date +%s)
  measure "$r.raw" vcan0 vcan0 181 "$burst" burst
  raw_fps=$(out "$r.raw" rate_fps)
  row "$r" raw "$raw_fps" 1.000 "$(out "$r.raw" lost)" "$(out "$r.raw" reordered)" - - - - - - - - - - - - - - - -

  cangw -F
  cangw -A -s vcan1 -d vcan0 -e
  measure "$r.cangw" vcan1 vcan0 181 "$burst" burst
  measure "$r.cangw.p1k" vcan1 vcan0 181 $paced paced1k
  measure "$r.cangw.pmax" vcan1 vcan0 181 $max_count pacedmax
  cangw -A -s vcan0 -d vcan1 -e
  sdo_download "$r.cangw" vcan0 2
  cangw -F
  row "$r" can-gw "$(out "$r.cangw" rate_fps)" \
    "$(awk -v a="$(out "$r.cangw" rate_fps)" -v b="$raw_fps" 'BEGIN{printf "%.3f", a / b}')" \
    "$(out "$r.cangw" lost)" "$(out "$r.cangw" reordered)" \
    "$(out "$r.cangw.p1k" latency_us_p50)" "$(out "$r.cangw.p1k" latency_us_p99)" \
    "$(out "$r.cangw.pmax" latency_us_p50)" "$(out "$r.cangw.pmax" latency_us_p99)" \
    - - - - - - - "1.00" - - - -
  echo "     paced rates reached: 1k $(kv "$work/$r.cangw.p1k.send" rate_fps_per_bus)" \
    "(largest batch $(kv "$work/$r.cangw.p1k.send" largest_batch))," \
    "max $(kv "$work/$r.cangw.pmax.send" rate_fps_per_bus) frames/s" \
    "(late wakes $(kv "$work/$r.cangw.pmax.send" late_wakes), largest batch $(kv "$work/$r.cangw.pmax.send" largest_batch));" \
    "can-gw SDO $(sdo_ms "$r.cangw") ms"

  for exe_label in "" before-; do
    exe=$canbridge
    configs=$work
    if [[ -n $exe_label ]]; then
      [[ -z $baseline ]] && continue
      exe=$baseline
      configs=$work/before
    fi
    tunnel_row "$r" "${exe_label}tcp-default" "$exe" "$configs/tcp"
    tunnel_row "$r" "${exe_label}tcp-plain" "$exe" "$configs/tcp-plain"
    [[ -n $tune ]] && tunnel_row "$r" "${exe_label}tcp-tuned" "$exe" "$configs/tuned"
    tunnel_row "$r" "${exe_label}serial-115200" "$exe" "$configs/tcp-serial-115200" 115200
    tunnel_row "$r" "${exe_label}serial-1M" "$exe" "$configs/tcp-serial-1000000" 1000000
  done
  echo "     run $r took $(($(date +%s) - run_t0)) s"
done

echo
echo "medians over $runs run(s):"
header "${columns[@]}"
# shellcheck disable=SC2013  # path names are single words
for p in $(awk '!seen[$2]++ {print $2}' "$table"); do  # paths, in table order
  vals=()
  for ((c = 3; c <= 22; c++)); do
    vals+=("$(awk -v p="$p" -v c="$c" '$2 == p {print $c}' "$table" | median)")
  done
  printf '%-4s %-20s %6s %6s %6s %5s %7s %7s %7s %8s %6s %6s %7s %6s %6s %6s %6s %6s %6s %6s %7s %7s\n' \
    med "$p" "${vals[@]}"
done
