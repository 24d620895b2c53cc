#!/usr/bin/env bash
# The folder graph of the tree, checked: every edge "folder A uses folder B" is derived from the
# #include lines of every source folder and from the link libraries of every project target, and
# any edge the allowed list below does not name fails, naming the file and line (or the target).
# The allowed graph itself must have no cycle. On top of the graph, the oldest rule is checked on
# its own: can/ and backbone/ know nothing of each other, of CANopen (canopen/, routing/, bridge/)
# or of the bridge's payload schema (proto/canbridge.proto); backbone/ uses only its own session
# schema (proto/session.proto), can/ no schema at all.
# Usage: check_layering.sh SOURCE_DIR LINK_LIBRARIES_FILE ("target folder/ lib;lib;..." lines)
set -euo pipefail -o noglob  # "*" in the graph below is a word, not a glob
src=$1
links=$2

# Every allowed folder -> folder edge, listed once. A folder's sources may include, and its
# targets link, only the folders after its name. "*" stands for every layer of the product (each
# folder whose own entry has no "*"), so the folders of tests, benches and tools may use every
# layer but one another only as listed. proto/session and proto/canbridge are proto/'s two
# schemas (session.pb.h, canbridge.pb.h: libraries canbridge_session_proto, canbridge_proto).
# backbone/auth is backbone/'s key files and peer proofs (pre_shared_keys.hpp,
# peer_authenticator.hpp: library canbridge_backbone_auth), which config/ checks key files with.
# bridge/options is bridge/'s header-only option structs of remote access, which config/ fills.
allowed_edges=(
  "coro:"
  "logging:"
  "can: coro"
  "proto:"
  "backbone: proto/session coro"
  "canopen: can"
  "yaml:"
  "routing: can canopen"
  "config: yaml canopen routing backbone/auth bridge/options"
  "sim: can canopen yaml coro logging"
  "bridge: can backbone canopen routing proto/canbridge coro"
  "app: can backbone canopen bridge config sim coro logging"
  "bench: * tools"
  "tools: *"
  "tests: * tools"
)

fail=0
problem() {
  echo "layering: $*" >&2
  fail=1
}

declare -A allowed=()
for entry in "${allowed_edges[@]}"; do
  folder=${entry%%:*}
  if [[ -v allowed[$folder] ]]; then problem "folder $folder/ is listed twice in the folder graph"; fi
  read -ra targets <<<"${entry#*:}"
  declare -A seen=()
  for t in "${targets[@]}"; do
    if [[ -v seen[$t] ]]; then problem "edge $folder -> $t is listed twice"; fi
    seen[$t]=1
  done
  unset seen
  allowed[$folder]=" ${targets[*]} "
done

# The layers "*" stands for.
declare -A layer=()
for folder in "${!allowed[@]}"; do
  if [[ ${allowed[$folder]} != *" * "* ]]; then layer[$folder]=1; fi
done
allows() {  # FROM TO: is FROM -> TO an allowed edge? (TO may be proto/session: folder proto)
  local list=${allowed[$1]:-} folder=${2%%/*}
  [[ $list == *" $2 "* || $list == *" $folder "* || ($list == *" * "* && -v layer[$folder]) ]]
}

# Every top-level folder holding sources must have its place in the graph.
mapfile -t source_folders < <(find "$src" -mindepth 2 -path "$src/.*" -prune -o \
  -path "$src/build*" -prune -o -type f \( -name '*.cpp' -o -name '*.hpp' -o -name '*.h' \
  -o -name '*.cc' -o -name '*.c' -o -name '*.proto' \) -printf '%P\n' | cut -d/ -f1 | sort -u)
for folder in "${source_folders[@]}"; do
  if [[ ! -v allowed[$folder] ]]; then
    problem "folder $folder/ has sources but no entry in the folder graph"
  fi
done

# The allowed graph has no cycle ("*" stands for an edge to every other folder).
graph=$(for folder in "${!allowed[@]}"; do
  echo "$folder $folder"
  for t in ${allowed[$folder]}; do
    if [[ $t == "*" ]]; then
      for other in "${!layer[@]}"; do echo "$folder $other"; done
    else
      echo "$folder ${t%%/*}"
    fi
  done
done)
if ! loop=$(tsort <<<"$graph" 2>&1 >/dev/null) || [[ -n $loop ]]; then
  problem "the allowed folder graph has a cycle: $loop"
fi

declare -A used=()
# Edges from #include lines: "X/..." for a top-level folder X, and the two generated schemas.
while IFS= read -r hit; do
  file=${hit%%:*}
  rest=${hit#*:}
  line=${rest%%:*}
  text=${rest#*:}
  from=${file%%/*}
  [[ $text =~ \#[[:space:]]*include[[:space:]]*[\<\"]([^\>\"]+)[\>\"] ]] || continue
  header=${BASH_REMATCH[1]}
  if [[ $header == *../* ]]; then
    problem "$file:$line: includes a relative path ($header): name the folder"
    continue
  fi
  case $header in
    session.pb.h) to=proto/session ;;
    canbridge.pb.h) to=proto/canbridge ;;
    backbone/pre_shared_keys.hpp | backbone/peer_authenticator.hpp) to=backbone/auth ;;
    bridge/command_endpoint_options.hpp | bridge/surface_remote_options.hpp | \
      bridge/gateway_remote_options.hpp) to=bridge/options ;;
    */*)
      to=${header%%/*}
      if [[ ! -v allowed[$to] ]]; then continue; fi
      ;;
    *) continue ;;
  esac
  if [[ ${to%%/*} == "$from" ]]; then continue; fi
  used["$from $to"]=1
  allows "$from" "$to" || problem "$file:$line: $from/ includes $to ($header): not an edge of the folder graph"
done < <(cd "$src" && grep -rnE '^[[:space:]]*#[[:space:]]*include' "${source_folders[@]}" \
  --include='*.cpp' --include='*.hpp' --include='*.h' --include='*.cc' --include='*.c')

# Edges from link libraries: a project target links a project library of another folder.
declare -A target_node=()
while read -r target folder _; do
  case $target in
    canbridge_session_proto) target_node[$target]=proto/session ;;
    canbridge_proto) target_node[$target]=proto/canbridge ;;
    canbridge_backbone_auth) target_node[$target]=backbone/auth ;;
    *) target_node[$target]=${folder%%/*} ;;
  esac
done <"$links"
while read -r target folder libs; do
  from=${folder%%/*}
  if [[ -z $from ]]; then continue; fi  # build infrastructure of the top-level CMakeLists
  IFS=';' read -ra deps <<<"${libs:-}"
  for dep in "${deps[@]}"; do
    if [[ ! -v target_node[$dep] ]]; then continue; fi
    to=${target_node[$dep]}
    if [[ -z $to || ${to%%/*} == "$from" ]]; then continue; fi
    used["$from $to"]=1
    allows "$from" "$to" || problem "target $target ($from/) links $dep ($to/): not an edge of the folder graph"
  done
done <"$links"

# An allowed edge nothing uses is worth knowing (the list should stay the true graph), not a failure.
for folder in "${!allowed[@]}"; do
  for t in ${allowed[$folder]}; do
    if [[ $t != "*" && ! -v used["$folder $t"] ]]; then
      echo "layering: note: allowed edge $folder -> $t is unused"
    fi
  done
done

# The oldest rule, on its own: can/ and backbone/ independent of each other and of CANopen.
check_includes() {  # DIR FORBIDDEN_PREFIX...
  local dir=$1; shift
  for prefix in "$@"; do
    if grep -rnE "#include [<\"]${prefix}/" "$src/$dir" --include='*.?pp'; then
      problem "$dir/ includes $prefix/ headers"
    fi
  done
}
check_links() {  # TARGET FORBIDDEN_TARGET...
  local target=$1; shift
  local line
  line=$(grep "^$target " "$links") || { problem "target $target is missing from $links"; return; }
  for forbidden in "$@"; do
    if [[ $line =~ (^|[^a-z_])$forbidden([^a-z_]|$) ]]; then
      problem "$target links $forbidden ($line)"
    fi
  done
}
check_includes can backbone canopen routing bridge proto config sim yaml app
check_includes backbone can canopen routing bridge proto config sim yaml app
if grep -rnE '#include [<"](canbridge|session)\.pb\.h' "$src/can" --include='*.?pp'; then
  problem "can/ includes a backbone schema"
fi
if grep -rnE '#include [<"]canbridge\.pb\.h' "$src/backbone" --include='*.?pp'; then
  problem "backbone/ includes the bridge's payload schema (canbridge.pb.h)"
fi
check_links canbridge_can canbridge_backbone canbridge_bridge canbridge_routing canbridge_proto canbridge_session_proto canbridge_canopen
check_links canbridge_backbone canbridge_can canbridge_bridge canbridge_routing canbridge_proto canbridge_canopen
check_links canbridge_backbone_core canbridge_can canbridge_bridge canbridge_routing canbridge_proto canbridge_session_proto canbridge_canopen

if [[ $fail == 0 ]]; then
  echo "layering: every include and link follows the folder graph:"
  printf '  %s\n' "${allowed_edges[@]}"
fi
exit $fail
