#!/usr/bin/env bash
# logging.fatal_errors: the errors canbridge writes itself before or instead of running a role
# (config errors, usage errors, the exception that ends a role) follow --log-format as the
# logger's lines do: under journal every line of stderr starts with <3>, so that the journal files
# a multi-line config error at priority error; under text they stay as they were. The same for
# canbridge-sim and canbridge-link-emulator.
# Usage: fatal_errors_test.sh CANBRIDGE CANBRIDGE_SIM CANBRIDGE_LINK_EMULATOR SOURCE_DIR
# CANBRIDGE_TARGET_LAUNCHER: what runs the programs in a cross-built tree (qemu-user), if any.
set -euo pipefail
launcher=${CANBRIDGE_TARGET_LAUNCHER:-}
canbridge=$1 sim=$2 emulator=$3 source=$4
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
fail() {
  echo "logging.fatal_errors: FAIL: $*" >&2
  exit 1
}

# run_program NAME STATUS PROGRAM ARGS...: runs PROGRAM ARGS with stderr in $scratch/NAME.err,
# expects STATUS.
run_program() {
  local name=$1 status=$2
  shift 2
  local got=0
  # shellcheck disable=SC2086 # the launcher is a command with its arguments
  $launcher "$@" >"$scratch/$name.out" 2>"$scratch/$name.err" || got=$?
  [[ $got == "$status" ]] || fail "$name: exit status $got, expected $status: $(cat "$scratch/$name.err")"
  [[ -s $scratch/$name.err ]] || fail "$name: nothing on stderr"
  [[ ! -s $scratch/$name.out ]] || fail "$name: stdout is not empty: $(cat "$scratch/$name.out")"
}
run() {  # run NAME STATUS ARGS...: canbridge ARGS
  local name=$1 status=$2
  shift 2
  run_program "$name" "$status" "$canbridge" "$@"
}
# every_line_journal NAME NEEDLE: every stderr line starts with <3>, and one says NEEDLE.
every_line_journal() {
  local bad
  bad=$(grep -v '^<3>' "$scratch/$1.err" || true)
  [[ -z $bad ]] || fail "$1: lines without <3>: $bad"
  grep -qF -- "$2" "$scratch/$1.err" || fail "$1: no '$2' in: $(cat "$scratch/$1.err")"
  echo "$1: $(wc -l <"$scratch/$1.err") line(s), all <3>"
}

# A config file with three problems: the error is four lines.
cat >"$scratch/bad.yaml" <<'EOF'
role: gateway
name: broken
log: {level: loud}
modules: [{id: 9, bus: vcan1}]
EOF

run missing_file 2 surface --log-format journal --config /nonexistent
every_line_journal missing_file "<3>canbridge: invalid configuration (1 problem)"

run three_problems 2 gateway --log-format journal --config "$scratch/bad.yaml"
every_line_journal three_problems "<3>canbridge: invalid configuration (3 problems)"
[[ $(wc -l <"$scratch/three_problems.err") == 4 ]] || fail "three_problems: not 4 lines"
grep -qF "<3>  $scratch/bad.yaml:3: log.level: 'loud'" "$scratch/three_problems.err" ||
  fail "three_problems: the problem lines are not prefixed as written"

# Refused after the file loaded (a usage error of main's own).
run lss_module 2 gateway --log-format journal \
  --config "$source/tests/config/fixtures/gateway_profiles.yaml" --lss-module 9
every_line_journal lss_module "<3>canbridge: --lss-module 9: not the id of a module in"

# A usage error of the grammar: --log-format stood before the bad argument.
run bad_argument 2 surface --log-format journal --bogus
every_line_journal bad_argument "<3>canbridge: unexpected argument(s): --bogus"

# auto (the default), as systemd runs the units: stderr is the journal when JOURNAL_STREAM names
# its device and inode (here a file standing in for the journal's stream).
: >"$scratch/auto.err"
stream=$(stat -c '%d:%i' "$scratch/auto.err")
got=0
# shellcheck disable=SC2086
JOURNAL_STREAM=$stream $launcher "$canbridge" gateway --config "$scratch/bad.yaml" >/dev/null \
  2>>"$scratch/auto.err" || got=$?
[[ $got == 2 ]] || fail "auto: exit status $got"
every_line_journal auto "<3>canbridge: invalid configuration (3 problems)"

# text: the lines as a terminal shows them, no prefix.
run text 2 gateway --log-format text --config "$scratch/bad.yaml"
[[ $(head -1 "$scratch/text.err") == "canbridge: invalid configuration (3 problems)" ]] ||
  fail "text: first line $(head -1 "$scratch/text.err")"
! grep -q '^<' "$scratch/text.err" || fail "text: a prefixed line: $(cat "$scratch/text.err")"
echo "text: $(wc -l <"$scratch/text.err") line(s), none prefixed"

# canbridge-sim: a rig with two problems (exit 2, as canbridge for its own files), a --bus the rig
# does not have (a usage error).
cat >"$scratch/bad_rig.yaml" <<'EOF'
rig: broken
buses:
  - name: a
    nodes:
      - {kind: bogus, node_id: 200}
EOF
run_program sim_rig 2 "$sim" --log-format journal "$scratch/bad_rig.yaml"
every_line_journal sim_rig "<3>canbridge-sim: invalid configuration (2 problems)"
run_program sim_bus 2 "$sim" --log-format journal --virtual --bus nope "$source/config/rigs/demo.yaml"
every_line_journal sim_bus "<3>canbridge-sim: rig demo has no bus nope"

# canbridge-link-emulator: an endpoint that cannot be made ends the run (exit 1).
run_program emulator_endpoint 1 "$emulator" --log-format journal \
  --a "pty:$scratch/no/such/dir/pty" --b tcp-listen:127.0.0.1:0
every_line_journal emulator_endpoint "<3>canbridge-link-emulator: symlink $scratch/no/such/dir/pty"

echo "logging.fatal_errors: OK"
