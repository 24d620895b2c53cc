#!/usr/bin/env bash
# Remote access (issue 16) against the transparent tunnel, in one boot of the vcan rig: the same
# SDO work run by the gateway through the surface's CiA 309-3 endpoint ("endpoint") and by a
# master on the surface bus whose every SDO frame crosses the backbone ("transparent").
#
#   bench/remote_sdo_bench.sh [BUILD_DIR] [RUNS]      (default: build, 3 runs; medians printed)
#
# Nodes (canbridge-sim): module 1 (vcan1, cia301, net 2) locals 1..4 = surface 42..45; module 2
# (vcan2, qd, net 3) locals 1..4 = surface 1..4. Links, each through canbridge-link-emulator:
#   tcp0      TCP, no added latency
#   tcp20     TCP, 10 ms each way (20 ms round trip)
#   serial    a pty pair at 115200 bit/s (8N1, 4 KiB line buffer), the slow-line session tuning
# Per link and run: a 64 KiB segmented download and a 64 KiB block download into 2100h of
# cia301 local 1 (surface 42), and 100 expedited reads of 1018h:01 over the 8 nodes, one at a
# time and with one in flight per node (--parallel). Then the robustness run on tcp20: a 256 KiB
# firmware image to qd local 1 (surface 1) by the gateway (endpoint `flash`) and by a transparent
# master (the same loader sequence), each while the emulator cuts the link three times
# (--cut-at, placed inside the gateway's uncut flash time); the gateway's result is verified by
# reading 1F56h:01 against the image's CRC-32.
# Environment: CANBRIDGE_BENCH_LINKS (default "tcp0 tcp20 serial"), CANBRIDGE_BENCH_SLOW_RUNS
# (runs of the transparent segmented download on tcp20 and serial, which take minutes each;
# default RUNS), CANBRIDGE_BENCH_ROBUSTNESS (default 1; 0 skips it).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
build=$(cd "${1:-$root/build}" && pwd)
runs=${2:-3}

if [[ -z ${CANBRIDGE_IN_RIG:-} ]]; then
  # shellcheck source=bench/rig_common.sh
  source "$here/rig_common.sh"
  # CANBRIDGE_BENCH_RIG=qemu: Debian's kernel in qemu-system instead of user-mode Linux.
  rig=$(rig_script uml)
  exec "$rig" --vcan 3 --mem 1536M --timeout 5400 -- \
    env CANBRIDGE_IN_RIG=1 "$0" "$build" "$runs"
fi

probe=$build/bench/remote_sdo_probe
canbridge=$build/app/canbridge
sim=$build/sim/canbridge-sim
emulator=$build/tools/link_emulator/canbridge-link-emulator
for b in "$probe" "$canbridge" "$sim" "$emulator"; do
  [[ -x $b ]] || { echo "bench: $b is missing (build it first)" >&2; exit 1; }
done
work=$(mktemp -d /tmp/canbridge-remote-bench.XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$work"' EXIT
read -r -a links <<<"${CANBRIDGE_BENCH_LINKS:-tcp0 tcp20 serial}"
slow_runs=${CANBRIDGE_BENCH_SLOW_RUNS:-$runs}
sock=$work/surface.sock
timeout_ms=5000

# Bounded wait for a line in a file (a benchmark script may poll; tests may not).
wait_line() {
  local file=$1 text=$2
  for _ in $(seq 1200); do grep -q "$text" "$file" 2>/dev/null && return 0; sleep 0.025; done
  echo "bench: timed out waiting for '$text' in $file" >&2; cat "$file" >&2; return 1
}
now() { date +%s.%N; }

{
  echo "rig: remote-bench"
  echo "buses:"
  for bus in "cia301-module vcan1 cia301" "qd-module vcan2 qd"; do
    read -r name interface kind <<<"$bus"
    echo "  - name: $name"
    echo "    interface: $interface"
    echo "    nodes:"
    for n in 1 2 3 4; do
      echo "      - {name: $kind$n, kind: $kind, node_id: $n, heartbeat_ms: 1000,"
      echo "         objects: [{index: 0x2100, type: domain, size: 0}]}"
    done
  done
} >"$work/rig.yaml"

slow_line="  keepalive_ms: 200
  dead_after_ms: 1000
  retransmit_ms: 1000
  max_write_bytes: 512"
modules="modules:
  - {id: 1, bus: vcan1, profile: cia301, nodes: {1: 42, 2: 43, 3: 44, 4: 45}}
  - {id: 2, bus: vcan2, profile: qd, nodes: {1: 1, 2: 2, 3: 3, 4: 4}}"
gateways="gateways: [{name: bench-gw, modules: [1, 2], surface_nodes: [1-4, 42-45]}]
command_endpoint: {unix_socket: $sock, sdo_timeout_ms: $timeout_ms}"

# start_bridge LINK [emulator args...]: emulator, surface and gateway; returns once the session
# is up and the endpoint's socket exists. Sets $ready_at (the emulator's ready line, for cuts).
start_bridge() {
  local link=$1
  shift
  rm -f "$sock"
  if [[ $link == serial ]]; then
    cat >"$work/surface.yaml" <<YAML
role: surface
name: bench-surface
bus: vcan0
backbone:
  auth: {mode: plain}
  serial:
    - {device: $work/surface.tty, baud: 115200, gateway: bench-gw}
$slow_line
$gateways
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
$modules
log: {level: info, stats_interval_s: 0}
YAML
    "$emulator" --a "pty:$work/gw.tty" --b "pty:$work/surface.tty" --baud 115200 \
      --buffer-bytes 4096 "$@" >"$work/emulator.log" 2>&1 &
    epid=$!
    wait_line "$work/emulator.log" "link-emulator: ready"
    ready_at=$(now)
    "$canbridge" surface --config "$work/surface.yaml" >"$work/surface.log" 2>&1 &
    spid=$!
    "$canbridge" gateway --config "$work/gateway.yaml" >"$work/gateway.log" 2>&1 &
    gpid=$!
    wait_line "$work/gateway.log" "ready over $work/gw.tty"
    wait_line "$work/surface.log" "ready over $work/surface.tty"
  else
    cat >"$work/surface.yaml" <<YAML
role: surface
name: bench-surface
bus: vcan0
backbone: {listen: 127.0.0.1:7100, auth: {mode: plain}, keepalive_ms: 100, dead_after_ms: 400}
$gateways
log: {level: info, stats_interval_s: 0}
YAML
    "$canbridge" surface --config "$work/surface.yaml" >"$work/surface.log" 2>&1 &
    spid=$!
    wait_line "$work/surface.log" listening
    local latency=0
    [[ $link == tcp20 ]] && latency=10
    "$emulator" --a tcp-listen:127.0.0.1:7101 --b tcp-connect:127.0.0.1:7100 \
      --latency-ms $latency "$@" >"$work/emulator.log" 2>&1 &
    epid=$!
    wait_line "$work/emulator.log" "link-emulator: ready"
    ready_at=$(now)
    cat >"$work/gateway.yaml" <<YAML
role: gateway
name: bench-gw
backbone: {connect: 127.0.0.1:7101, auth: {mode: plain}, reconnect_min_ms: 20,
           reconnect_max_ms: 100, keepalive_ms: 100, dead_after_ms: 400}
$modules
log: {level: info, stats_interval_s: 0}
YAML
    "$canbridge" gateway --config "$work/gateway.yaml" >"$work/gateway.log" 2>&1 &
    gpid=$!
    wait_line "$work/surface.log" "gateway 'bench-gw' ready"
  fi
  for _ in $(seq 400); do [[ -S $sock ]] && break; sleep 0.025; done
  [[ -S $sock ]] || { echo "bench: no endpoint socket $sock" >&2; cat "$work/surface.log" >&2; exit 1; }
}

stop_bridge() {
  kill -TERM $gpid $spid $epid 2>/dev/null || true
  wait $gpid $spid $epid 2>/dev/null || true
}

val() { grep "^$2=" "$1" | cut -d= -f2- || true; }
# probe OUT MODE ARGS...: runs the probe; its key=value lines go to OUT. Both ways use the same
# SDO timeout: the surface's wait for a long gateway-run transfer follows its progress reports.
probe() {
  local out=$1
  shift
  "$probe" "$@" --timeout-ms $timeout_ms >"$out" 2>&1 || true
}

# measure LINK RUN CASE WAY: one measurement, one row in $work/table
# (link run case way ok ms error).
measure() {
  local link=$1 r=$2 case=$3 way=$4 out=$work/out.$1.$2.$3.$4
  case "$case/$way" in
    segdown/endpoint) probe "$out" endpoint --socket "$sock" --net 2 --node 1 --op segdown --size 65536 --seed "$r" ;;
    segdown/transparent) probe "$out" master --interface vcan0 --node 42 --op segdown --size 65536 --seed "$r" ;;
    blockdown/endpoint) probe "$out" endpoint --socket "$sock" --net 2 --node 1 --op blockdown --size 65536 --seed "$r" ;;
    blockdown/transparent) probe "$out" master --interface vcan0 --node 42 --op blockdown --size 65536 --seed "$r" ;;
    reads/endpoint) probe "$out" endpoint-reads --socket "$sock" --count 100 \
      --targets 2:1,2:2,2:3,2:4,3:1,3:2,3:3,3:4 ;;
    reads/transparent) probe "$out" master-reads --interface vcan0 --count 100 --nodes 42,43,44,45,1,2,3,4 ;;
    preads/endpoint) probe "$out" endpoint-reads --socket "$sock" --count 100 --parallel \
      --targets 2:1,2:2,2:3,2:4,3:1,3:2,3:3,3:4 ;;
    preads/transparent) probe "$out" master-reads --interface vcan0 --count 100 --parallel \
      --nodes 42,43,44,45,1,2,3,4 ;;
  esac
  local ok ms err
  ok=$(val "$out" ok)
  ms=$(val "$out" ms)
  err=$(val "$out" error)
  printf '%-7s %3s %-9s %-11s %2s %10s  %s\n' "$link" "$r" "$case" "$way" "${ok:-0}" "${ms:--}" \
    "${err:-$(grep -v '=' "$out" | head -1)}" | tee -a "$work/table"
}

"$sim" "$work/rig.yaml" --stats-seconds 0 >"$work/sim.log" 2>&1 &
simpid=$!
wait_line "$work/sim.log" "canbridge-sim: ready"

echo "remote access vs transparent tunnel: 64 KiB segmented / block downloads, 100 expedited" \
  "reads over 8 nodes of two modules; $runs runs; $(nproc) CPU, $(uname -r)"
printf '%-7s %3s %-9s %-11s %2s %10s  %s\n' link run case way ok ms notes
touch "$work/table"
for link in "${links[@]}"; do
  start_bridge "$link"
  for ((r = 1; r <= runs; r++)); do
    for c in segdown blockdown reads preads; do
      measure "$link" "$r" "$c" endpoint
      if [[ $c == segdown && $link != tcp0 && $r -gt $slow_runs ]]; then continue; fi
      measure "$link" "$r" "$c" transparent
    done
  done
  stop_bridge
done

echo
echo "medians (ms, successful runs only) and ratio transparent / endpoint (> 1: the endpoint is faster);"
echo "rate = 65536 B / median time; serial line payload rate 115200/10 = 11520 B/s"
printf '%-7s %-9s %12s %12s %8s %12s %12s\n' link case endpoint_ms transp_ms ratio ep_B/s tr_B/s
med() { awk -v l="$1" -v c="$2" -v w="$3" '$1 == l && $3 == c && $4 == w && $5 == 1 {print $6}' \
  "$work/table" | sort -g | awk '{a[NR]=$1} END{if (NR) print a[int((NR+1)/2)]; else print "-"}'; }
for link in "${links[@]}"; do
  for c in segdown blockdown reads preads; do
    e=$(med "$link" "$c" endpoint)
    t=$(med "$link" "$c" transparent)
    awk -v l="$link" -v c="$c" -v e="$e" -v t="$t" 'BEGIN{
      ratio = (e != "-" && t != "-" && e > 0) ? sprintf("%.1f", t / e) : "-";
      erate = (c ~ /down/ && e != "-") ? sprintf("%.0f", 65536000 / e) : "-";
      trate = (c ~ /down/ && t != "-") ? sprintf("%.0f", 65536000 / t) : "-";
      printf "%-7s %-9s %12s %12s %8s %12s %12s\n", l, c, e, t, ratio, erate, trate }'
  done
done

if [[ ${CANBRIDGE_BENCH_ROBUSTNESS:-1} == 1 ]]; then
  echo
  echo "robustness: 256 KiB firmware to qd local 1 (surface 1) on tcp20, three link cuts"
  # Two images: the uncut runs flash one, the cut runs the other, so that 1F56h after a cut run
  # can only show the cut run's image. Prints the second one's CRC-32.
  crc=$(python3 - "$work/image.bin" "$work/image_cut.bin" <<'PY'
import random, sys, zlib
for seed, path in ((16, sys.argv[1]), (17, sys.argv[2])):
    random.seed(seed)
    app = bytes(random.getrandbits(8) for _ in range(256 * 1024 - 4))
    open(path, 'wb').write(app + zlib.crc32(app).to_bytes(4, 'little'))
print(zlib.crc32(app))
PY
)
  # Uncut, to place the cuts inside the gateway's flash time.
  start_bridge tcp20
  probe "$work/flash.uncut.ep" endpoint-flash --socket "$sock" --net 3 --node 1 --image "$work/image.bin"
  probe "$work/flash.uncut.tr" master-flash --interface vcan0 --node 1 --image "$work/image.bin"
  stop_bridge
  d=$(val "$work/flash.uncut.ep" ms)
  printf 'uncut    endpoint ok=%s %s ms (%s progress lines); transparent ok=%s %s ms %s\n' \
    "$(val "$work/flash.uncut.ep" ok)" "$d" "$(val "$work/flash.uncut.ep" progress_lines)" \
    "$(val "$work/flash.uncut.tr" ok)" "$(val "$work/flash.uncut.tr" ms)" \
    "$(val "$work/flash.uncut.tr" error)"
  # The flash starts `lead` s after the emulator's ready line; cuts at 15/45/75 % of the uncut
  # gateway time, each an eighth of it (at least 0.2 s).
  lead=4
  cuts=$(awk -v d="${d:-2000}" -v s=$lead 'BEGIN{
    len = d / 8000; if (len < 0.2) len = 0.2;
    for (i = 0; i < 3; ++i) printf "--cut-at %.3f+%.3f ", s + d * (0.15 + 0.3 * i) / 1000, len }')
  for way in endpoint transparent; do
    # shellcheck disable=SC2086
    start_bridge tcp20 $cuts
    sleep "$(awk -v r="$ready_at" -v n="$(now)" -v s=$lead 'BEGIN{w = r + s - n; print (w > 0 ? w : 0)}')"
    t0=$(now)
    if [[ $way == endpoint ]]; then
      probe "$work/flash.cut.$way" endpoint-flash --socket "$sock" --net 3 --node 1 --image "$work/image_cut.bin"
    else
      probe "$work/flash.cut.$way" master-flash --interface vcan0 --node 1 --image "$work/image_cut.bin"
    fi
    t1=$(now)
    verify=-
    if [[ $way == endpoint ]]; then
      wait_line "$work/surface.log" "gateway 'bench-gw' ready"
      verify=$(python3 - "$sock" <<'PY'
import socket, sys
s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); s.sendall(b"[1] 3 1 r 0x1F56 1 u32\n")
buf = b""
while not buf.endswith(b"\r\n"): buf += s.recv(100)
print(buf.decode().strip()[4:])
PY
)
    fi
    stop_bridge
    begun=$(grep -c "cut [0-9]/3 begins" "$work/emulator.log" || true)
    inside=$(awk -v r="$ready_at" -v a="$t0" -v b="$t1" -v c="$cuts" 'BEGIN{
      n = split(c, w, " "); k = 0;
      for (i = 2; i <= n; i += 2) { split(w[i], p, "+"); t = r + p[1]; if (t > a && t < b) ++k }
      print k }')
    printf 'cut      %-11s ok=%s %s ms, cuts begun %s, inside the transfer %s/3; %s%s\n' "$way" \
      "$(val "$work/flash.cut.$way" ok)" "$(val "$work/flash.cut.$way" ms)" "$begun" "$inside" \
      "$(val "$work/flash.cut.$way" error)" \
      "$([[ $way == endpoint ]] && echo "1F56h:01 = $verify (image CRC-32 $crc)")"
  done
  echo "cut schedule: $cuts(seconds after the emulator's ready line; the flash starts at $lead s)"
fi
kill -TERM $simpid
wait $simpid || true
