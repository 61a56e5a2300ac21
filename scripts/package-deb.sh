#!/usr/bin/env bash
# Debian packages of the daemon and its camera front-end, for the companion
# computer: cmsckf_<version>_<arch>.deb and cmsckf-dbgsym_<version>_<arch>.deb.
#
#   scripts/package-deb.sh                        # this machine's architecture
#   scripts/package-deb.sh --target aarch64-unknown-linux-gnu   # arm64 (Jetson, Pi, VOXL)
#
# Options:
#   --target TRIPLE   Rust target (x86_64-unknown-linux-gnu -> amd64,
#                     aarch64-unknown-linux-gnu -> arm64); cross-linking needs
#                     gcc-aarch64-linux-gnu and `rustup target add`.
#   --profile NAME    cargo profile (release).
#   --bin-dir DIR     package binaries already built there; build nothing.
#   --out DIR         where the .deb files go (target/debian).
#   --fast            gzip level 1 instead of xz (the test's packages).
#   --allow-sim       accept a daemon built with the simulator (`demo`,
#                     `evaluate`): the test packs the test build's binaries.
#
# What the package holds:
#   /usr/bin/cmsckf, /usr/bin/cmsckf-frontend  stripped; their debug info is in
#       the -dbgsym package under /usr/lib/debug/.build-id/, found by gdb
#   /lib/systemd/system/cmsckf.service           the daemon, as the cmsckf user
#   /lib/systemd/system/cmsckf-frontend.service  the V4L2 front-end, same user
#   /etc/cmsckf/cmsckf.toml                      the config (a conffile: kept on upgrade)
#   /etc/default/cmsckf-frontend                 the camera device and options
#   /usr/share/doc/cmsckf/                       README, copyright, changelog
#   /usr/share/man/man1/cmsckf.1.gz, cmsckf-frontend.1.gz   manual pages
#   /usr/share/cmsckf/camera-socket.py           the bridge for cameras that are not V4L2
# The postinst makes the system user cmsckf (groups dialout and video); the
# units are installed but not enabled: a companion computer flies only what its
# owner switched on (`systemctl enable --now cmsckf cmsckf-frontend`). Flight
# logs go to /var/log/cmsckf (LogsDirectory=), kept on removal and purge.
set -euo pipefail
cd "$(dirname "$0")/.."

target=""
profile="release"
bin_dir=""
out="target/debian"
compress=(-Zxz)
allow_sim=0
while [ $# -gt 0 ]; do
  case "$1" in
    --target) target="$2"; shift 2 ;;
    --profile) profile="$2"; shift 2 ;;
    --bin-dir) bin_dir="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --fast) compress=(-Zgzip -z1); shift ;;
    --allow-sim) allow_sim=1; shift ;;
    *) echo "package-deb.sh: unknown option $1 (see the header of $0)" >&2; exit 2 ;;
  esac
done
[ -n "$target" ] || target="$(rustc -vV | sed -n 's/^host: //p')"

case "$target" in
  x86_64-unknown-linux-gnu) arch=amd64; tool_prefix="" ;;
  aarch64-unknown-linux-gnu) arch=arm64; tool_prefix="aarch64-linux-gnu-" ;;
  *) echo "package-deb.sh: no Debian architecture for $target (x86_64- or aarch64-unknown-linux-gnu)" >&2; exit 2 ;;
esac
host="$(rustc -vV | sed -n 's/^host: //p')"
[ "$target" = "$host" ] && tool_prefix=""
objcopy="${tool_prefix}objcopy"
command -v "$objcopy" >/dev/null || { echo "package-deb.sh: $objcopy not found (binutils for $arch)" >&2; exit 1; }
command -v dpkg-deb >/dev/null || { echo "package-deb.sh: dpkg-deb not found (Debian's dpkg)" >&2; exit 1; }

version="$(sed -n '/^\[package\]/,/^\[/s/^version = "\(.*\)"/\1/p' Cargo.toml | head -1)"
[ -n "$version" ] || { echo "package-deb.sh: no version in Cargo.toml" >&2; exit 1; }

if [ -z "$bin_dir" ]; then
  cross_env=()
  if [ "$arch" = arm64 ] && [ "$target" != "$host" ]; then
    cross_env=(CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
               CC_aarch64_unknown_linux_gnu=aarch64-linux-gnu-gcc)
  fi
  # The daemon that flies builds without the simulator (no demo, no evaluate),
  # the front-end with its V4L2 camera: --no-default-features applies to both
  # packages of the one cargo call, so the front-end's feature is named.
  env "${cross_env[@]}" cargo build --profile "$profile" --target "$target" --no-default-features \
    -p cmsckf --bin cmsckf -p cmsckf-frontend --bin cmsckf-frontend --features cmsckf-frontend/v4l2
  dir="$profile"; [ "$profile" = dev ] && dir=debug
  bin_dir="target/$target/$dir"
fi
for b in cmsckf cmsckf-frontend; do
  [ -x "$bin_dir/$b" ] || { echo "package-deb.sh: $bin_dir/$b is not there (build it, or give --bin-dir)" >&2; exit 1; }
done

# The binaries run here (natively, or under qemu): the daemon must be the
# flight build, the front-end must have its V4L2 camera.
runner=()
if [ "$target" != "$host" ]; then
  if command -v qemu-aarch64 >/dev/null && [ "$arch" = arm64 ]; then
    runner=(qemu-aarch64 -L /usr/aarch64-linux-gnu)
  else
    runner=(none)
  fi
fi
if [ "${runner[0]:-}" != none ]; then
  if [ "$allow_sim" = 0 ] && "${runner[@]}" "$bin_dir/cmsckf" evaluate --help >/dev/null 2>&1; then
    echo "package-deb.sh: $bin_dir/cmsckf has the simulator (demo, evaluate): build it with --no-default-features" >&2
    exit 1
  fi
  help="$("${runner[@]}" "$bin_dir/cmsckf-frontend" --help)"
  case "$help" in
    *--v4l2*) ;;
    *) echo "package-deb.sh: $bin_dir/cmsckf-frontend has no V4L2 camera (build it with its default features)" >&2; exit 1 ;;
  esac
else
  echo "package-deb.sh: cannot run $arch binaries here (no qemu-aarch64): their features are not checked" >&2
fi

stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
pkg="$stage/cmsckf"
dbg="$stage/cmsckf-dbgsym"
mkdir -p "$pkg/DEBIAN" "$pkg/usr/bin" "$pkg/lib/systemd/system" "$pkg/etc/cmsckf" "$pkg/etc/default" \
  "$pkg/usr/share/doc/cmsckf" "$pkg/usr/share/cmsckf" "$dbg/DEBIAN" "$dbg/usr/lib/debug/.build-id" \
  "$dbg/usr/share/doc/cmsckf-dbgsym"

# Stripped binaries; the debug info apart, named by build id.
build_ids=()
for b in cmsckf cmsckf-frontend; do
  id="$(LC_ALL=C readelf -n "$bin_dir/$b" | sed -n 's/^ *Build ID: \([0-9a-f]*\)$/\1/p' | head -1)"
  [ -n "$id" ] || { echo "package-deb.sh: $b has no GNU build id" >&2; exit 1; }
  debug="$dbg/usr/lib/debug/.build-id/${id:0:2}/${id:2}.debug"
  mkdir -p "$(dirname "$debug")"
  "$objcopy" --only-keep-debug --compress-debug-sections "$bin_dir/$b" "$debug"
  chmod 0644 "$debug"
  "$objcopy" --strip-debug --strip-unneeded --add-gnu-debuglink="$debug" "$bin_dir/$b" "$pkg/usr/bin/$b"
  chmod 0755 "$pkg/usr/bin/$b"
  build_ids+=("$id")
done

# The daemon's unit, as the package's static user (the front-end shares its
# socket directory), from the same file a hand install uses, its install
# notes for a hand install replaced by the package's.
{
  echo "# systemd unit for cmsckf, installed by the Debian package (scripts/package-deb.sh)."
  echo "# The config: /etc/cmsckf/cmsckf.toml. Flight logs: /var/log/cmsckf. The camera"
  echo "# front-end runs as the same user (cmsckf-frontend.service) and reaches the feature"
  echo "# socket in /run/cmsckf (0750; the socket is made 0660)."
  sed -e '1,/^\[Unit\]$/{/^#/d}' config/cmsckf.service
} | sed -e 's|/usr/local/bin/cmsckf|/usr/bin/cmsckf|' \
    -e 's|--config /etc/cmsckf.toml|--config /etc/cmsckf/cmsckf.toml|' \
    -e 's|^DynamicUser=yes$|User=cmsckf\nGroup=cmsckf|' \
    -e 's|^RuntimeDirectoryMode=0700$|RuntimeDirectoryMode=0750|' \
    -e 's|^RuntimeDirectory=cmsckf$|RuntimeDirectory=cmsckf\nRuntimeDirectoryPreserve=restart|' \
    > "$pkg/lib/systemd/system/cmsckf.service"
grep -q '^User=cmsckf$' "$pkg/lib/systemd/system/cmsckf.service" \
  && grep -q '^ExecStart=/usr/bin/cmsckf run --config /etc/cmsckf/cmsckf.toml$' "$pkg/lib/systemd/system/cmsckf.service" \
  || { echo "package-deb.sh: config/cmsckf.service changed shape; update the sed above" >&2; exit 1; }
install -m 0644 packaging/cmsckf-frontend.service "$pkg/lib/systemd/system/cmsckf-frontend.service"
install -m 0644 packaging/cmsckf-frontend.default "$pkg/etc/default/cmsckf-frontend"
# The config: the defaults, with the clock a V4L2 front-end stamps with,
# and the per-frame error such a camera adds that its front-end cannot see:
# a host's stamp jitters by a millisecond or two, 0.05-0.5 px at this
# focal length at a multirotor's turn rates (docs/packaging.md). It weighs
# only with camera.frontend_sigma turned on (off by default).
sed -e 's|^clock = "autopilot"  |clock = "monotonic"  |' \
    -e 's|^model_noise_px = 0.01 |model_noise_px = 0.1  |' config/default.toml > "$pkg/etc/cmsckf/cmsckf.toml"
grep -q '^clock = "monotonic"' "$pkg/etc/cmsckf/cmsckf.toml" \
  || { echo "package-deb.sh: config/default.toml's features.clock line changed shape" >&2; exit 1; }
grep -q '^model_noise_px = 0.1 ' "$pkg/etc/cmsckf/cmsckf.toml" \
  || { echo "package-deb.sh: config/default.toml's camera.model_noise_px line changed shape" >&2; exit 1; }
chmod 0644 "$pkg/etc/cmsckf/cmsckf.toml"
install -m 0644 README.md "$pkg/usr/share/doc/cmsckf/README.md"
install -m 0644 packaging/copyright "$pkg/usr/share/doc/cmsckf/copyright"
install -m 0644 packaging/copyright "$dbg/usr/share/doc/cmsckf-dbgsym/copyright"
# Manual pages, and lintian's override for what it cannot tell from a
# bundled C library.
mkdir -p "$pkg/usr/share/man/man1" "$pkg/usr/share/lintian/overrides"
for m in cmsckf cmsckf-frontend; do
  gzip -9n < "packaging/$m.1" > "$pkg/usr/share/man/man1/$m.1.gz"
  chmod 0644 "$pkg/usr/share/man/man1/$m.1.gz"
done
install -m 0644 packaging/lintian-overrides "$pkg/usr/share/lintian/overrides/cmsckf"
# The bridge for cameras that are not V4L2 (docs/frontend.md).
install -m 0755 scripts/camera-socket.py "$pkg/usr/share/cmsckf/camera-socket.py"
# Debian's changelog, from the package's version and the commit it is built from.
commit="$(git rev-parse --short=12 HEAD 2>/dev/null || echo unknown)"
for d in "$pkg/usr/share/doc/cmsckf" "$dbg/usr/share/doc/cmsckf-dbgsym"; do
  printf '%s (%s) unstable; urgency=medium\n\n  * Built from commit %s.\n\n -- cmsckf developers <cmsckf@users.noreply.github.com>  %s\n' \
    "$(basename "$d")" "$version" "$commit" "$(date -R)" | gzip -9n > "$d/changelog.gz"
  chmod 0644 "$d/changelog.gz"
done

# The newest glibc symbol version the binaries use is the libc6 they need.
glibc="$(for b in cmsckf cmsckf-frontend; do readelf -V -W "$bin_dir/$b"; done \
  | grep -o 'GLIBC_[0-9][0-9.]*' | sed 's/GLIBC_//' | sort -uV | tail -1)"
[ -n "$glibc" ] || { echo "package-deb.sh: no glibc version in the binaries" >&2; exit 1; }

installed_kb="$(du -sk --exclude=DEBIAN "$pkg" | cut -f1)"
cat > "$pkg/DEBIAN/control" <<EOF
Package: cmsckf
Version: $version
Architecture: $arch
Maintainer: cmsckf developers <cmsckf@users.noreply.github.com>
Installed-Size: $installed_kb
Depends: libc6 (>= $glibc), libgcc-s1, adduser, systemd
Recommends: python3
Section: misc
Priority: optional
Description: Compressed MSCKF visual-inertial-GNSS estimator for a drone's autopilot
 cmsckf runs on a drone's companion computer beside ArduPilot or PX4: it
 fuses the autopilot's IMU, raw GNSS observations and a camera's feature
 tracks, sends its estimate back as external navigation with an honest
 covariance, and logs every filter update to MCAP.
 .
 This package holds the daemon, the V4L2 camera front-end, their systemd
 units and the default config.
EOF
printf '/etc/cmsckf/cmsckf.toml\n/etc/default/cmsckf-frontend\n' > "$pkg/DEBIAN/conffiles"
install -m 0755 packaging/postinst "$pkg/DEBIAN/postinst"
install -m 0755 packaging/prerm "$pkg/DEBIAN/prerm"
install -m 0755 packaging/postrm "$pkg/DEBIAN/postrm"

cat > "$dbg/DEBIAN/control" <<EOF
Package: cmsckf-dbgsym
Version: $version
Architecture: $arch
Maintainer: cmsckf developers <cmsckf@users.noreply.github.com>
Installed-Size: $(du -sk --exclude=DEBIAN "$dbg" | cut -f1)
Depends: cmsckf (= $version)
Section: debug
Priority: optional
Description: debug symbols for cmsckf
 The debug information of cmsckf and cmsckf-frontend, for gdb and for
 symbolising a crash report, under /usr/lib/debug/.build-id/ (the build
 ids are in this package's Build-Ids field).
Build-Ids: ${build_ids[*]}
EOF

# Checksums, for `dpkg --verify`.
for d in "$pkg" "$dbg"; do
  (cd "$d" && find . -path ./DEBIAN -prune -o -type f -printf '%P\0' | sort -z | xargs -0 md5sum > DEBIAN/md5sums)
done

mkdir -p "$out"
dpkg-deb --root-owner-group "${compress[@]}" --build "$pkg" "$out/cmsckf_${version}_${arch}.deb" >/dev/null
dpkg-deb --root-owner-group "${compress[@]}" --build "$dbg" "$out/cmsckf-dbgsym_${version}_${arch}.deb" >/dev/null
echo "$out/cmsckf_${version}_${arch}.deb"
echo "$out/cmsckf-dbgsym_${version}_${arch}.deb"
