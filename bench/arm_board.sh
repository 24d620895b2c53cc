#!/usr/bin/env bash
# Issue 18's memory figures on a real ARM Linux kernel: the gateway's RSS at idle and under load,
# for armhf and arm64, without a board. qemu-user cannot give them (its RSS is qemu's own), so
# this boots Debian's own ARM kernel in qemu-system (TCG emulation) with a small initramfs holding
# busybox, the CAN modules, the cross-built canbridge with its libraries, can-utils and the
# shipped sample configs, and reads /proc/PID/status of the gateway and the surface in there.
#
#   bench/arm_board.sh ARCH [BUILD_DIR]      ARCH: armhf or arm64; BUILD_DIR: build-ARCH, a tree
#                                            of tools/cross-build.sh ARCH (uses its app/canbridge)
#
# Run as root on Debian 12: installs qemu-system-arm (qemu-system-arm and -aarch64) and cpio, runs
# tools/install-cross-deps.sh ARCH (cross binutils, the target's libraries in
# /opt/canbridge-sysroot/ARCH), and fetches the kernel (linux-image-*-armmp, which boots on
# `-M virt`, or linux-image-*-arm64), busybox-static and can-utils of ARCH with `apt-get download`,
# unpacked with `dpkg-deb -x` into a temporary folder: nothing of ARCH is installed on the host.
#
# The guest mirrors bench/speed_bench.sh's four-bus scenario: vcan0 (surface) and vcan1..vcan4
# (modules 1, 2, 0, 3), config/gateway.yaml and config/surface.yaml as shipped plus the lines
# four_bus_configs (bench/rig_common.sh) adds. The guest has a filesystem of its own, so the
# shipped key path (/etc/canbridge/keys/) and command socket (/run/canbridge/surface.sock) are
# used unchanged; the psk key is made with openssl per run. Steps: surface and gateway started,
# connected (their "ready" log lines), CANBRIDGE_ARM_IDLE_SECONDS idle, then VmRSS read; then
# cangen sends TPDO 0x181 on each module bus and RPDO 0x221 (surface node 33, module 1's node 1)
# on the surface bus, one frame per CANBRIDGE_ARM_GAP_MS each (0.125: speed_bench's nominal 8
# frames per ms per bus; the emulated CPU reaches less, the rate reached is printed), for
# CANBRIDGE_ARM_LOAD_SECONDS; VmRSS and VmHWM are read at its end, then both are stopped and their
# final stats lines prove the frames crossed.
#
# Environment (defaults): CANBRIDGE_ARM_LOAD_SECONDS (20), CANBRIDGE_ARM_GAP_MS (0.125, cangen -g),
# CANBRIDGE_ARM_IDLE_SECONDS (10), CANBRIDGE_ARM_SMP (2), CANBRIDGE_ARM_MEM (512M),
# CANBRIDGE_ARM_TIMEOUT (1200 s for the whole boot), CANBRIDGE_ARM_KEEP=1 (keep the work folder).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
# shellcheck source=bench/rig_common.sh
source "$root/bench/rig_common.sh"
arch=${1:-}
case $arch in
  armhf)
    triplet=arm-linux-gnueabihf flavour=armmp qemu=qemu-system-arm
    # highmem=off: a 32-bit kernel without LPAE cannot reach RAM or devices above 4 GiB.
    machine=(-M "virt,highmem=off" -cpu cortex-a15) ;;
  arm64)
    triplet=aarch64-linux-gnu flavour=arm64 qemu=qemu-system-aarch64
    # cortex-a72 (a Raspberry Pi 4's core) rather than 'max': TCG emulates pointer
    # authentication slowly, and nothing here depends on the core.
    machine=(-M virt -cpu cortex-a72) ;;
  *) echo "usage: $0 armhf|arm64 [BUILD_DIR]" >&2; exit 2 ;;
esac
build=$(cd "${2:-$root/build-$arch}" && pwd)
canbridge=$build/app/canbridge
[[ -x $canbridge ]] || { echo "arm_board: $canbridge is missing (tools/cross-build.sh $arch)" >&2; exit 1; }
load_seconds=${CANBRIDGE_ARM_LOAD_SECONDS:-20}
gap_ms=${CANBRIDGE_ARM_GAP_MS:-0.125}
idle_seconds=${CANBRIDGE_ARM_IDLE_SECONDS:-10}
smp=${CANBRIDGE_ARM_SMP:-2}
mem=${CANBRIDGE_ARM_MEM:-512M}
boot_timeout=${CANBRIDGE_ARM_TIMEOUT:-1200}
sysroot=${CANBRIDGE_SYSROOT_BASE:-/opt/canbridge-sysroot}/$arch

# ---- host tools ----
sudo=""
[[ $(id -u) -ne 0 ]] && sudo=sudo
missing=()
for p in qemu-system-arm cpio openssl; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "arm_board: installing ${missing[*]}"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
# The cross binutils (strip, readelf) and the sysroot the libraries come from; a no-op when done.
"$root/tools/install-cross-deps.sh" "$arch"

work=$(mktemp -d "${TMPDIR:-/tmp}/canbridge-arm-board.XXXXXX")
cleanup() {
  if [[ -n ${CANBRIDGE_ARM_KEEP:-} ]]; then echo "arm_board: kept $work"; else rm -rf "$work"; fi
}
trap cleanup EXIT

# ---- ARCH packages, unpacked only ----
# The kernel is whatever linux-image-FLAVOUR (the metapackage) depends on now.
kernel_pkg=$(apt-cache depends "linux-image-$flavour:$arch" 2>/dev/null |
  awk '/Depends: linux-image-/ {sub(/:.*/, "", $2); print $2; exit}')
if [[ -z $kernel_pkg ]]; then
  $sudo apt-get update -qq
  kernel_pkg=$(apt-cache depends "linux-image-$flavour:$arch" |
    awk '/Depends: linux-image-/ {sub(/:.*/, "", $2); print $2; exit}')
fi
mkdir -p "$work/debs" "$work/pkg"
chmod 755 "$work" "$work/debs"
# apt-get download runs as the _apt user where it can; the folder must be writable for it.
chown _apt "$work/debs" 2>/dev/null || true
(cd "$work/debs" && apt-get download -qq "$kernel_pkg:$arch" "busybox-static:$arch" "can-utils:$arch")
for deb in "$work"/debs/*.deb; do dpkg-deb -x "$deb" "$work/pkg"; done
kernel_version=$(dpkg-deb -f "$work"/debs/linux-image-*.deb Version)
kernel_release=${kernel_pkg#linux-image-}
vmlinuz=$work/pkg/boot/vmlinuz-$kernel_release
modules=$work/pkg/lib/modules/$kernel_release/kernel

# ---- initramfs ----
rootfs=$work/rootfs
mkdir -p "$rootfs"/{bin,sbin,usr/bin,usr/sbin,lib,proc,sys,dev,tmp,run,mods,bench}
mkdir -p "$rootfs/etc/canbridge/keys" "$rootfs/lib/$triplet"
cp "$work/pkg/bin/busybox" "$rootfs/bin/busybox"
cp "$work/pkg/usr/bin/cangen" "$work/pkg/usr/bin/candump" "$rootfs/usr/bin/"
# What a board runs (installed packages are stripped); its size is part of the table.
"$triplet-strip" -o "$rootfs/usr/bin/canbridge" "$canbridge"
stripped_bytes=$(stat -c %s "$rootfs/usr/bin/canbridge")

# CAN modules and what they depend on (modinfo reads a foreign architecture's .ko too); Debian
# may ship them compressed, which busybox's insmod does not take, so they go in uncompressed.
add_module() {
  local name=$1 file dep
  [[ -e $rootfs/mods/$name.ko ]] && return
  file=$(find "$modules" -name "$name.ko" -o -name "$name.ko.xz" -o -name "$name.ko.zst" \
    -o -name "$name.ko.gz" | head -1)
  [[ -n $file ]] || { echo "arm_board: module $name not in $kernel_pkg" >&2; exit 1; }
  case $file in
    *.xz) xz -dc "$file" >"$rootfs/mods/$name.ko" ;;
    *.zst) zstd -qdc "$file" >"$rootfs/mods/$name.ko" ;;
    *.gz) gzip -dc "$file" >"$rootfs/mods/$name.ko" ;;
    *) cp "$file" "$rootfs/mods/$name.ko" ;;
  esac
  for dep in $(modinfo -F depends "$rootfs/mods/$name.ko" | tr ',' ' '); do
    add_module "$dep"
    echo "$dep" >>"$rootfs/mods/order.$name"
  done
}
for m in can can-raw vcan; do add_module "$m"; done
# Load order: dependencies first (insmod does not resolve them).
module_order() {
  local name=$1 dep
  if [[ -f $rootfs/mods/order.$name ]]; then
    while read -r dep; do module_order "$dep"; done <"$rootfs/mods/order.$name"
  fi
  grep -qx "$name" "$work/order" 2>/dev/null || echo "$name" >>"$work/order"
}
for m in can can-raw vcan; do module_order "$m"; done
rm -f "$rootfs"/mods/order.*

# Shared libraries, recursively: the cross compiler's libc and libstdc++ (/usr/TRIPLET/lib) and
# the sysroot's Debian packages, all into /lib/TRIPLET, where Debian's loader looks first.
lib_dirs=("/usr/$triplet/lib" "$sysroot/usr/lib/$triplet" "$sysroot/lib/$triplet")
add_libs() {
  local needed dir found
  for needed in $("$triplet-readelf" -d "$1" | awk '/\(NEEDED\)/ {gsub(/[][]/, "", $5); print $5}'); do
    [[ -e $rootfs/lib/$triplet/$needed ]] && continue
    found=
    for dir in "${lib_dirs[@]}"; do
      if [[ -e $dir/$needed ]]; then found=$dir/$needed; break; fi
    done
    [[ -n $found ]] || { echo "arm_board: $needed (needed by $1) not found in ${lib_dirs[*]}" >&2; exit 1; }
    cp -L "$found" "$rootfs/lib/$triplet/$needed"
    add_libs "$rootfs/lib/$triplet/$needed"
  done
}
for exe in canbridge cangen candump; do add_libs "$rootfs/usr/bin/$exe"; done
for exe in canbridge cangen candump; do
  interp=$("$triplet-readelf" -l "$rootfs/usr/bin/$exe" | sed -n 's/.*program interpreter: \(.*\)]/\1/p')
  if [[ -n $interp ]]; then  # empty for a static executable
    mkdir -p "$rootfs$(dirname "$interp")"
    cp -L "/usr/$triplet/lib/$(basename "$interp")" "$rootfs$interp"
  fi
done

# The shipped configs; only the four-bus lines speed_bench.sh also adds (rig_common.sh).
four_bus_configs "$root/config" "$rootfs/bench"
echo "arm_board: config lines changed from config/*.yaml (< shipped, > used):"
for r in gateway surface; do
  diff "$root/config/$r.yaml" "$rootfs/bench/$r.yaml" | grep '^[<>]' | sed "s|^|  $r.yaml: |" || true
done
(umask 077 && openssl rand -hex 32 >"$rootfs/etc/canbridge/keys/tool-gateway.key")

cat >"$rootfs/init" <<INIT
#!/bin/busybox sh
# PID 1 of the guest: the scenario, then power off. Results are "arm_board: KEY=VALUE" lines.
/bin/busybox --install -s
export PATH=/usr/bin:/usr/sbin:/bin:/sbin LD_LIBRARY_PATH=/lib/$triplet
mount -t proc proc /proc; mount -t sysfs sysfs /sys; mount -t devtmpfs devtmpfs /dev
mount -t tmpfs tmpfs /tmp; mount -t tmpfs tmpfs /run; mkdir -p /run/canbridge
say() { echo "arm_board: \$*"; }
finish() { say "status=\$1"; sync; poweroff -f; }
say "init_uptime=\$(cut -d' ' -f1 /proc/uptime)"
say "kernel=\$(uname -r) \$(uname -m)"
say "cpus=\$(grep -c ^processor /proc/cpuinfo) mem_total_kb=\$(awk '/^MemTotal:/ {print \$2}' /proc/meminfo)"
for m in $(tr '\n' ' ' <"$work/order"); do insmod /mods/\$m.ko || { say "insmod \$m failed"; finish 1; }; done
ip link set lo up
for i in 0 1 2 3 4; do ip link add dev vcan\$i type vcan && ip link set vcan\$i up || finish 1; done

# wait_line LOG TEXT PID: bounded wait for a line (the emulated CPU is slow: up to 240 s), given
# up at once when PID has exited.
wait_line() {
  n=0
  until grep -q -- "\$2" "\$1" 2>/dev/null; do
    n=\$((n + 1))
    if [ \$n -gt 4800 ] || ! kill -0 \$3 2>/dev/null; then
      say "gave up waiting for '\$2' in \$1"; tail -20 "\$1"; finish 1
    fi
    sleep 0.05
  done
}
status() { awk -v k="\$2:" '\$1 == k {print \$2}' /proc/\$1/status; }
# Where the resident memory is: heap and stacks (RssAnon) against mapped files (RssFile; here
# RssShmem, since the initramfs is a tmpfs: on a board's disk they would count as RssFile).
mem_split() { awk '/^Rss(Anon|File|Shmem):/ {printf "%s%s ", \$1, \$2}' /proc/\$1/status; }

t0=\$(cut -d' ' -f1 /proc/uptime)
canbridge surface --config /bench/surface.yaml >/tmp/surface.log 2>&1 &
spid=\$!
wait_line /tmp/surface.log listening \$spid
canbridge gateway --config /bench/gateway.yaml >/tmp/gateway.log 2>&1 &
gpid=\$!
wait_line /tmp/surface.log "gateway 'tool-gateway' ready" \$spid
wait_line /tmp/gateway.log "ready over" \$gpid
say "connected_after_s=\$(awk -v a=\$t0 -v b=\$(cut -d' ' -f1 /proc/uptime) 'BEGIN{print b - a}')"
# Idle: connected, keepalives only, before any frame.
sleep $idle_seconds
say "gw_idle_rss_kb=\$(status \$gpid VmRSS) gw_idle_hwm_kb=\$(status \$gpid VmHWM) sf_idle_rss_kb=\$(status \$spid VmRSS)"
say "gw_idle_split_kb=\$(mem_split \$gpid)"

t1=\$(cut -d' ' -f1 /proc/uptime)
pids=""
for bus in vcan1 vcan2 vcan3 vcan4; do
  cangen \$bus -g $gap_ms -I 181 -L 8 -D i & pids="\$pids \$!"
done
cangen vcan0 -g $gap_ms -I 221 -L 8 -D i & pids="\$pids \$!"
sleep $load_seconds
# Still running means no cangen gave up (one that did printed why on the console).
for p in \$pids; do kill -0 \$p 2>/dev/null || say "a cangen exited early"; done
say "gw_load_rss_kb=\$(status \$gpid VmRSS) gw_load_hwm_kb=\$(status \$gpid VmHWM) sf_load_rss_kb=\$(status \$spid VmRSS) sf_load_hwm_kb=\$(status \$spid VmHWM)"
say "gw_load_split_kb=\$(mem_split \$gpid)"
# Which mappings hold it: the executable, each library, the heap ([anon] and [heap]), stacks.
say "gw_load_rss_by_mapping_kb=\$(awk '\$1 ~ /^[0-9a-f]+-[0-9a-f]+\$/ {n = NF >= 6 ? \$6 : "[anon]"; sub(/.*\//, "", n)}
  \$1 == "Rss:" {kb[n] += \$2} END {for (n in kb) if (kb[n] >= 64) print n ":" kb[n]}' /proc/\$gpid/smaps |
  sort -t: -k2 -rn | tr '\n' ' ')"
kill \$pids; wait \$pids 2>/dev/null
t2=\$(cut -d' ' -f1 /proc/uptime)
say "load_s=\$(awk -v a=\$t1 -v b=\$t2 'BEGIN{print b - a}')"
# Drained when the frames written by the surface to vcan0 and by the gateway to vcan1 stopped
# changing for a second (bounded): at a rate the emulated CPU cannot carry, the sockets and the
# queues still hold frames when cangen stops, and stopping then would count them as lost.
written() { cat /sys/class/net/vcan0/statistics/tx_packets /sys/class/net/vcan1/statistics/tx_packets; }
prev=""; n=0
while cur=\$(written | tr '\n' ' '); [ "\$cur" != "\$prev" ] && [ \$n -lt 120 ]; do
  prev=\$cur; n=\$((n + 1)); sleep 1
done
say "drained_after_s=\$n"
kill -TERM \$gpid \$spid
wait \$gpid; wait \$spid
say "gw_stats=\$(grep 'gateway tool-gateway:' /tmp/gateway.log | tail -1)"
say "sf_stats=\$(grep 'surface surface:' /tmp/surface.log | tail -1)"
# Warnings and errors of either process (spdlog's level is the third field).
awk '\$3 == "warning" || \$3 == "error" || \$3 == "critical"' /tmp/gateway.log /tmp/surface.log |
  head -10 | sed 's/^/arm_board: log: /'
finish 0
INIT
chmod 755 "$rootfs/init"
# Owned by root in the guest: canbridge refuses a key file owned by another user.
(cd "$rootfs" && find . | cpio -o -H newc -R 0:0 --quiet | gzip -1 >"$work/initrd.gz")

# ---- boot ----
qemu_version=$("$qemu" --version | head -1)
echo "arm_board: $arch, $kernel_pkg $kernel_version, $qemu_version, -smp $smp -m $mem," \
  "initramfs $(stat -c %s "$work/initrd.gz") bytes, load $load_seconds s at -g $gap_ms ms"
start=$(date +%s.%N)
rc=0
# No network: the default virtio NIC wants ipxe ROMs (not installed) and nothing needs it.
timeout --kill-after=10 "$boot_timeout" "$qemu" "${machine[@]}" -smp "$smp" -m "$mem" -nographic \
  -no-reboot -nic none -kernel "$vmlinuz" -initrd "$work/initrd.gz" \
  -append "console=ttyAMA0 rdinit=/init panic=-1 loglevel=4" \
  </dev/null >"$work/console.log" 2>&1 || rc=$?
wall=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN{printf "%.0f", b - a}')
tr -d '\r' <"$work/console.log" >"$work/console.txt"
get() { grep -o "arm_board: .*\b$1=[^ ]*" "$work/console.txt" | tail -1 | sed "s/.*\b$1=//"; }
if [[ $(get status) != 0 ]]; then
  echo "arm_board: the guest did not finish (qemu exit $rc after $wall s; timeout $boot_timeout s)" >&2
  tail -40 "$work/console.txt" >&2
  exit 1
fi
grep '^arm_board: ' "$work/console.txt"
forwarded() {  # forwarded STATS_KEY WORD: the number after WORD in a stats line
  grep -o "arm_board: $1=.*" "$work/console.txt" | tail -1 | grep -o "$2 [0-9]*" | head -1 | awk '{print $NF}'
}
mb() { awk -v k="$1" 'BEGIN{printf "%.1f", k / 1024}'; }
echo
echo "arm_board: $arch in qemu-system ($qemu_version), kernel $(get kernel) ($kernel_pkg" \
  "$kernel_version), $smp CPUs, wall $wall s, init at $(get init_uptime) s of uptime"
printf '| %s | %s | %s | %s | %s | %s | %s | %s | %s |\n' arch kernel "stripped B" \
  "gw RSS idle MB" "gw RSS load MB" "gw VmHWM MB" "sf RSS idle / load / HWM MB" \
  "gw bus->backbone / sf backbone->bus" "sf bus->backbone / gw backbone->bus"
printf '| %s | %s | %s | %s | %s | %s | %s | %s | %s |\n' "$arch" "$(get kernel)" "$stripped_bytes" \
  "$(mb "$(get gw_idle_rss_kb)")" "$(mb "$(get gw_load_rss_kb)")" "$(mb "$(get gw_load_hwm_kb)")" \
  "$(mb "$(get sf_idle_rss_kb)") / $(mb "$(get sf_load_rss_kb)") / $(mb "$(get sf_load_hwm_kb)")" \
  "$(forwarded gw_stats 'bus->backbone') / $(forwarded sf_stats 'backbone->bus')" \
  "$(forwarded sf_stats 'bus->backbone') / $(forwarded gw_stats 'backbone->bus')"
echo "load: cangen -g $gap_ms on vcan1..4 (0x181) and vcan0 (0x221) for $(get load_s) s;" \
  "gateway bus->backbone $(awk -v f="$(forwarded gw_stats 'bus->backbone')" -v s="$(get load_s)" \
    'BEGIN{printf "%.0f", f / s}') frames/s"
# A run is only as good as its link: an emulated guest starved by a busy host misses the
# keepalives (dead_after_ms 2000 as shipped), and a dropped link or frames missing at the far
# end mean the load did not cross as measured. Say so, and fail.
doubts=()
[[ $(forwarded gw_stats 'bus->backbone') == "$(forwarded sf_stats 'backbone->bus')" ]] ||
  doubts+=("module frames missing at the surface")
[[ $(forwarded sf_stats 'bus->backbone') == "$(forwarded gw_stats 'backbone->bus')" ]] ||
  doubts+=("surface frames missing at the gateway")
grep -q '^arm_board: log: ' "$work/console.txt" && doubts+=("warnings in the logs (above)")
if ((${#doubts[@]})); then
  echo "arm_board: doubtful run: $(IFS=';'; echo "${doubts[*]}") (a busy host starves the guest)" >&2
  exit 3
fi
