#!/usr/bin/env bash
# Tunnel throughput and latency against the raw vcan ceiling, all in one boot of the vcan rig.
#
#   bench/tunnel_bench.sh [BUILD_DIR] [RUNS]      (default: build, 5 runs)
#   CANBRIDGE_BASELINE=OLD/canbridge bench/tunnel_bench.sh ...
#
# With CANBRIDGE_BASELINE set, each run also carries the burst and the paced run through that
# older canbridge executable (path "before"), so a change is compared with its baseline in the
# same boot, against the same raw ceiling.
#
# Per run, four paths (five with a baseline) carry a 100,000-frame `cangen -g 0` burst (id 0x181, 8 bytes, counter
# payload) to a receiver that counts loss and order (bench/can_counter):
#   raw    cangen vcan0 -> receiver on vcan0                      (the ceiling)
#   can-gw cangen vcan1 -> kernel can-gw -> vcan0                 (in-kernel reference)
#   tunnel cangen vcan1 -> canbridge gateway -> TCP -> canbridge surface -> vcan0
#   tls    the same over TLS 1.3 with a pre-shared key (auth mode psk, key made per boot)
# and then a paced 2,000-frame run (cangen -g 1, about 1,000 frames/s) measures one-way latency
# from the module bus to the surface bus with kernel receive timestamps on both.
# Prints each run and the medians; rates are also given as a ratio of the raw rate of the same run.
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
  exec "$rig" --vcan 2 --mem 1536M --timeout 1200 -- \
    env CANBRIDGE_IN_RIG=1 CANBRIDGE_BASELINE="${CANBRIDGE_BASELINE:-}" \
    CANBRIDGE_BASELINE_PRE_AUTH="${CANBRIDGE_BASELINE_PRE_AUTH:-}" "$0" "$build" "$runs"
fi

counter=$build/bench/can_counter
canbridge=$build/app/canbridge
baseline=${CANBRIDGE_BASELINE:-}
paths="raw cangw tunnel tls"
[[ -n $baseline ]] && paths="$paths before"
work=$(mktemp -d /tmp/canbridge-bench.XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
burst=100000
paced=2000

# Bounded wait for a line in a file (a benchmark script may poll; tests may not).
wait_line() {
  local file=$1 text=$2
  for _ in $(seq 400); do grep -q "$text" "$file" 2>/dev/null && return 0; sleep 0.025; done
  echo "bench: timed out waiting for '$text' in $file" >&2; cat "$file" >&2; return 1
}

# measure NAME SOURCE_IF SINK_IF COUNT GAP_MS -> key=value lines in $work/NAME.out
measure() {
  local name=$1 src=$2 sink=$3 count=$4 gap=$5
  "$counter" --source "$src" --sink "$sink" --id 181 --count "$count" --idle-ms 3000 >"$work/$name.out" &
  local pid=$!
  wait_line "$work/$name.out" ready
  cangen "$src" -g "$gap" -n "$count" -I 181 -L 8 -D i -p 100
  wait $pid
}

val() { grep "^$2=" "$work/$1.out" | cut -d= -f2; }

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
  - {id: 0, bus: vcan1}
log: {level: info, stats_interval_s: 0}
YAML
# The same pair over TLS 1.3 PSK (issue 15's cost): a key made for this boot only.
mkdir -p "$work/tls"
(umask 077 && openssl rand -hex 32 >"$work/tls/bench-gw.key")
sed -e 's|auth: {mode: plain}|auth: {mode: psk}|' \
  -e "s|gateways: \[{name: bench-gw, modules: \[0\]}\]|gateways: [{name: bench-gw, modules: [0], key_file: $work/tls/bench-gw.key}]|" \
  "$work/surface.yaml" >"$work/tls/surface.yaml"
sed -e "s|auth: {mode: plain}|auth: {mode: psk, key_file: $work/tls/bench-gw.key}|" \
  "$work/gateway.yaml" >"$work/tls/gateway.yaml"
# The baseline runs the same configs; one from before issue 15 knew neither 'auth' nor
# 'gateways' (and refuses unknown keys): CANBRIDGE_BASELINE_PRE_AUTH=1 leaves them out for it.
mkdir -p "$work/before"
for role in surface gateway; do
  if [[ -n ${CANBRIDGE_BASELINE_PRE_AUTH:-} ]]; then
    grep -v '^  auth: \|^gateways: ' "$work/$role.yaml" >"$work/before/$role.yaml"
  else
    cp "$work/$role.yaml" "$work/before/$role.yaml"
  fi
done

printf '%-4s %-7s %10s %6s %6s %6s %8s %8s %8s\n' run path frames/s ratio lost reord p50_us p99_us max_us
for ((r = 1; r <= runs; r++)); do
  measure raw vcan0 vcan0 $burst 0

  cangw -F; cangw -A -s vcan1 -d vcan0 -e
  measure cangw vcan1 vcan0 $burst 0
  measure cangw_paced vcan1 vcan0 $paced 1
  cangw -F

  # tunnel_path NAME EXECUTABLE: the burst and the paced run through one canbridge build.
  tunnel_path() {
    local name=$1 exe=$2 configs=$work
    [[ $name == before ]] && configs=$work/before
    [[ $name == tls ]] && configs=$work/tls
    "$exe" surface --config "$configs/surface.yaml" >"$work/${name}-surface.log" 2>&1 &
    local spid=$!
    wait_line "$work/${name}-surface.log" listening
    "$exe" gateway --config "$configs/gateway.yaml" >"$work/${name}-gateway.log" 2>&1 &
    local gpid=$!
    wait_line "$work/${name}-surface.log" "gateway 'bench-gw' ready"
    wait_line "$work/${name}-gateway.log" "ready"
    measure "$name" vcan1 vcan0 $burst 0
    measure "${name}_paced" vcan1 vcan0 $paced 1
    kill -TERM $gpid $spid; wait $gpid $spid || true
  }
  tunnel_path tunnel "$canbridge"
  tunnel_path tls "$canbridge"
  [[ -n $baseline ]] && tunnel_path before "$baseline"

  raw_rate=$(val raw rate_fps)
  for p in $paths; do
    paced_name=${p}_paced
    [[ $p == raw ]] && paced_name=raw
    ratio=$(awk -v a="$(val $p rate_fps)" -v b="$raw_rate" 'BEGIN{printf "%.3f", a/b}')
    printf '%-4s %-7s %10s %6s %6s %6s %8s %8s %8s\n' "$r" "$p" "$(val $p rate_fps)" "$ratio" \
      "$(val $p lost)" "$(val $p reordered)" "$(val $paced_name latency_us_p50)" \
      "$(val $paced_name latency_us_p99)" "$(val $paced_name latency_us_max)" | tee -a "$work/table"
  done
  grep -h "kernel-drops\|dropped" "$work/tunnel-gateway.log" "$work/tunnel-surface.log" | tail -2 | sed 's/^/     /'
  grep -h "TLS handshake.*failed" "$work/tls-gateway.log" "$work/tls-surface.log" | head -2 | sed 's/^/     /' || true
done

echo
echo "medians over $runs runs (ratio = frames/s of the path / frames/s of raw in the same run):"
for p in $paths; do
  awk -v p="$p" '$2 == p {print $3, $4, $5, $6, $7, $8}' "$work/table" | sort -n >"$work/col"
  med() { awk -v c="$1" '{print $c}' "$work/col" | sort -n | awk '{a[NR]=$1} END{print a[int((NR+1)/2)]}'; }
  printf '%-7s frames/s %8s  ratio %6s  lost %s  reordered %s  latency p50 %s us  p99 %s us\n' \
    "$p" "$(med 1)" "$(med 2)" "$(med 3)" "$(med 4)" "$(med 5)" "$(med 6)"
done
