#!/usr/bin/env bash
# Builds the .deb from a configured and built tree and installs it into a fresh root, then checks the
# installed files as the service would use them. Usage: packaging/test_package.sh BUILD_DIR
#
# The fresh root: the host's Debian 12 /usr and dpkg database as read-only lower layers of overlay
# mounts (so the package's dependencies are there and dpkg checks them), an /etc with only the files a
# minimal Debian root has (users, groups, loader cache), nothing of ridgewatch. `dpkg --root` installs
# the package there and runs its maintainer scripts chrooted (service user from sysusers, directories
# from tmpfiles). Needs root with CAP_SYS_ADMIN for the mounts; otherwise the package is unpacked with
# dpkg -x and the installed binaries run from there (exit 77: ctest reports the chroot part skipped).
set -euo pipefail
build=$(cd "$1" && pwd)
work=$(mktemp -d /tmp/ridgewatch-pkgtest.XXXXXX)
root=$work/root
mounted=()
cleanup() {
  for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount "${mounted[$i]}" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT
fail() { echo "FAIL: $*" >&2; exit 1; }

echo "== cpack"
cpack --config "$build/CPackConfig.cmake" -G DEB -B "$work/pkg" >"$work/cpack.log" 2>&1 || { cat "$work/cpack.log"; fail "cpack"; }
deb=$(ls "$work"/pkg/ridgewatch_*.deb)
[[ $'\n'$(dpkg-deb -I "$deb" conffiles)$'\n' == *$'\n/etc/ridgewatch/ridgewatch.yaml\n'* ]] || fail "ridgewatch.yaml is not a conffile"

# The generated man pages render without warnings and list every flag of --help (test_usage checks
# the text; here: the installed copies are the generated ones).
check_man() {
  local page=$1
  local warn
  warn=$(LC_ALL=C.UTF-8 MANWIDTH=100 man --warnings -l "$page" 2>&1 >/dev/null) || fail "man -l $page"
  [[ -z $warn ]] || fail "man -l $page warns: $warn"
  [[ $(LC_ALL=C.UTF-8 MANWIDTH=100 man -l "$page" 2>/dev/null) == *"$2"* ]] || fail "man -l $page: no '$2'"
}

mkdir -p "$root"/{usr,etc,var/lib/dpkg,tmp,dev,proc,run} "$work"/{usr-up,usr-work,dpkg-up,dpkg-work}
if ! mount -t overlay overlay -o "lowerdir=/usr,upperdir=$work/usr-up,workdir=$work/usr-work" "$root/usr" 2>/dev/null; then
  echo "== no overlay mount here (needs root with CAP_SYS_ADMIN): dpkg -x instead of a chroot"
  dpkg-deb -x "$deb" "$work/x"
  "$work/x/usr/sbin/ridgewatchd" --check-config "$work/x/etc/ridgewatch/ridgewatch.yaml"
  "$work/x/usr/bin/ridgewatch" modes --help >/dev/null
  check_man "$work/x/usr/share/man/man1/ridgewatch.1" "--all-methods"
  check_man "$work/x/usr/share/man/man8/ridgewatchd.8" "--test-relays"
  check_man "$work/x/usr/share/man/man5/ridgewatch.yaml.5" "max_files"
  exit 77
fi
mounted+=("$root/usr")
mount -t overlay overlay -o "lowerdir=/var/lib/dpkg,upperdir=$work/dpkg-up,workdir=$work/dpkg-work" "$root/var/lib/dpkg"
mounted+=("$root/var/lib/dpkg")
mount --bind /dev "$root/dev" && mounted+=("$root/dev")
mount -t proc proc "$root/proc" && mounted+=("$root/proc")
for l in bin sbin lib lib64; do ln -s "usr/$l" "$root/$l"; done
# A minimal /etc: the system users and groups of a fresh Debian root (base-passwd's masters; the
# host's man-db trigger needs its "man" user), the loader cache.
cp /usr/share/base-passwd/passwd.master "$root/etc/passwd"
cp /usr/share/base-passwd/group.master "$root/etc/group"
sed 's/:.*/:*:19000:0:99999:7:::/' "$root/etc/passwd" >"$root/etc/shadow"
sed 's/:.*/:*::/' "$root/etc/group" >"$root/etc/gshadow"
cp -a /etc/ld.so.cache /etc/ld.so.conf /etc/ld.so.conf.d /etc/nsswitch.conf "$root/etc/"
cp -a /etc/manpath.config "$root/etc/" 2>/dev/null || true

echo "== dpkg -i into the fresh root"
dpkg --root="$root" --log=/dev/null -i "$deb" >"$work/dpkg.log" 2>&1 || { cat "$work/dpkg.log"; fail "dpkg -i"; }
in_root() { chroot "$root" "$@"; }
in_root getent passwd ridgewatch >/dev/null || fail "postinst made no ridgewatch user"
[[ " $(in_root id -nG ridgewatch) " == *" audio "* ]] || fail "ridgewatch is not in the audio group"
in_root test -d /var/lib/ridgewatch/captures || fail "tmpfiles: no /var/lib/ridgewatch/captures"
[[ $(in_root stat -c '%U:%G %a' /etc/ridgewatch/ridgewatch.yaml) == "root:ridgewatch 640" ]] || fail "config owner/mode"

echo "== the service's config check, as the service user"
[[ $(in_root /usr/sbin/ridgewatchd --check-config /etc/ridgewatch/ridgewatch.yaml) == "/etc/ridgewatch/ridgewatch.yaml: ok" ]] ||
  fail "check-config"
in_root setpriv --reuid=ridgewatch --regid=ridgewatch --init-groups \
  /usr/sbin/ridgewatchd --check-config /etc/ridgewatch/ridgewatch.yaml >/dev/null || fail "check-config as ridgewatch"
in_root grep -q '^ExecStart=/usr/sbin/ridgewatchd --config /etc/ridgewatch/ridgewatch.yaml$' \
  /usr/lib/systemd/system/ridgewatchd.service || fail "unit ExecStart"
[[ $(in_root /usr/bin/ridgewatch --version) == "ridgewatch "* ]] || fail "ridgewatch --version"
[[ $(in_root /usr/bin/ridgewatch modes --help) == *--min-snr-db* ]] || fail "ridgewatch modes --help"
# The installed rig example and configuration work with the installed tools: simulate 0.5 s of the
# paper rig, analyze it with the installed configuration's pipeline.
in_root /usr/bin/ridgewatch simulate --rig /usr/share/ridgewatch/rigs/paper-rig.yaml --duration 0.5 --out /tmp/sim \
  >/dev/null 2>&1 || fail "simulate with the installed rig"
in_root /usr/bin/ridgewatch analyze --config /etc/ridgewatch/ridgewatch.yaml /tmp/sim.wav >"$work/events" 2>/dev/null ||
  fail "analyze with the installed configuration"
grep -q '"status":"ok"' "$work/events" || fail "analyze: no ok event"
bash -n "$root/usr/share/bash-completion/completions/ridgewatch" || fail "completion syntax"

echo "== man -l"
check_man "$root/usr/share/man/man1/ridgewatch.1" "--all-methods"
check_man "$root/usr/share/man/man8/ridgewatchd.8" "--test-relays"
check_man "$root/usr/share/man/man5/ridgewatch.yaml.5" "max_files"

echo "== remove keeps the edited conffile, purge removes it"
echo "# site edit" >>"$root/etc/ridgewatch/ridgewatch.yaml"
dpkg --root="$root" --log=/dev/null -r ridgewatch >>"$work/dpkg.log" 2>&1 || { cat "$work/dpkg.log"; fail "dpkg -r"; }
[[ ! -e $root/usr/sbin/ridgewatchd && -f $root/etc/ridgewatch/ridgewatch.yaml ]] || fail "remove"
dpkg --root="$root" --log=/dev/null -P ridgewatch >>"$work/dpkg.log" 2>&1 || { cat "$work/dpkg.log"; fail "dpkg -P"; }
[[ ! -e $root/etc/ridgewatch/ridgewatch.yaml ]] || fail "purge left the conffile"
echo "package test passed: $(basename "$deb")"
