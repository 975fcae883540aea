#!/usr/bin/env bash
# Both README commands on a fresh Debian 12 (bookworm) minbase system, as a new user would meet
# them: a debootstrap chroot (/proc, /sys, /dev, /dev/pts, /dev/shm, /etc/hosts, resolv.conf) with
# this working tree copied in (what git neither ignores nor keeps in .git; build/ left out) and
# ../shared bind-mounted read-only beside it. Runs scripts/run.sh (set-up from nothing, build,
# the demo), then scripts/test.sh, prints the tail and wall time of each, fails when either fails.
# The minbase system is made once and kept as a tarball (build/fresh_debian/minbase.tar);
# every run unpacks a new root from it.
# Usage: sudo scripts/fresh_debian_check.sh   (root: debootstrap, mount, chroot; ~30 min on 2 cores)
#   FRESH_DIR (default build/fresh_debian), DEBIAN_MIRROR (default http://deb.debian.org/debian)
set -euo pipefail
cd "$(dirname "$0")/.."
SRC="$(pwd)"
DIR="${FRESH_DIR:-$SRC/build/fresh_debian}"
MIRROR="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
ROOT="$DIR/root"
WS=/root/ws  # the project at $WS/endo_guidance, shared data at $WS/shared

[ "$(id -u)" -eq 0 ] || { echo "fresh_debian_check.sh: needs root (debootstrap, mount, chroot): sudo $0" >&2; exit 2; }
if ! command -v debootstrap >/dev/null; then
  echo "[fresh] installing debootstrap"
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends debootstrap >/dev/null \
    || { echo "fresh_debian_check.sh: debootstrap is missing and could not be installed" >&2; exit 2; }
fi
[ -d ../shared ] || echo "[fresh] no ../shared beside the project: the tests on real data will report skipped"

mounted=()
kill_inside() {  # every process whose root is the fresh system (a killed run leaves apt or a build)
  local p
  for p in /proc/[0-9]*; do
    case "$(readlink "$p/root" 2>/dev/null)" in "$ROOT" | "$ROOT"/*) kill -9 "${p#/proc/}" 2>/dev/null || true ;; esac
  done
}
unmount_all() {
  local i
  kill_inside
  for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount -l "${mounted[i]}" 2>/dev/null || true; done
  mounted=()
}
trap unmount_all EXIT
trap 'exit 130' INT TERM
bind() {  # bind SRC DST [ro]
  mkdir -p "$2"
  mount --bind "$1" "$2"
  mounted+=("$2")
  [ "${3:-}" = ro ] && mount -o remount,bind,ro "$2"
  return 0
}

mkdir -p "$DIR"
if [ ! -f "$DIR/minbase.tar" ]; then
  echo "[fresh] debootstrap --variant=minbase bookworm ($MIRROR)"
  rm -rf "$DIR/bootstrap"
  timeout 1800 debootstrap --variant=minbase bookworm "$DIR/bootstrap" "$MIRROR" >"$DIR/debootstrap.log" 2>&1 \
    || { echo "fresh_debian_check.sh: debootstrap failed ($DIR/debootstrap.log):" >&2; tail -5 "$DIR/debootstrap.log" >&2; exit 1; }
  tar -C "$DIR/bootstrap" -cf "$DIR/minbase.tar.part" . && mv "$DIR/minbase.tar.part" "$DIR/minbase.tar"
  rm -rf "$DIR/bootstrap"
fi

# A new root from the pristine system (what a killed run left running or mounted is released first).
kill_inside
grep -q " $ROOT/" /proc/mounts && awk -v r="$ROOT/" '$2 ~ "^"r {print $2}' /proc/mounts | sort -r | xargs -r umount -l
rm -rf "$ROOT"
mkdir -p "$ROOT"
tar -C "$ROOT" -xf "$DIR/minbase.tar"
cat >"$ROOT/etc/apt/sources.list" <<EOF
deb $MIRROR bookworm main
deb $MIRROR bookworm-updates main
deb http://deb.debian.org/debian-security bookworm-security main
EOF
cp /etc/hosts "$ROOT/etc/hosts"
cp -L /etc/resolv.conf "$ROOT/etc/resolv.conf" 2>/dev/null || true

echo "[fresh] copying the working tree into $WS/endo_guidance"
mkdir -p "$ROOT$WS/endo_guidance"
tar -C "$SRC" --exclude-vcs --exclude-vcs-ignores --exclude=./build -cf - . | tar -C "$ROOT$WS/endo_guidance" -xf -

mount -t proc proc "$ROOT/proc"; mounted+=("$ROOT/proc")
mount -t sysfs sys "$ROOT/sys"; mounted+=("$ROOT/sys")
bind /dev "$ROOT/dev"
bind /dev/pts "$ROOT/dev/pts"
mount -t tmpfs shm "$ROOT/dev/shm"; mounted+=("$ROOT/dev/shm")
[ -d ../shared ] && bind "$(cd ../shared && pwd)" "$ROOT$WS/shared" ro

status=0
for cmd in scripts/run.sh scripts/test.sh; do
  name="$(basename "$cmd" .sh)"
  log="$DIR/$name.log"
  echo "[fresh] $cmd (log: $log)"
  start=$(date +%s)
  rc=0
  chroot "$ROOT" /usr/bin/env -i HOME=/root LANG=C.UTF-8 TERM=dumb CI=true \
    PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    timeout 5400 bash -c "cd $WS/endo_guidance && bash $cmd" >"$log" 2>&1 &
  wait $! || rc=$?  # (in the background: a signal to this script stops it at once, the trap cleans up)
  secs=$(($(date +%s) - start))
  echo "----- $cmd: exit $rc after $((secs / 60)) min $((secs % 60)) s; its last lines:"
  tail -25 "$log"
  [ "$rc" -eq 0 ] || status=1
done
unmount_all
[ "$status" -eq 0 ] && echo "[fresh] both README commands passed on a fresh Debian 12 minbase system" \
  || echo "[fresh] FAILED on a fresh Debian 12 minbase system (logs in $DIR)" >&2
exit $status
