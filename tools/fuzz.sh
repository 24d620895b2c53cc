#!/usr/bin/env bash
# Builds the libFuzzer targets of tests/fuzz with clang and runs each one for a while; fails when
# any target finds a crash, a sanitizer report, a leak, a timeout or runs out of memory.
#
# Usage: tools/fuzz.sh [--seconds N] [--target NAME]... [BUILD_DIR]
#   --seconds N    how long each target runs (default 10; e.g. 3600 for a long run)
#   --target NAME  run only this target (repeatable): serial_deframer_fuzz, envelope_fuzz,
#                  delimited_decoder_fuzz, pdop_reassembler_fuzz, peer_authenticator_fuzz,
#                  session_auth_fuzz
#   BUILD_DIR      build and work directory (default: build-fuzz in the repository root)
# Inside BUILD_DIR: corpus/<target>/ keeps what the fuzzers learn from run to run, seeds/<target>/
# the generated seeds, crashes/<target>/ the inputs that failed, logs/<target>.log the output.
# docs/fuzzing.md says how to reproduce and minimise a crash.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)

seconds=10
build=""
only=()
while (($#)); do
  case $1 in
    --seconds) seconds=${2:?--seconds needs a value}; shift 2 ;;
    --seconds=*) seconds=${1#*=}; shift ;;
    --target) only+=("${2:?--target needs a name}"); shift 2 ;;
    --target=*) only+=("${1#*=}"); shift ;;
    -h | --help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
    -*) echo "fuzz: unknown option $1 (see --help)" >&2; exit 2 ;;
    *) build=$1; shift ;;
  esac
done
if ! [[ $seconds =~ ^[1-9][0-9]*$ ]]; then
  echo "fuzz: --seconds wants a positive whole number, not '$seconds'" >&2
  exit 2
fi
build=$(realpath -m "${build:-$root/build-fuzz}")

for tool in clang clang++ protoc; do
  if ! command -v "$tool" >/dev/null; then
    echo "fuzz: $tool not found; run tools/install-deps.sh (clang, libclang-rt-14-dev)" >&2
    exit 1
  fi
done

# Longest input per target: room for a few maximum-size frames, small enough to mutate quickly.
# pdop_reassembler_fuzz: 2 option bytes and up to 511 operations of 4 bytes.
# peer_authenticator_fuzz: a mode byte, a challenge and a proof, then a few dozen operations.
# session_auth_fuzz: a mode byte, then up to 64 operations of a few to 257 bytes.
declare -A max_len=([serial_deframer_fuzz]=4096 [envelope_fuzz]=2048 [delimited_decoder_fuzz]=4096
                    [pdop_reassembler_fuzz]=2046 [peer_authenticator_fuzz]=2048
                    [session_auth_fuzz]=4096)
targets=(serial_deframer_fuzz envelope_fuzz delimited_decoder_fuzz pdop_reassembler_fuzz
         peer_authenticator_fuzz session_auth_fuzz)
if ((${#only[@]})); then
  for t in "${only[@]}"; do
    [[ -v "max_len[$t]" ]] || { echo "fuzz: no target '$t' (have: ${targets[*]})" >&2; exit 2; }
  done
  targets=("${only[@]}")
fi

echo "=== fuzz: building in $build"
# -Werror, as tools/clang-check.sh holds every other source to clang's warnings (README).
CC=clang CXX=clang++ cmake -S "$root/tests/fuzz" -B "$build" -G Ninja -DCMAKE_CXX_FLAGS=-Werror >/dev/null
cmake --build "$build"

failed=()
for t in "${targets[@]}"; do
  corpus=$build/corpus/$t
  crashes=$build/crashes/$t
  log=$build/logs/$t.log
  mkdir -p "$corpus" "$crashes" "$build/logs"
  echo "=== fuzz: $t for ${seconds}s"
  rc=0
  # New interesting inputs go to the first directory (corpus/), the seeds are only read.
  "$build/$t" -max_total_time="$seconds" -max_len="${max_len[$t]}" -rss_limit_mb=2048 \
    -timeout=10 -print_final_stats=1 -artifact_prefix="$crashes/" \
    "$corpus" "$build/seeds/$t" >"$log" 2>&1 || rc=$?
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
  coverage=$(grep -oE 'cov: [0-9]+ ft: [0-9]+' "$log" | tail -n 1 || true)
  echo "fuzz: $t: ${execs:-?} execs in ${seconds}s, ${coverage:-no coverage line}," \
    "corpus $(find "$corpus" -type f | wc -l) inputs"
  if ((rc != 0)); then
    echo "fuzz: $t FAILED (exit $rc); log $log, inputs in $crashes:" >&2
    grep -E 'ERROR|invariant|SUMMARY|Test unit written' "$log" >&2 || tail -n 30 "$log" >&2
    failed+=("$t")
  fi
done

if ((${#failed[@]})); then
  echo "fuzz: FAILED: ${failed[*]} (reproduce: $build/<target> $build/crashes/<target>/<file>)" >&2
  exit 1
fi
echo "fuzz: all ${#targets[@]} targets ran ${seconds}s each without a failure"
