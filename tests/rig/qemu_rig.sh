#!/usr/bin/env bash
# The real-kernel vcan rig: runs one command under Debian's own amd64 kernel in qemu-system, where
# real SocketCAN vcan interfaces vcan0..vcan<N-1> exist, and returns that command's real exit
# status and output. Same calling convention as tests/rig/vcan_rig.sh (user-mode Linux), but the
# guest is a real x86-64 kernel: system calls and clock_gettime cost about 1 us instead of ~65 us,
# so timings measured in it are closer to a board's.
#
# Usage: qemu_rig.sh [--vcan N] [--mem SIZE] [--timeout SECONDS] -- COMMAND [ARGS...]
#   --vcan N        interfaces to create (default 3)
#   --mem SIZE      guest memory (default 1G)
#   --timeout S     kill the guest after S seconds (default 600)
# Environment variables named GTEST_*, CANBRIDGE_*, ASAN_*, UBSAN_*, LSAN_* (and HOME, TERM)
# reach the command, which runs as root in the caller's working directory. Its stdout and stderr
# come back merged on stdout (as from vcan_rig.sh), while it runs.
# Rig settings: CANBRIDGE_RIG_SMP (guest CPUs, 2), CANBRIDGE_RIG_ACCEL (kvm or tcg; default kvm
# where /dev/kvm is writable and the CPU shows vmx or svm, else tcg), CANBRIDGE_RIG_CACHE (the
# kernel cache folder; /var/cache/canbridge-rig for root), CANBRIDGE_RIG_REFRESH_DAYS (7: how old
# the cached kernel may get before apt is asked whether Debian has a newer one),
# CANBRIDGE_RIG_VERBOSE=1 (boot times, accelerator and the guest's log on stderr),
# CANBRIDGE_RIG_KEEP=1 (keep this run's folder), CANBRIDGE_RIG_APPEND (more kernel parameters).
#
# How: on first use it installs qemu-system-x86, busybox-static, cpio, kmod and xz-utils
# (apt-get), fetches Debian's current linux-image-*-amd64 for this release with `apt-get download`
# into the cache (checked against apt's SHA256), extracts only the kernel and the module folders a
# CAN rig needs, runs depmod over them, unpacks the ELF kernel from vmlinuz (qemu boots it by its
# PVH entry: the bzImage's decompressor alone takes ~10 s under TCG), and builds a small busybox
# initramfs holding the virtio, 9p, rng and CAN modules (vcan, can, can-raw, can-gw, can-bcm,
# can-dev), in the order modules.dep gives. Later runs reuse all of it.
# In the guest, the initramfs loads them, mounts the host's root over 9p (-virtfs), mounts proc,
# sys, dev, a tmpfs /run and a tmpfs /tmp in it, creates the interfaces and switches into it, so
# the command runs the host's own programs. Everything up to the command is done by the
# initramfs's busybox, which is in memory: under TCG each first start of a program from the host
# costs a fraction of a second. The kernel's modprobe (and `modprobe` on PATH) reads the cached
# module tree, so what the kernel asks for later (sch_tbf for `tc`, ...) loads too.
# /tmp is a tmpfs of the guest's own: Unix sockets cannot live on 9p, and two rigs under
# `ctest -j2` do not share one; the /tmp folders the working directory or an argument lie in are
# bound back in, and the whole host /tmp stays reachable at /run/canbridge-rig/host-tmp. Output
# and exit status travel through a second, uncached 9p share of this run's own folder.
set -euo pipefail

vcan_count=3
mem=1G
timeout_s=600
while [[ $# -gt 0 ]]; do
  case "$1" in
    --vcan) vcan_count=$2; shift 2 ;;
    --mem) mem=$2; shift 2 ;;
    --timeout) timeout_s=$2; shift 2 ;;
    --) shift; break ;;
    *) echo "qemu_rig: unknown option '$1'" >&2; exit 2 ;;
  esac
done
if [[ $# -eq 0 ]]; then
  echo "usage: qemu_rig.sh [--vcan N] [--mem SIZE] [--timeout S] -- COMMAND [ARGS...]" >&2
  exit 2
fi
smp=${CANBRIDGE_RIG_SMP:-2}
refresh_days=${CANBRIDGE_RIG_REFRESH_DAYS:-7}
verbose=${CANBRIDGE_RIG_VERBOSE:-0}
say() { echo "qemu_rig: $*" >&2; }
sudo=""
[[ $(id -u) -ne 0 ]] && sudo=sudo

# ---- host tools ----
# One apt at a time: tools/test.sh's background jobs take the same lock, and two rigs started
# together by ctest -j2 on a fresh machine would otherwise both run apt-get.
apt_lock=/tmp/canbridge-apt.lock
apt_install() {
  local p missing=()
  exec 8>"$apt_lock"
  flock 8
  for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if ((${#missing[@]})); then
    say "installing ${missing[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
      -o DPkg::Lock::Timeout=600 "${missing[@]}" >&2
  fi
  exec 8>&-
}
if ! command -v qemu-system-x86_64 >/dev/null || [[ ! -x /bin/busybox ]] ||
  ! command -v cpio >/dev/null || ! command -v depmod >/dev/null || ! command -v xz >/dev/null; then
  apt_install qemu-system-x86 busybox-static cpio kmod xz-utils
fi
# Debian's busybox package (not -static) puts a dynamic busybox in /bin; the initramfs has no
# libraries, so it must be the static one (ldd refuses a static executable).
if ldd /bin/busybox >/dev/null 2>&1; then
  apt_install busybox-static
  ldd /bin/busybox >/dev/null 2>&1 && { say "/bin/busybox is not static (busybox-static)"; exit 1; }
fi

# ---- the kernel, fetched once ----
# In the initramfs, with what they depend on: the guest's devices and the CAN stack the rig is for.
initramfs_modules=(virtio_pci virtio_rng 9pnet_virtio 9p can can_raw can_gw can_bcm can_dev vcan)
cache=${CANBRIDGE_RIG_CACHE:-}
if [[ -z $cache ]]; then
  if [[ $(id -u) -eq 0 ]]; then cache=/var/cache/canbridge-rig
  else cache=${XDG_CACHE_HOME:-$HOME/.cache}/canbridge-rig; fi
fi
mkdir -p "$cache"
# The whole preparation under one lock: ctest -j2 starts rigs together.
exec 9>"$cache/lock"
flock 9

# kernel_valid DIR: the extracted tree is whole: its stamp, written last, names vmlinuz's SHA256
# and the unpacked vmlinux's size (hashing that 65 MB on every run would cost more than a check).
kernel_valid() {
  local dir=$1 want size
  [[ -f $dir/stamp && -x $dir/bin/modprobe ]] || return 1
  want=$(awk '$1 == "vmlinuz_sha256" {print $2}' "$dir/stamp")
  size=$(awk '$1 == "vmlinux_bytes" {print $2}' "$dir/stamp")
  [[ -n $want && $(sha256sum <"$dir/vmlinuz" | cut -d' ' -f1) == "$want" ]] || return 1
  [[ $size == none || $(stat -c %s "$dir/vmlinux" 2>/dev/null) == "$size" ]]
}

# apt's current kernel package and version for this release ("" when apt cannot say: no lists).
apt_kernel() {
  local pkg ver
  pkg=$(apt-cache depends linux-image-amd64 2>/dev/null |
    awk '/Depends: linux-image-/ {sub(/:.*/, "", $2); print $2; exit}')
  [[ -n $pkg ]] || return 0
  ver=$(apt-cache show --no-all-versions "$pkg" 2>/dev/null | awk '/^Version:/ {print $2; exit}')
  if [[ -n $ver ]]; then echo "$pkg $ver"; fi
}

# missing_deps ROOT RELEASE MODULE...: the modules named, or depended on by them (each .ko's own
# "depends", written by the kernel build), that are not in the extracted tree; with Debian's
# placeholder System.map depmod cannot report a missing dependency itself.
missing_deps() {
  local root=$1 release=$2 seen=" " m dep
  local queue=("${@:3}")
  while ((${#queue[@]})); do
    m=${queue[0]//-/_}
    queue=("${queue[@]:1}")
    [[ $seen == *" $m "* ]] && continue
    seen+="$m "
    if ! dep=$(modinfo -b "$root" -k "$release" -F depends "$m" 2>/dev/null); then
      echo "$m"
      continue
    fi
    # shellcheck disable=SC2206  # a comma-separated list
    [[ -n $dep ]] && queue+=(${dep//,/ })
  done
}

# fetch_kernel PKG VERSION: download (or reuse the cached .deb), check, extract, depmod,
# initramfs; into $cache/PKG_VERSION.
fetch_kernel() {
  local pkg=$1 ver=$2 dest=$cache/$1_$2 tmp deb want release missing
  want=$(apt-cache show "$pkg=$ver" 2>/dev/null | awk '/^SHA256:/ {print $2; exit}')
  [[ -n $want ]] || { say "apt has no SHA256 for $pkg $ver"; return 1; }
  mkdir -p "$cache/debs"
  deb=$cache/debs/${pkg}_${ver//:/%3a}_amd64.deb
  if [[ ! -f $deb || $(sha256sum <"$deb" | cut -d' ' -f1) != "$want" ]]; then
    tmp=$(mktemp -d "$cache/download.XXXXXX")
    # apt-get download runs as the _apt user where it can: the folder must be writable for it.
    chmod 755 "$tmp"
    chown _apt "$tmp" 2>/dev/null || true
    say "fetching $pkg $ver (once; cached in $cache)"
    if ! (cd "$tmp" && apt-get download -qq "$pkg=$ver") >&2 ||
      [[ $(sha256sum <"$tmp/$(basename "$deb")" | cut -d' ' -f1) != "$want" ]]; then
      say "could not fetch $pkg $ver with apt's SHA256 $want"
      rm -rf "$tmp"
      return 1
    fi
    mv "$tmp/$(basename "$deb")" "$deb"
    rm -rf "$tmp"
  fi
  tmp=$(mktemp -d "$cache/new.XXXXXX")
  # Called as a condition (errexit does not apply here): each step checks for itself.
  give_up() { say "$1"; rm -rf "$tmp"; return 1; }
  mkdir "$tmp/root"
  # Only what a CAN rig needs of the ~400 MB (~85 MB): the kernel, the module lists, and the
  # module folders of networking (CAN, can-gw, qdiscs, ...), the virtual network devices (not the
  # hardware drivers below them), virtio, 9p and what they link against.
  dpkg-deb --fsys-tarfile "$deb" | tar -x -C "$tmp/root" --wildcards --no-wildcards-match-slash \
    './boot/vmlinuz-*' './lib/modules/*/modules.order' './lib/modules/*/modules.builtin' \
    './lib/modules/*/modules.builtin.modinfo' \
    './lib/modules/*/kernel/net/*' './lib/modules/*/kernel/drivers/net/can/*' \
    './lib/modules/*/kernel/drivers/virtio/*' './lib/modules/*/kernel/drivers/char/hw_random/*' \
    './lib/modules/*/kernel/fs/9p/*' './lib/modules/*/kernel/fs/netfs/*' \
    './lib/modules/*/kernel/fs/fscache/*' './lib/modules/*/kernel/crypto/*' \
    './lib/modules/*/kernel/lib/*' './lib/modules/*/kernel/drivers/net/*.ko*' ||
    { give_up "$deb: not the layout this rig knows (boot/vmlinuz-*, lib/modules/*/kernel/...)"; return 1; }
  release=${pkg#linux-image-}
  mv "$tmp/root/boot/vmlinuz-$release" "$tmp/vmlinuz" || { give_up "no vmlinuz-$release"; return 1; }
  # The bzImage's own decompressor takes ~10 s under TCG; qemu boots the uncompressed ELF
  # inside it directly (its PVH entry point), so it is unpacked here once (as the kernel's
  # scripts/extract-vmlinux does: from the xz stream's magic on).
  local offset
  offset=$(LC_ALL=C grep -obUaP '\xfd7zXZ\x00' "$tmp/vmlinuz" | head -1 | cut -d: -f1)
  # (tail through a process substitution: xz stops reading at the stream's end, and tail's
  # SIGPIPE must not fail the command under pipefail.)
  if [[ -n $offset ]] &&
    xz -dc --single-stream < <(tail -c +$((offset + 1)) "$tmp/vmlinuz") >"$tmp/vmlinux" 2>/dev/null &&
    [[ $(head -c 4 "$tmp/vmlinux" | od -An -c | tr -d ' ') == 177ELF ]]; then
    :
  else
    say "could not unpack the ELF kernel from vmlinuz: booting the bzImage (slower)"
    rm -f "$tmp/vmlinux"
  fi
  depmod -b "$tmp/root" "$release" || { give_up "depmod failed"; return 1; }
  missing=$(missing_deps "$tmp/root" "$release" "${initramfs_modules[@]}" sch_tbf)
  [[ -z $missing ]] ||
    { give_up "not in the extracted part of $pkg: $(echo "$missing" | tr '\n' ' ')"; return 1; }
  # modprobe for the guest (the kernel's and PATH's): the cached tree as its root.
  mkdir "$tmp/bin"
  printf '#!/bin/sh\n# modprobe of the qemu rig guest: modules from the rig cache\nexec /sbin/modprobe -d %q "$@"\n' \
    "$dest/root" >"$tmp/bin/modprobe"
  chmod 755 "$tmp/bin/modprobe"
  printf 'package %s\nversion %s\nrelease %s\nvmlinuz_sha256 %s\nvmlinux_bytes %s\n' "$pkg" "$ver" \
    "$release" "$(sha256sum <"$tmp/vmlinuz" | cut -d' ' -f1)" \
    "$(stat -c %s "$tmp/vmlinux" 2>/dev/null || echo none)" >"$tmp/stamp"
  rm -rf "$dest"
  mv "$tmp" "$dest"
  echo "$pkg $ver" >"$cache/current"
}

# PID 1 of the initramfs. Its text names the cached initramfs (initrd-HASH.gz), so a change here
# builds a new one. Settings come on the kernel command line (rig.NAME=VALUE).
read -r -d '' initramfs_init <<'INIT' || true
#!/bin/busybox sh
# PID 1 of the qemu rig's initramfs (tests/rig/qemu_rig.sh): modules, the host's root over 9p
# with the guest's own mounts in it, the vcan interfaces; then the rig's init script there.
bb=/bin/busybox
$bb mount -t proc proc /proc
opt() { $bb sed -n "s/.*\brig\.$1=\([^ ]*\).*/\1/p" /proc/cmdline; }
verbose=$(opt verbose)
mark() { [ "$verbose" = 1 ] && echo "qemu_rig: initramfs at $($bb cut -d' ' -f1 /proc/uptime) s: $*"; }
fail() { echo "qemu_rig: initramfs: $*"; $bb poweroff -f; }
mark started
for m in $($bb cat /mods/order); do $bb insmod "/mods/$m" || fail "insmod $m"; done
mark modules loaded
h=/host
$bb mount -t 9p -o "trans=virtio,version=9p2000.L,msize=$(opt msize),cache=$(opt cache)" host $h ||
  fail "cannot mount the host's root"
$bb mount -t proc proc $h/proc && $bb mount -t sysfs sysfs $h/sys &&
  $bb mount -t devtmpfs devtmpfs $h/dev && $bb mkdir -p $h/dev/pts $h/dev/shm &&
  $bb mount -t devpts devpts $h/dev/pts && $bb mount -t tmpfs tmpfs $h/dev/shm &&
  $bb mount -t tmpfs tmpfs $h/run && $bb mkdir -p $h/run/canbridge-rig/share $h/run/canbridge-rig/host-tmp &&
  $bb mount -t 9p -o trans=virtio,version=9p2000.L,cache=none rig $h/run/canbridge-rig/share &&
  $bb mount -o bind $h/tmp $h/run/canbridge-rig/host-tmp &&
  $bb mount -t tmpfs -o mode=1777 tmpfs $h/tmp || fail "mounts"
# The rig's init runs under this busybox (no program of the host needs starting before the command).
$bb cp $bb $h/run/canbridge-rig/busybox
opt modprobe >/proc/sys/kernel/modprobe
$bb ip link set lo up || fail "lo"
i=0
while [ $i -lt "$(opt vcan)" ]; do
  $bb ip link add dev vcan$i type vcan && $bb ip link set vcan$i up || fail "vcan$i"
  i=$((i + 1))
done
mark ready
$bb umount /proc
exec $bb switch_root $h /run/canbridge-rig/share/init
INIT

# build_initrd DIR RELEASE FILE: FILE, busybox and what mounting the host's root needs.
build_initrd() {
  local dir=$1 release=$2 out=$3 rootfs line ko n=0 name
  rootfs=$(mktemp -d "$dir/initramfs.XXXXXX")
  mkdir -p "$rootfs"/{bin,mods,proc,sys,dev,host}
  cp /bin/busybox "$rootfs/bin/busybox"
  # The load order from modules.dep (dependencies first), as modprobe would insert them;
  # busybox's insmod takes neither dependencies nor compressed modules.
  : >"$rootfs/mods/order"
  while read -r line; do
    [[ $line == insmod\ * ]] || continue
    ko=$(awk '{print $2}' <<<"$line")
    name=$(basename "$ko"); name=${name%%.ko*}
    grep -qx "[0-9]*-$name.ko" "$rootfs/mods/order" && continue
    n=$((n + 1))
    case $ko in
      *.xz) xz -dc "$ko" ;;
      *.zst) zstd -qdc "$ko" ;;
      *.gz) gzip -dc "$ko" ;;
      *) cat "$ko" ;;
    esac >"$rootfs/mods/$n-$name.ko"
    echo "$n-$name.ko" >>"$rootfs/mods/order"
  done < <(modprobe -d "$dir/root" -S "$release" -a --show-depends "${initramfs_modules[@]}")
  printf '%s\n' "$initramfs_init" >"$rootfs/init"
  chmod 755 "$rootfs/init"
  (cd "$rootfs" && find . | cpio -o -H newc -R 0:0 --quiet | gzip -1 >"$out.tmp")
  mv "$out.tmp" "$out"
  rm -rf "$rootfs"
}

kdir=
if [[ -f $cache/current ]]; then
  read -r cur_pkg cur_ver <"$cache/current" || true
  kdir=$cache/${cur_pkg:-none}_${cur_ver:-none}
  kernel_valid "$kdir" || { say "the cached kernel in $kdir is damaged: fetching again"; kdir=; }
fi
# Asked again only now and then: the rig must not depend on apt's lists being fresh, or there.
if [[ -z $kdir ]] || [[ -n $(find "$cache/current" -mtime +"$refresh_days" 2>/dev/null) ]]; then
  latest=$(apt_kernel)
  if [[ -z $latest && -z $kdir ]]; then
    $sudo apt-get update -qq
    latest=$(apt_kernel)
  fi
  if [[ -n $latest && $latest != "${cur_pkg:-} ${cur_ver:-}" || -z $kdir ]]; then
    [[ -n $latest ]] || { say "apt knows no linux-image-amd64 kernel"; exit 1; }
    # shellcheck disable=SC2086  # "PKG VERSION"
    if fetch_kernel $latest; then
      kdir=$cache/${latest/ /_}
    elif [[ -z $kdir ]]; then
      exit 1
    else
      say "keeping the cached kernel $kdir"
    fi
  fi
  [[ -n $kdir ]] && touch "$cache/current"
fi
release=$(awk '$1 == "release" {print $2}' "$kdir/stamp")
initrd=$kdir/initrd-$(printf '%s' "$initramfs_init" | sha256sum | cut -c1-16).gz
[[ -f $initrd ]] || build_initrd "$kdir" "$release" "$initrd"
flock -u 9

# ---- this run ----
work=$(mktemp -d /tmp/canbridge-qemu-rig.XXXXXX)
qemu_pid=
tail_pid=
# shellcheck disable=SC2317  # run by the EXIT trap
cleanup() {
  [[ -n $qemu_pid ]] && kill "$qemu_pid" 2>/dev/null
  [[ -n $tail_pid ]] && kill "$tail_pid" 2>/dev/null
  if [[ ${CANBRIDGE_RIG_KEEP:-0} == 1 ]]; then say "kept $work"; else rm -rf "$work"; fi
}
trap cleanup EXIT
# Killed (ctest's timeout, ^C): the EXIT trap stops the guest.
trap 'exit 143' TERM HUP
trap 'exit 130' INT
mkdir "$work/share"

# The /tmp folders that must stay the host's: where the working directory, any argument and the
# kernel cache (its modules) lie.
host_tmp=()
for p in "$PWD" "$@" "$kdir"; do
  if [[ $p == /tmp/?* && -e $p ]]; then
    top=${p#/tmp/}; top=${top%%/*}
    [[ " ${host_tmp[*]} " == *" $top "* ]] || host_tmp+=("$top")
  fi
done

# sh_quote WORD: WORD in single quotes, for busybox sh.
sh_quote() { printf "'%s'" "${1//\'/\'\\\'\'}"; }
share=/run/canbridge-rig/share
# shellcheck disable=SC2016  # $bb, $? and $* are the guest shell's
{
  echo '#!/run/canbridge-rig/busybox sh'
  echo '# The qemu rig guest after the initramfs, in the host root (written by tests/rig/qemu_rig.sh).'
  echo "bb=/run/canbridge-rig/busybox"
  echo "exec >$share/guest.log 2>&1"
  echo 'fail() { echo "qemu_rig: $*"; echo 125 >'"$share/status"'; $bb sync; $bb poweroff -f; }'
  for top in "${host_tmp[@]}"; do
    echo "\$bb mkdir -p /tmp/$(sh_quote "$top") && \$bb mount -o bind /run/canbridge-rig/host-tmp/$(sh_quote "$top") /tmp/$(sh_quote "$top") || fail 'bind $top'"
  done
  echo "export PATH=$(sh_quote "$kdir/bin"):/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
  while IFS= read -r -d '' var; do
    name=${var%%=*}
    [[ $name =~ ^(GTEST_|CANBRIDGE_|ASAN_|UBSAN_|LSAN_)[A-Za-z0-9_]*$|^(HOME|TERM)$ ]] || continue
    echo "export $name=$(sh_quote "${var#*=}")"
  done < <(env -0)
  echo "cd $(sh_quote "$PWD") || fail 'no working directory $(sh_quote "$PWD")'"
  echo "\$bb cut -d' ' -f1 /proc/uptime >$share/started"
  printf '%s ' "$(for a in "$@"; do sh_quote "$a"; printf ' '; done)"
  echo ">$share/output 2>&1 </dev/null"
  echo "echo \$? >$share/status"
  echo '$bb sync'
  echo '$bb poweroff -f'
} >"$work/share/init"
chmod +x "$work/share/init"
: >"$work/share/output"

accel=${CANBRIDGE_RIG_ACCEL:-}
if [[ -z $accel ]]; then
  accel=tcg
  # /dev/kvm can exist where KVM cannot run a guest (this project's VMs have it without the
  # CPU's virtualisation flags, and a guest started there hangs): both must be there.
  if [[ -w /dev/kvm ]] && grep -qwE 'vmx|svm' /proc/cpuinfo; then accel=kvm; fi
fi
accel_opts=(-accel "$accel" -cpu max)
# max: on KVM the host's CPU; under TCG every feature qemu emulates.
[[ $accel == tcg ]] && accel_opts=(-accel "tcg,thread=multi" -cpu max)
kernel=$kdir/vmlinux
[[ -f $kernel ]] || kernel=$kdir/vmlinuz

# tsc=reliable: under TCG the guest's TSC is the host's, steady and the same on every vCPU, but
# the kernel's boot check finds the emulated CPUs' TSCs "unsynchronized" and falls back to the
# HPET, whose every read traps into qemu: clock_gettime then cost 2.7 us instead of 0.14 us
# through the vDSO (a board's is ~0.02-0.1 us), and the roles read the clock on every wake.
start=$(date +%s.%N)
# The host's root, cached in the guest (loose): the guest reads programs and libraries many times
# and nothing on the host changes them while it runs; what it writes reaches the host at its sync.
# setpriv --pdeathsig: should this script be killed outright, the guest goes with it.
setpriv --pdeathsig KILL -- timeout --kill-after=10 "$timeout_s" \
  setpriv --pdeathsig KILL -- qemu-system-x86_64 "${accel_opts[@]}" -smp "$smp" \
  -m "$mem" -M pc -nodefaults -no-user-config -display none -no-reboot -nic none \
  -serial "file:$work/console.log" \
  -device virtio-rng-pci \
  -virtfs local,path=/,mount_tag=host,security_model=none,multidevs=remap \
  -virtfs "local,path=$work/share,mount_tag=rig,security_model=none" \
  -kernel "$kernel" -initrd "$initrd" \
  -append "console=ttyS0 quiet loglevel=3 panic=-1 tsc=reliable rdinit=/init rig.msize=512000 rig.cache=loose rig.verbose=$verbose rig.vcan=$vcan_count rig.modprobe=$kdir/bin/modprobe ${CANBRIDGE_RIG_APPEND:-}" \
  </dev/null >"$work/qemu.log" 2>&1 &
qemu_pid=$!
# The output while it is written (tail ends after the last bytes once qemu has exited); waited for
# in the background, where a signal to this script is handled at once.
tail --pid="$qemu_pid" -s 0.2 -n +1 -f "$work/share/output" 2>/dev/null &
tail_pid=$!
wait "$tail_pid" || true
tail_pid=
rc=0
wait "$qemu_pid" || rc=$?
qemu_pid=

if [[ $verbose == 1 && -f $work/share/started ]]; then
  boot=$(awk -v a="$start" -v b="$(stat -c %.9Y "$work/share/started")" 'BEGIN{printf "%.1f", b - a}')
  say "$accel, -smp $smp, kernel $release: command started $boot s after qemu ($(cat "$work/share/started") s of guest uptime)"
fi
if [[ ! -f $work/share/status ]]; then
  say "the guest reported no exit status (qemu exit $rc; timeout ${timeout_s}s)"
  echo "--- qemu" >&2; cat "$work/qemu.log" >&2 || true
  echo "--- guest log" >&2; cat "$work/share/guest.log" >&2 2>/dev/null || true
  echo "--- console (tail)" >&2; tail -n 30 "$work/console.log" >&2 || true
  exit 1
fi
status=$(cat "$work/share/status")
[[ $verbose == 1 ]] && tr -d '\r' <"$work/console.log" | grep '^qemu_rig: initramfs' >&2
if grep -q 'qemu_rig:' "$work/share/guest.log" 2>/dev/null || [[ $verbose == 1 ]]; then
  cat "$work/share/guest.log" >&2
fi
exit "$status"
