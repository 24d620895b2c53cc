#!/usr/bin/env bash
# Builds the canbridge image with podman, without any registry: makes a local Debian 12 base with
# debootstrap when it is missing, then builds docker/Dockerfile from the repository root.
#
#   docker/build.sh [--rebuild-base] [--prebuilt DIR] [-- EXTRA PODMAN BUILD ARGS...]
#   docker/build.sh --base-only [--rebuild-base]
#
# Default: the image's final stage `runtime`, the executables compiled from source in the build
# stage (what `docker build` does). --prebuilt DIR: the Dockerfile's `prebuilt` target instead, the
# same runtime content with the executables canbridge, canbridge-sim and canbridge-link-emulator
# taken from DIR (e.g. a build tree's freshly built ones, for the test suite; stripped copies go
# into the image, DIR is not changed); the build stage does not run. The executables must have
# been built against Debian 12's libraries (the smoke test checks each resolves in the image).
# --base-only: only make the base when it is missing (CI starts it early, in the background,
# while it compiles). Callers serialize on a lock while one makes the base, so a second one waits
# for it and then finds the base there instead of running debootstrap again.
#
# Environment: BASE_IMAGE (default localhost/debian-bookworm-base), IMAGE (default canbridge:dev),
# MIRROR (default: the host's Debian mirror from /etc/apt), ISOLATION (default chroot).
# Idempotent: an existing base is reused; podman's layer cache makes a repeated build quick.
# The build stage's untagged image is removed after the build (no dangling image is left); the
# layers it was made of stay cached. Each phase reports how long it took.
# Needs root (debootstrap, podman import), podman and debootstrap (apt-get install podman
# debootstrap).
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
base_image=${BASE_IMAGE:-localhost/debian-bookworm-base}
image=${IMAGE:-canbridge:dev}
isolation=${ISOLATION:-chroot}
rebuild_base=0
base_only=0
prebuilt=""
extra=()
while (($#)); do
  case $1 in
    --rebuild-base) rebuild_base=1 ;;
    --base-only) base_only=1 ;;
    --prebuilt)
      [[ $# -ge 2 && -n $2 ]] || { echo "build.sh: --prebuilt needs a directory" >&2; exit 2; }
      prebuilt=$2; shift ;;
    --) shift; extra=("$@"); break ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "build.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
  shift
done

say() { echo "build.sh: $*"; }
die() { echo "build.sh: error: $*" >&2; exit 1; }
((base_only)) && [[ -n $prebuilt || ${#extra[@]} -gt 0 ]] &&
  { echo "build.sh: --base-only builds no image: no --prebuilt or podman arguments" >&2; exit 2; }

# --prebuilt's input is checked before minutes of debootstrap, not after.
prebuilt_executables=(canbridge canbridge-sim canbridge-link-emulator)
if [[ -n $prebuilt ]]; then
  [[ -d $prebuilt ]] || die "--prebuilt $prebuilt: not a directory"
  for exe in "${prebuilt_executables[@]}"; do
    [[ -f $prebuilt/$exe && -x $prebuilt/$exe ]] || die "--prebuilt: no executable $prebuilt/$exe"
  done
  command -v strip >/dev/null || die "--prebuilt needs strip (binutils) to strip the executables"
fi

# Temporary directories this run made (the base's rootfs, the stripped executables), removed on
# any exit.
temp_dirs=()
remove_temp_dirs() { ((${#temp_dirs[@]} == 0)) || rm -rf "${temp_dirs[@]}"; }
trap remove_temp_dirs EXIT

command -v podman >/dev/null || die "podman not found (apt-get install podman)"

# Every URI named by one apt source file (one-line .list or deb822 .sources format).
source_uris() {
  case $1 in
    *.sources) awk 'tolower($1)=="uris:" { for (i = 2; i <= NF; i++) print $i }' "$1" ;;
    *) sed -nE 's/^[[:space:]]*deb(-src)?[[:space:]]+(\[[^]]*\][[:space:]]+)?([^[:space:]]+).*/\3/p' "$1" ;;
  esac
}

# The host's enabled apt source files (apt ignores other names, e.g. *.disabled).
host_source_files() {
  local f
  for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources; do
    [[ -s $f ]] && printf '%s\n' "$f"
  done
  return 0
}

# The host's Debian archive mirror (not -security/-updates), else deb.debian.org.
host_mirror() {
  local f uri
  while read -r f; do
    while read -r uri; do
      [[ $uri =~ /debian/?$ ]] && { echo "${uri%/}"; return; }
    done < <(source_uris "$f")
  done < <(host_source_files)
  echo http://deb.debian.org/debian
}

make_base() {
  [[ $(id -u) -eq 0 ]] || die "making the base needs root (debootstrap); run as root or build it once as root"
  command -v debootstrap >/dev/null || die "debootstrap not found (apt-get install debootstrap)"
  local mirror=${MIRROR:-$(host_mirror)}
  local mirror_host=${mirror#*://}; mirror_host=${mirror_host%%/*}
  local dir; dir=$(mktemp -d /tmp/canbridge-base.XXXXXX)
  temp_dirs+=("$dir")
  local include=()
  [[ $mirror == https:* ]] && include=(--include=ca-certificates)

  say "debootstrap --variant=minbase bookworm $dir $mirror  (a few minutes)"
  local started=$SECONDS
  debootstrap --variant=minbase "${include[@]}" bookworm "$dir" "$mirror" >"$dir.log" 2>&1 ||
    { tail -20 "$dir.log" >&2; die "debootstrap failed (full log: $dir.log)"; }
  rm -f "$dir.log"
  say "debootstrap took $((SECONDS - started)) s"
  started=$SECONDS

  # Apt inside the build uses the host's mirror configuration: copy the host's Debian source
  # files (those whose keyrings exist in the new rootfs, or that name only Debian hosts) and any
  # apt.conf.d settings for proxies and snapshot validity.
  local f uri copied=0 keyring ok
  while read -r f; do
    ok=1
    while read -r keyring; do
      [[ -e $dir$keyring ]] || ok=0
    done < <(sed -nE 's/.*[Ss]igned-[Bb]y[:=][[:space:]]*([^][:space:]]+).*/\1/p' "$f")
    if ! grep -qiE 'signed-by' "$f"; then
      while read -r uri; do
        [[ $uri =~ ://([^/]*\.)?debian\.org/ || $uri == *"://$mirror_host/"* ]] || ok=0
      done < <(source_uris "$f")
    fi
    if ((ok)); then
      mkdir -p "$dir$(dirname "$f")"
      cp "$f" "$dir$f"
      say "  apt source from host: $f"
      copied=1
    else
      say "  skipped host apt source $f (non-Debian repository or keyring missing in the base)"
    fi
  done < <(host_source_files)
  if ((copied)); then
    # debootstrap wrote sources.list for its mirror; drop it unless the host's own one was copied.
    [[ -s /etc/apt/sources.list ]] || rm -f "$dir/etc/apt/sources.list"
  fi
  for f in /etc/apt/apt.conf /etc/apt/apt.conf.d/*; do
    [[ -f $f ]] && grep -qE 'Acquire::([^[:space:]]*::)?([Pp]roxy|Check-Valid-Until|Check-Date)' "$f" || continue
    mkdir -p "$dir$(dirname "$f")"
    cp "$f" "$dir$f"
    say "  apt setting from host: $f"
  done
  # Like Debian's slim images: no documentation, manual pages or translations (copyright files
  # stay), in the base and for every package the image builds install later.
  [[ -n $dir && $dir == /tmp/canbridge-base.* && -x $dir/usr/bin/dpkg ]] || die "bad rootfs dir '$dir'"
  mkdir -p "$dir/etc/dpkg/dpkg.cfg.d"
  printf '%s\n' 'path-exclude /usr/share/doc/*' 'path-include /usr/share/doc/*/copyright' \
    'path-exclude /usr/share/man/*' 'path-exclude /usr/share/info/*' \
    'path-exclude /usr/share/locale/*' 'path-include /usr/share/locale/locale.alias' \
    >"$dir/etc/dpkg/dpkg.cfg.d/canbridge-slim"
  find "$dir/usr/share/doc" -mindepth 1 ! -type d ! -name copyright -delete
  find "$dir/usr/share/doc" -mindepth 1 -type d -empty -delete
  find "$dir/usr/share/man" "$dir/usr/share/info" -mindepth 1 -delete
  find "$dir/usr/share/locale" -mindepth 1 -maxdepth 1 ! -name locale.alias -exec rm -rf {} +
  chroot "$dir" apt-get clean
  rm -rf "$dir"/var/lib/apt/lists/* "$dir"/var/cache/apt/*.bin

  say "podman import $dir -> $base_image"
  tar --numeric-owner -C "$dir" -c . |
    podman import \
      --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
      --change 'CMD ["/bin/bash"]' \
      --message "debian bookworm minbase from $mirror (canbridge docker/build.sh)" \
      - "$base_image" >/dev/null
  rm -rf "$dir"
  say "slimming and podman import took $((SECONDS - started)) s"
}

# One base maker at a time: a caller that finds the base missing takes this lock, and one that
# finds it held (CI's background --base-only) waits, then sees the base made and reuses it. A
# lock in /run/lock (root's, as making the base needs root) rather than /tmp, where others write.
lock_dir=/run/lock
[[ -d $lock_dir && -w $lock_dir ]] || lock_dir=/tmp
base_lock=$lock_dir/canbridge-base-${base_image//[^A-Za-z0-9._-]/_}.lock
ensure_base() {
  if ((!rebuild_base)) && podman image exists "$base_image"; then
    say "base image $base_image exists: reusing it (--rebuild-base to recreate)"
    return
  fi
  local fd started=$SECONDS
  exec {fd}>>"$base_lock" || die "cannot open the lock $base_lock"
  if ! flock --nonblock "$fd"; then
    say "another docker/build.sh is making the base ($base_lock): waiting for it"
    flock "$fd"
    say "waited $((SECONDS - started)) s for the other base maker"
  fi
  if ((rebuild_base)); then
    say "--rebuild-base: replacing $base_image"
    make_base
  elif podman image exists "$base_image"; then
    say "base image $base_image exists: reusing it"
  else
    say "base image $base_image is missing: creating it"
    make_base
  fi
  exec {fd}>&-
}
ensure_base
if ((base_only)); then
  say "--base-only: $base_image is ready"
  exit 0
fi

# --prebuilt: stripped copies of the three executables in a directory of our own, the extra
# build context `executables` of the Dockerfile's `prebuilt` target (the repository's build
# trees stay out of the main context: Dockerfile.dockerignore).
target=()
if [[ -n $prebuilt ]]; then
  bin_dir=$(mktemp -d /tmp/canbridge-prebuilt.XXXXXX)
  temp_dirs+=("$bin_dir")
  for exe in "${prebuilt_executables[@]}"; do
    cp "$prebuilt/$exe" "$bin_dir/$exe"
  done
  strip "$bin_dir"/*
  chmod 755 "$bin_dir"/*
  target=(--target prebuilt --build-context "executables=$bin_dir")
  say "prebuilt executables from $prebuilt (stripped copies in $bin_dir)"
fi

cd "$root"
cmd=(podman build --isolation="$isolation" --ignorefile docker/Dockerfile.dockerignore
     --build-arg BASE="$base_image" -f docker/Dockerfile "${target[@]}" -t "$image" "${extra[@]}" .)
say "in $root: ${cmd[*]}"
started=$SECONDS
"${cmd[@]}"
say "podman build took $((SECONDS - started)) s"
# Podman keeps the build stage's last image, untagged (dangling), after a multi-stage build; every
# image of that stage carries this label (docker/Dockerfile), the runtime image does not. A
# rebuild under the same tag also leaves the previous canbridge image untagged.
for label in io.canbridge.stage=build org.opencontainers.image.title=canbridge; do
  podman image prune --force --filter "label=$label" >/dev/null
done
say "built $image ($(podman image inspect --format '{{.Size}}' "$image" | numfmt --to=iec) uncompressed)"
say "run: podman run --rm $image   |   the compose bench rig and the rest: docker/README.md"
