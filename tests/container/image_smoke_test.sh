#!/usr/bin/env bash
# The image smoke test: builds the canbridge image with docker/build.sh (a debootstrap base and
# `podman build --isolation=chroot`) and checks it from its root filesystem, because no
# container can be started on the build machines: the three executables answer --version (or
# --help), `canbridge demo` runs to completion as the image's non-root user, the sample configs
# load as far as their missing keys (exit 2 naming the key file), every reference rig runs in
# canbridge-sim on virtual buses, the compose file is valid and its three services (simulated
# modules, gateway, surface) carry the nodes' heartbeats from vcan1 to vcan0 in the vcan rig,
# the image runs as uid 10001 and holds no compiler, and the build left no dangling image.
#
#   tests/container/image_smoke_test.sh SOURCE_DIR [CANBRIDGE CANBRIDGE_SIM LINK_EMULATOR]
#
# Without executables the image compiles them from source (the Dockerfile's default `runtime`
# stage). Given the three (ctest passes its build tree's own, CANBRIDGE_IMAGE_TEST_PREBUILT), it
# builds the `prebuilt` target with them (docker/build.sh --prebuilt), which skips the compile,
# and checks also that the image holds exactly their stripped copies. Every other check is the
# same for both. A base image that another docker/build.sh is making (CI's --base-only in the
# background) is waited for, not made twice.
#
# Exit 77 (ctest: skipped) only where podman cannot run at all; needs root (debootstrap, mounting
# the image, chroot). Environment: CANBRIDGE_TEST_IMAGE (default localhost/canbridge:smoketest);
# CANBRIDGE_TEST_IMAGE_PREBUILT=1 checks that image as it is, without running docker/build.sh.
set -euo pipefail
# env -i runs it with the image's PATH, which may not hold the host's /usr/sbin.
chroot=$(command -v chroot)

# Inside a fresh network namespace (see the end): the checks that run the executables, with the
# backbone on a private loopback, so nothing clashes with the host's ports.
if [[ ${1:-} == --run-in-netns ]]; then
  rootfs=$2 work=$3
  ip link set lo up
  failures=0
  fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }
  # Starts a command as the image's user with the image's PATH (what `docker run` would do), in
  # the background, its output through a FIFO; sets the variables pid_NAME and fd_NAME.
  start() {
    local name=$1
    shift
    mkfifo "$work/$name.fifo"
    # A simple command, so that $! is the program itself (env and chroot exec it).
    env -i PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
      "$chroot" --userspec=10001:10001 "$rootfs" "$@" >"$work/$name.fifo" 2>&1 &
    printf -v "pid_$name" %s $!
    local fd
    exec {fd}<"$work/$name.fifo"
    printf -v "fd_$name" %s "$fd"
  }
  # Reads NAME's output (copied to its log) until a line contains TEXT; 1 when the process ends
  # or SECONDS pass first.
  await_line() {
    local name=$1 text=$2 seconds=$3 fd_var="fd_$1" line
    local deadline=$((SECONDS + seconds))
    while ((SECONDS < deadline)) && IFS= read -r -t $((deadline - SECONDS)) -u "${!fd_var}" line; do
      printf '%s\n' "$line" >>"$work/$name.log"
      [[ $line == *"$text"* ]] && return 0
    done
    return 1
  }
  # Sends SIGTERM, keeps the rest of the output and returns the exit status.
  stop() {
    local name=$1 pid_var="pid_$1" fd_var="fd_$1" status=0
    local fd=${!fd_var}
    kill -TERM "${!pid_var}" 2>/dev/null || true
    # EOF once the program has exited; one that ignores SIGTERM is killed after 30 s.
    timeout 30 cat <&"$fd" >>"$work/$name.log" || kill -KILL "${!pid_var}" 2>/dev/null || true
    wait "${!pid_var}" || status=$?
    exec {fd}<&-
    return "$status"
  }
  show() { sed 's/^/    /' "$work/$1.log" | tail -n "${2:-15}" >&2; }

  echo "--- canbridge demo, as uid 10001"
  status=0
  timeout 300 env -i PATH=/usr/local/bin:/usr/bin:/bin \
    "$chroot" --userspec=10001:10001 "$rootfs" canbridge demo >"$work/demo.log" 2>&1 || status=$?
  if ((status != 0)) || ! grep -q "demo OK" "$work/demo.log"; then
    fail "canbridge demo: exit $status, no 'demo OK'"
    show demo
  else
    grep -E "SDO|demo OK" "$work/demo.log" | tail -n 3
  fi

  echo "--- the sample configs load as far as their keys, which no image holds"
  for role in gateway surface; do
    status=0
    timeout 60 env -i PATH=/usr/local/bin:/usr/bin:/bin "$chroot" --userspec=10001:10001 "$rootfs" \
      canbridge "$role" --config "/etc/canbridge/$role.yaml" >"$work/$role-sample.log" 2>&1 ||
      status=$?
    if ((status == 2)) && grep -q "/etc/canbridge/keys/tool-gateway.key" "$work/$role-sample.log"; then
      echo "$role: exit 2, $(grep -m1 -o '[^:]*key_file[^:]*' "$work/$role-sample.log" || echo 'names the key file')"
    else
      fail "canbridge $role --config /etc/canbridge/$role.yaml: exit $status (expected 2 naming /etc/canbridge/keys/tool-gateway.key)"
      show "$role-sample"
    fi
  done

  echo "--- every reference rig in canbridge-sim, on virtual buses"
  for rig in "$rootfs"/etc/canbridge/rigs/*.yaml; do
    name=sim_$(basename "$rig" .yaml)
    start "$name" canbridge-sim "/etc/canbridge/rigs/$(basename "$rig")" --virtual --stats-seconds 0
    if await_line "$name" "canbridge-sim: ready" 60; then
      grep -m1 "canbridge-sim: ready" "$work/$name.log"
    else
      fail "$name: no 'canbridge-sim: ready' within 60 s"
    fi
    status=0
    stop "$name" || status=$?
    ((status == 0)) || { fail "$name: exit $status after SIGTERM"; show "$name"; }
  done

  echo "--- the compose bench rig's configs load (no vcan here: the roles stop at their buses)"
  for role in gateway surface; do
    status=0
    timeout 20 env -i PATH=/usr/local/bin:/usr/bin:/bin "$chroot" --userspec=10001:10001 "$rootfs" \
      canbridge "$role" --config "/etc/canbridge/bench/$role.yaml" >"$work/bench-$role.log" 2>&1 ||
      status=$?
    # Loaded and checked: the plain-mode warning comes after the loader, a config error is exit 2.
    if ((status != 2)) && grep -q "NOT authenticated" "$work/bench-$role.log"; then
      echo "bench $role: config accepted (plain on loopback), then exit $status"
    else
      fail "bench $role config: exit $status, no plain-mode warning"
      show "bench-$role"
    fi
  done
  exit $((failures == 0 ? 0 : 1))
fi

# Inside the vcan rig (tests/rig/vcan_rig.sh: vcan0 and vcan1 exist): the compose file's three
# services, each the command compose would run, as uid 10001 in the image's root filesystem;
# the simulated lab instrument's nodes must reach vcan0 through the gateway and the surface.
if [[ ${1:-} == --run-compose-rig ]]; then
  rootfs=$2 work=$3
  failures=0
  fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }
  # The socket directory on a tmpfs: the rig's guest sees the host's files through hostfs, which
  # holds no Unix sockets.
  mount -t tmpfs -o mode=755,uid=10001,gid=10001 tmpfs "$rootfs/run/canbridge"
  pids=()
  # No process substitution here: the rig's guest has no /dev/fd.
  python3 - "$work/compose.yaml" >"$work/compose-services.txt" <<'PY'
import shlex, sys, yaml
services = yaml.safe_load(open(sys.argv[1]))["services"]
for name in ("surface", "gateway", "modules"):
    s = services[name]
    argv = (s.get("entrypoint") or ["canbridge"]) + [str(a) for a in s.get("command", [])]
    print(name, " ".join(shlex.quote(a) for a in argv), sep="\t")
PY
  while IFS=$'\t' read -r name argv; do
    eval "args=($argv)"
    env -i PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
      "$chroot" --userspec=10001:10001 "$rootfs" "${args[@]}" >"$work/rig-$name.log" 2>&1 &
    pids+=("$name:$!")
    echo "started $name: ${args[*]}"
  done <"$work/compose-services.txt"
  # Heartbeats of the nodes of config/rigs/lab_instrument.yaml (qd 1..6, CiA 301 20) on the
  # surface's bus: they crossed vcan1, the gateway, the backbone and the surface.
  # Node 2 (magnet-supply) sends no heartbeat: the rig gives it `loader: {wait_for_command:
  # true}`, so it waits in its loader until the host starts it (docs/sim-nodes.md).
  want="701 703 704 705 706 714"
  # A 30 s window holds several heartbeats of each node (periods 0.5..2 s). A plain file: FIFOs
  # and /dev/fd do not work across the guest's hostfs.
  timeout 30 candump -L vcan0 >"$work/candump.log" || true
  seen=""
  for id in $want; do
    grep -q " vcan0 $id#" "$work/candump.log" && seen="$seen $id"
  done
  echo "heartbeats on vcan0 from the surface:$seen"
  [[ ${seen# } == "$want" ]] ||
    fail "in 30 s only these of the heartbeats $want reached vcan0:$seen"
  for entry in "${pids[@]}"; do
    name=${entry%%:*} pid=${entry#*:} status=0
    kill -TERM "$pid" 2>/dev/null || true
    wait "$pid" || status=$?
    ((status == 0)) || fail "$name: exit $status after SIGTERM"
  done
  if ((failures)); then
    for f in "$work"/rig-*.log; do echo "--- $f" >&2; tail -n 15 "$f" >&2; done
  fi
  exit $((failures == 0 ? 0 : 1))
fi

src=$(cd "${1:?usage: image_smoke_test.sh SOURCE_DIR [CANBRIDGE CANBRIDGE_SIM LINK_EMULATOR]}" && pwd)
shift
executables=("$@")
case ${#executables[@]} in
  0 | 3) ;;
  *) echo "usage: image_smoke_test.sh SOURCE_DIR [CANBRIDGE CANBRIDGE_SIM LINK_EMULATOR]" >&2; exit 2 ;;
esac
for exe in "${executables[@]}"; do
  [[ -f $exe && -x $exe ]] || { echo "FAIL: no executable $exe (build it first)" >&2; exit 1; }
done
image=${CANBRIDGE_TEST_IMAGE:-localhost/canbridge:smoketest}
skip() {
  echo "SKIPPED: the image smoke test cannot run podman here: $*"
  exit 77
}
[[ $(id -u) -eq 0 ]] || skip "not root (debootstrap, podman image mounts and chroot need root)"
# What only this test needs: installed here, not by tools/install-deps.sh, so that the test
# suite's run (which leaves this test out: tools/test.sh) does not spend minutes installing it.
missing=()
for p in podman debootstrap docker-compose; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "installing ${missing[*]}"
  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
      --no-install-recommends "${missing[@]}"; } >/dev/null || echo "could not install ${missing[*]}"
fi
command -v podman >/dev/null || skip "podman is not installed and could not be installed"
podman info >/dev/null 2>&1 || skip "podman cannot run here: $(podman info 2>&1 | tail -n 1)"

failures=0
fail() { echo "FAIL: $*" >&2; failures=$((failures + 1)); }
work=$(mktemp -d /tmp/canbridge-image-test.XXXXXX)
container=""
cleanup() {
  if [[ -n $container ]]; then
    podman umount "$container" >/dev/null 2>&1 || true
    podman rm -f "$container" >/dev/null 2>&1 || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT

if [[ ${CANBRIDGE_TEST_IMAGE_PREBUILT:-0} == 1 ]]; then
  echo "--- CANBRIDGE_TEST_IMAGE_PREBUILT=1: checking $image as built before"
  podman image exists "$image" || { echo "FAIL: no image $image" >&2; exit 1; }
else
  build_args=()
  if ((${#executables[@]})); then
    # docker/build.sh --prebuilt takes a directory holding the three by their installed names.
    mkdir "$work/bin"
    names=(canbridge canbridge-sim canbridge-link-emulator)
    for i in 0 1 2; do
      ln -s "$(realpath "${executables[i]}")" "$work/bin/${names[i]}"
    done
    build_args=(--prebuilt "$work/bin")
  fi
  echo "--- docker/build.sh ${build_args[*]} (IMAGE=$image), $(uptime)"
  started=$SECONDS
  if ! IMAGE=$image "$src/docker/build.sh" "${build_args[@]}" >"$work/build.log" 2>&1; then
    tail -n 40 "$work/build.log" >&2
    echo "FAIL: docker/build.sh failed (log above)" >&2
    exit 1
  fi
  grep -E "took|built|wait" "$work/build.log"
  echo "build: $((SECONDS - started)) s in all, $(uptime)"
fi

echo "--- no dangling image of ours"
for label in io.canbridge.stage=build org.opencontainers.image.title=canbridge; do
  dangling=$(podman images --quiet --filter dangling=true --filter "label=$label")
  [[ -z $dangling ]] || fail "dangling images labelled $label after docker/build.sh: $dangling"
done

echo "--- image config"
user=$(podman image inspect --format '{{.Config.User}}' "$image")
entrypoint=$(podman image inspect --format '{{.Config.Entrypoint}}' "$image")
echo "user '$user', entrypoint $entrypoint, $(podman image inspect --format '{{.Size}}' "$image" | numfmt --to=iec)B"
[[ $user == canbridge || $user == 10001 ]] || fail "image user is '$user', not canbridge (10001)"
[[ $entrypoint == *canbridge* ]] || fail "image entrypoint is $entrypoint, not canbridge"
# Which stage made it: `runtime` (compiled in the image) says source, `prebuilt` says prebuilt.
origin=$(podman image inspect --format '{{index .Config.Labels "io.canbridge.executables"}}' "$image")
echo "executables: $origin"
if ((${#executables[@]})); then
  [[ $origin == prebuilt ]] || fail "image label io.canbridge.executables is '$origin', not prebuilt"
elif [[ ${CANBRIDGE_TEST_IMAGE_PREBUILT:-0} != 1 ]]; then
  [[ $origin == source ]] || fail "image label io.canbridge.executables is '$origin', not source"
fi

# A container's root filesystem (podman create + mount) is writable, unlike an image mount: the
# surface makes its command endpoint socket in /run/canbridge. Nothing starts the container.
container=$(podman create "$image")
rootfs=$(podman mount "$container")

echo "--- the image's user and files"
passwd=$(grep '^canbridge:' "$rootfs/etc/passwd" || true)
[[ $passwd == canbridge:x:10001:10001:* ]] || fail "no user canbridge with uid 10001: '$passwd'"
ls -l "$rootfs/usr/local/bin"
for exe in canbridge canbridge-sim canbridge-link-emulator; do
  f=$rootfs/usr/local/bin/$exe
  if [[ ! -x $f ]]; then
    fail "/usr/local/bin/$exe is missing"
    continue
  fi
  readelf -S "$f" | grep -q '\.symtab' && fail "/usr/local/bin/$exe is not stripped"
  missing=$(chroot "$rootfs" ldd "/usr/local/bin/$exe" | grep 'not found' || true)
  [[ -z $missing ]] || fail "$exe: libraries missing in the image: $missing"
  # --version is the grammar every executable is getting; --help where a build predates it.
  status=0
  out=$(env -i PATH=/usr/local/bin:/usr/bin:/bin "$chroot" --userspec=10001:10001 "$rootfs" \
    "$exe" --version 2>&1) || status=$?
  if ((status == 0)) && [[ -n $out ]]; then
    echo "$exe --version: $out"
  else
    status=0
    env -i PATH=/usr/local/bin:/usr/bin:/bin "$chroot" --userspec=10001:10001 "$rootfs" \
      "$exe" --help >/dev/null 2>&1 || status=$?
    ((status == 0)) && echo "$exe: no --version yet, --help exits 0" ||
      fail "$exe: neither --version nor --help exits 0 (--help: $status)"
  fi
done
# The prebuilt image holds exactly the executables it was given, stripped (a stale layer cache
# or a wrong build context would put others there).
if ((${#executables[@]})); then
  names=(canbridge canbridge-sim canbridge-link-emulator)
  for i in 0 1 2; do
    strip -o "$work/expected-${names[i]}" "${executables[i]}"
    if cmp -s "$work/expected-${names[i]}" "$rootfs/usr/local/bin/${names[i]}"; then
      echo "${names[i]}: the stripped ${executables[i]}"
    else
      fail "/usr/local/bin/${names[i]} is not the stripped ${executables[i]}"
    fi
  done
fi
for f in gateway.yaml surface.yaml bench/gateway.yaml bench/surface.yaml \
  rigs/demo.yaml rigs/lab_instrument.yaml rigs/tool_string.yaml; do
  [[ -f $rootfs/etc/canbridge/$f ]] || fail "/etc/canbridge/$f is missing"
done

echo "--- no compiler or build tool in the runtime image"
for tool in cc c++ gcc g++ cpp clang clang++ ld as cmake ninja make; do
  [[ -e $rootfs/usr/bin/$tool || -e $rootfs/usr/local/bin/$tool ]] && fail "the image has $tool"
done
# gcc-12-base is libstdc++'s and libgcc's base package, not a compiler.
dev_packages=$(chroot "$rootfs" dpkg-query -W -f '${Package}\n' | grep -v -- '-base$' |
  grep -E '^(gcc|g\+\+|cpp|clang|llvm|cmake|ninja-build|binutils|make)($|-)|-dev$' || true)
[[ -z $dev_packages ]] || fail "build packages in the image: $(echo $dev_packages)"
echo "$(chroot "$rootfs" dpkg-query -W -f '${Package}\n' | wc -l) packages, none of them a compiler or -dev"

echo "--- docker/compose.yaml"
if command -v docker-compose >/dev/null; then
  # The Compose schema, without a daemon; the normalised file is what the checks below read.
  if CANBRIDGE_IMAGE=$image docker-compose -f "$src/docker/compose.yaml" config >"$work/compose.yaml" 2>"$work/compose.err"; then
    echo "docker-compose config: valid"
  else
    fail "docker-compose config: $(cat "$work/compose.err")"
    cp "$src/docker/compose.yaml" "$work/compose.yaml"
  fi
else
  echo "docker-compose not installed: YAML checks only"
  cp "$src/docker/compose.yaml" "$work/compose.yaml"
fi
# What the rig relies on: host networking, the three roles, each command's executable and every
# /etc/canbridge path it names present in the image.
if ! python3 - "$work/compose.yaml" "$rootfs" <<'EOF'; then
import os, sys, yaml
compose, rootfs = yaml.safe_load(open(sys.argv[1])), sys.argv[2]
problems = []
services = compose.get("services", {})
if set(services) != {"surface", "gateway", "modules"}:
    problems.append(f"services {sorted(services)}, expected surface, gateway, modules")
for name, s in services.items():
    if s.get("network_mode") != "host":
        problems.append(f"{name}: network_mode is not host")
    if s.get("privileged"):
        problems.append(f"{name}: privileged")
    argv = (s.get("entrypoint") or ["canbridge"]) + s.get("command", [])
    if not os.access(f"{rootfs}/usr/local/bin/{argv[0]}", os.X_OK):
        problems.append(f"{name}: {argv[0]} is not in the image")
    for arg in argv:
        if str(arg).startswith("/etc/canbridge/") and not os.path.isfile(rootfs + arg):
            problems.append(f"{name}: {arg} is not in the image")
for p in problems:
    print("compose:", p)
sys.exit(1 if problems else 0)
EOF
  fail "docker/compose.yaml does not fit the image (above)"
fi

echo "--- the executables at work, as uid 10001, in a private network namespace"
unshare --net -- "$0" --run-in-netns "$rootfs" "$work" || fail "the runs above"

echo "--- the compose rig's services on vcan0 and vcan1 (tests/rig/vcan_rig.sh)"
"$src/tests/rig/vcan_rig.sh" --vcan 2 --timeout 300 -- "$0" --run-compose-rig "$rootfs" "$work" ||
  fail "the compose rig on vcan (above)"

if ((failures)); then
  echo "image smoke test: $failures failure(s)" >&2
  exit 1
fi
echo "image smoke test: OK ($image)"
