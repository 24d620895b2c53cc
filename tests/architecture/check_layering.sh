#!/usr/bin/env bash
# Fails when can/ or backbone/ depend on each other, on bridge/ (CANopen routing) or on the
# bridge's payload schema (proto/canbridge.proto). backbone/ may use its own session schema
# (proto/session.proto, library canbridge_session_proto); can/ uses no schema at all.
# Usage: check_layering.sh SOURCE_DIR LINK_LIBRARIES_FILE
set -euo pipefail
src=$1
links=$2
fail=0
check_includes() {  # DIR FORBIDDEN_PREFIX...
  local dir=$1; shift
  for prefix in "$@"; do
    if grep -rnE "#include [<\"]${prefix}/" "$src/$dir" --include='*.?pp'; then
      echo "layering: $dir/ includes $prefix/ headers" >&2
      fail=1
    fi
  done
}
check_links() {  # TARGET FORBIDDEN_TARGET...
  local target=$1; shift
  local line
  line=$(grep "^$target:" "$links")
  for forbidden in "$@"; do
    if [[ $line =~ (^|[^a-z_])$forbidden([^a-z_]|$) ]]; then
      echo "layering: $target links $forbidden ($line)" >&2
      fail=1
    fi
  done
}
check_includes can backbone bridge proto config sim
check_includes backbone can bridge proto config sim
if grep -rnE '#include [<"](canbridge|session)\.pb\.h' "$src/can" --include='*.?pp'; then
  echo "layering: can/ includes a backbone schema" >&2
  fail=1
fi
if grep -rnE '#include [<"]canbridge\.pb\.h' "$src/backbone" --include='*.?pp'; then
  echo "layering: backbone/ includes the bridge's payload schema (canbridge.pb.h)" >&2
  fail=1
fi
check_links canbridge_can canbridge_backbone canbridge_bridge canbridge_routing canbridge_proto canbridge_session_proto canbridge_canopen
check_links canbridge_backbone canbridge_can canbridge_bridge canbridge_routing canbridge_proto canbridge_canopen
check_links canbridge_backbone_core canbridge_can canbridge_bridge canbridge_routing canbridge_proto canbridge_session_proto canbridge_canopen
[[ $fail == 0 ]] && echo "layering: can/ and backbone/ are independent of each other and of CANopen routing"
exit $fail
