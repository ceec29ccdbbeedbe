#!/usr/bin/env bash
# Installs `octoscope serve` as a system service (docs/deploy.md): the binary, the web client,
# the documentation, an example config, the systemd unit, the system user `octoscope`, its cache
# and state folders and a random access token. Run it again to upgrade: binary, web client and
# unit are replaced (each swapped in whole); the config, the token and the data are kept.
#
# Usage: deploy/install.sh [--build DIR] [--prefix DIR] [--destdir DIR] [--unit-dir DIR]
#                          [--no-start]
#   --build DIR    take the binary from DIR (default: build it with deploy/build.sh into build/)
#   --prefix DIR   installation prefix (default /usr/local): DIR/bin/octoscope,
#                  DIR/share/octoscope/web, DIR/share/doc/octoscope
#   --destdir DIR  stage everything below DIR (packaging, tests): no user is created, nothing is
#                  chowned and systemd is not told; run as any user
#   --unit-dir DIR where the unit goes (default /etc/systemd/system; packages use
#                  /lib/systemd/system)
#   --no-start     do not restart a running service after an upgrade
# The kernels are compiled into the binary; nothing else is needed at run time.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
build=""
prefix=/usr/local
destdir=""
unit_dir=/etc/systemd/system
restart=1
user=octoscope

die() {
  echo "install.sh: $*" >&2
  exit 2
}
usage() {
  sed -n '/^# Usage:/,/^# The kernels/p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2
  exit 64
}
while (($#)); do
  case "$1" in
    --build) build="${2:?--build needs a folder}"; shift 2 ;;
    --prefix) prefix="${2:?--prefix needs a folder}"; shift 2 ;;
    --destdir) destdir="${2:?--destdir needs a folder}"; shift 2 ;;
    --unit-dir) unit_dir="${2:?--unit-dir needs a folder}"; shift 2 ;;
    --no-start) restart=0; shift ;;
    -h | --help) usage ;;
    *) echo "install.sh: unknown option $1" >&2; usage ;;
  esac
done
[[ "$prefix" == /* ]] || die "--prefix must be an absolute path, got '$prefix'"
[[ "$unit_dir" == /* ]] || die "--unit-dir must be an absolute path, got '$unit_dir'"
if [[ -n "$destdir" ]]; then
  mkdir -p "$destdir"
  destdir="$(cd "$destdir" && pwd)"
elif [[ $(id -u) -ne 0 ]]; then
  die "installing into the system needs root (or --destdir DIR to stage the files)"
fi

if [[ -z "$build" ]]; then
  bash "$root/deploy/build.sh"
  build="${OCTOSCOPE_BUILD_DIR:-$root/build}"
fi
binary="$build/octoscope"
[[ -x "$binary" ]] || die "$binary: no octoscope binary (build it, or give --build DIR)"
[[ -f "$root/web/index.html" ]] || die "$root/web/index.html: the web client is missing"

bin_dir="$destdir$prefix/bin"
share_dir="$destdir$prefix/share/octoscope"
doc_dir="$destdir$prefix/share/doc/octoscope"
etc_dir="$destdir/etc/octoscope"
system=$([[ -z "$destdir" ]] && echo 1 || echo 0)

# Replaces DEST by the file SRC atomically (a running server keeps its old inode).
install_file() {  # MODE SRC DEST
  local tmp
  tmp="$(dirname "$3")/.$(basename "$3").new.$$"
  install -m "$1" "$2" "$tmp"
  mv -f "$tmp" "$3"
}

# 1. The system user and its folders (systemd re-creates the cache and state folders at every
#    start too: StateDirectory=, CacheDirectory=).
if ((system)); then
  if ! getent passwd "$user" >/dev/null; then
    useradd --system --user-group --home-dir /var/lib/octoscope --no-create-home \
      --shell /usr/sbin/nologin --comment "Octoscope viewer server" "$user"
    echo "install.sh: created the system user $user"
  fi
  # Open GPU render nodes (OpenCL) without a world-writable device.
  for group in render video; do
    getent group "$group" >/dev/null && usermod -a -G "$group" "$user"
  done
fi
install -d -m 0755 "$bin_dir" "$share_dir" "$doc_dir" "$destdir$unit_dir"
install -d -m 0750 "$etc_dir" "$destdir/var/cache/octoscope" "$destdir/var/lib/octoscope"
if ((system)); then
  chown "root:$user" "$etc_dir"
  chown "$user:$user" /var/cache/octoscope /var/lib/octoscope
fi

# 2. The binary (kernels are compiled into it) and the web client, each swapped in whole.
install_file 0755 "$binary" "$bin_dir/octoscope"
rm -rf "$share_dir/web.new" "$share_dir/web.old"
cp -R "$root/web" "$share_dir/web.new"
chmod -R u=rwX,go=rX "$share_dir/web.new"
if [[ -d "$share_dir/web" ]]; then mv "$share_dir/web" "$share_dir/web.old"; fi
mv "$share_dir/web.new" "$share_dir/web"
rm -rf "$share_dir/web.old"

# 3. Documentation and the example config (kept current; the live config is never touched).
for doc in deploy server api cli protocol web; do
  install_file 0644 "$root/docs/$doc.md" "$doc_dir/$doc.md"
done
install_file 0644 "$root/deploy/config.example.json" "$share_dir/config.example.json"
install_file 0644 "$root/deploy/nginx/octoscope.conf" "$share_dir/nginx-octoscope.conf"
install_file 0644 "$root/deploy/nginx/octoscope-prefix.conf" "$share_dir/nginx-octoscope-prefix.conf"
if [[ ! -e "$etc_dir/config.json" ]]; then
  install -m 0640 "$root/deploy/config.example.json" "$etc_dir/config.json"
  ((system)) && chown "root:$user" "$etc_dir/config.json"
  echo "install.sh: wrote $etc_dir/config.json (edit data, public-url, budgets)"
else
  echo "install.sh: kept $etc_dir/config.json (new options: $share_dir/config.example.json)"
fi

# 4. The admin token: 256 random bits, readable by root and the server only.
if [[ ! -e "$etc_dir/token" ]]; then
  (
    umask 077
    token="$(od -An -N32 -tx1 /dev/urandom | tr -d ' \n')"
    [[ ${#token} -eq 64 ]] || die "could not read 32 random bytes from /dev/urandom"
    printf '%s\n' "$token" >"$etc_dir/token.new.$$"
  )
  chmod 0640 "$etc_dir/token.new.$$"
  ((system)) && chown "root:$user" "$etc_dir/token.new.$$"
  mv "$etc_dir/token.new.$$" "$etc_dir/token"
  echo "install.sh: wrote a new admin token to $etc_dir/token"
fi

# 5. The unit, pointing at the installed binary and documentation.
unit="$destdir$unit_dir/octoscope.service"
sed -e "s#^ExecStart=/usr/local/bin/octoscope #ExecStart=$prefix/bin/octoscope #" \
  -e "s#^Documentation=file:///usr/local/share/doc/octoscope/#Documentation=file://$prefix/share/doc/octoscope/#" \
  "$root/deploy/systemd/octoscope.service" >"$unit.new.$$"
grep -q "^ExecStart=$prefix/bin/octoscope serve " "$unit.new.$$" ||
  die "deploy/systemd/octoscope.service: no ExecStart line to point at $prefix/bin/octoscope"
chmod 0644 "$unit.new.$$"
mv -f "$unit.new.$$" "$unit"

echo "install.sh: installed $prefix/bin/octoscope ($("$bin_dir/octoscope" serve --help >/dev/null 2>&1 && echo ok || echo 'does not run here'))${destdir:+ below $destdir}"
if ((system)) && [[ -d /run/systemd/system ]]; then
  systemctl daemon-reload
  if systemctl is-active --quiet octoscope; then
    if ((restart)); then
      systemctl restart octoscope
      echo "install.sh: restarted octoscope (upgrade)"
    else
      echo "install.sh: octoscope still runs the old binary: systemctl restart octoscope"
    fi
  else
    echo "install.sh: next: edit /etc/octoscope/config.json, then systemctl enable --now octoscope"
  fi
fi
