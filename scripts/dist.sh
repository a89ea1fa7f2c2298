#!/usr/bin/env bash
# Packs a relocatable release of the tools built in PROFILE_DIR (target/release for `make
# dist`; tests/dist.rs packs the ci profile's):
#
#   scripts/dist.sh PROFILE_DIR [OUT_DIR]     -> OUT_DIR/nimbus-VERSION-linux-x86_64.tar.xz
#
# OUT_DIR defaults to dist/. NIMBUS_DIST_XZ sets xz's level (default 6; tests use 0). The
# tarball's path is printed on stdout.
#
# The binaries are stripped and find their libraries through an rpath of $ORIGIN/../lib. Every
# shared library they load that a bare Linux x86-64 lacks goes into lib/ (resolved by ldd,
# whose answer is the whole closure); only glibc's and GCC's runtime (SYSTEM below) stay the
# system's, because they are on every distribution and a copy of libc must match the system's
# ld.so. The Vulkan loader is bundled too, although wgpu dlopens it and ldd never names it: a
# GPU node often has a driver (its ICD) without the loader (containers given a driver by the
# NVIDIA toolkit, runfile installs), and the loader is the one Vulkan piece with a stable ABI
# that reads whatever ICD the system registers (deleting lib/libvulkan.so.1 falls back to the
# system's).
#
# The rpath is the executables' DT_RPATH, not DT_RUNPATH: ld.so applies an executable's
# DT_RPATH to its libraries' dependencies too (libopenvdb's blosc, log4cplus, ...) and to what
# it dlopens, so the libraries ship as Debian built them. Giving each library a RUNPATH of
# $ORIGIN instead would have patchelf move libopenvdb's 22.5 MB .dynstr (its dynamic symbols'
# names) to grow it, a copy that made it 80 MB instead of 57. The price: LD_LIBRARY_PATH
# cannot override lib/.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)

die() { echo "dist.sh: error: $*" >&2; exit 2; }
[ $# -ge 1 ] && [ $# -le 2 ] || die "usage: scripts/dist.sh PROFILE_DIR [OUT_DIR]"
profile=$1
out_dir=${2:-$root/dist}
[ -d "$profile" ] || die "no such profile directory: $profile"
level=${NIMBUS_DIST_XZ:-6}
[[ $level =~ ^[0-9]$ ]] || die "NIMBUS_DIST_XZ must be an xz level 0-9, not '$level'"
for tool in ldd patchelf strip objdump tar xz dpkg-query; do
    command -v "$tool" >/dev/null || die "$tool is missing (scripts/install-deps.sh installs it)"
done

# What users run (the chain, the sequence driver, the test scenes and the image comparison
# scripts/bench_gpu.sh needs), and the particle generator of the analytic scenes (an example of
# nimbus-density: the Cloud1-class particles are made where the benchmark runs, not carried).
BINS=(particles2vdb vdbphoton vdbcache vdbmarch nimbus-render nimbus-scene nimbus-compare)
EXAMPLES=(gen_particles)
# Present on every glibc Linux: glibc's libraries, its loader, GCC's runtime.
SYSTEM=(linux-vdso.so.1 ld-linux-x86-64.so.2 libc.so.6 libm.so.6 libpthread.so.0 libdl.so.2
        librt.so.1 libutil.so.1 libresolv.so.2 libanl.so.1 libmvec.so.1 libgcc_s.so.1 libstdc++.so.6)
# dlopened, so invisible to ldd.
DLOPENED=(libvulkan.so.1)

version=$(sed -n '/^\[workspace.package\]/,/^\[/s/^version *= *"\(.*\)"/\1/p' "$root/Cargo.toml")
[ -n "$version" ] || die "no version under [workspace.package] in $root/Cargo.toml"
name=nimbus-$version-linux-x86_64
tarball=$out_dir/$name.tar.xz

stage=$(mktemp -d)
partial=
cleanup() { rm -rf "$stage"; [ -z "$partial" ] || rm -f "$partial"; }
trap cleanup EXIT
release=$stage/$name
mkdir -p "$release/bin" "$release/lib" "$release/licenses" "$release/scripts"

is_system() { local s; for s in "${SYSTEM[@]}"; do [ "$1" = "$s" ] && return 0; done; return 1; }

# "SONAME PATH" per library FILE loads, system ones left out; dies on any that is not found.
libraries_of() {
    local report
    report=$(env -u LD_LIBRARY_PATH -u LD_PRELOAD ldd "$1" 2>&1) || die "ldd $1: $report"
    if grep -q "not found" <<<"$report"; then
        die "$1 needs libraries this machine lacks: $(grep "not found" <<<"$report" | awk '{print $1}' | tr '\n' ' ')"
    fi
    awk '$2 == "=>" && $3 ~ /^\// {print $1, $3}' <<<"$report" | while read -r soname path; do
        is_system "$soname" || echo "$soname $path"
    done
}

for b in "${BINS[@]}"; do
    [ -x "$profile/$b" ] || die "$profile/$b is missing (build it: cargo build --workspace --bins with that profile)"
    cp "$profile/$b" "$release/bin/$b"
done
for e in "${EXAMPLES[@]}"; do
    [ -x "$profile/examples/$e" ] || die "$profile/examples/$e is missing (build it: cargo build -p nimbus-density --example $e with that profile)"
    cp "$profile/examples/$e" "$release/bin/$e"
done

# The closure: the binaries' libraries and the dlopened ones', and theirs, until nothing new.
declare -A found=()
queue=("$release"/bin/*)
for soname in "${DLOPENED[@]}"; do
    path=$(ldconfig -p | awk -v s="$soname" '$1 == s && /x86-64/ {print $NF; exit}')
    [ -n "$path" ] || die "$soname is not installed (Debian: libvulkan1); the release bundles it"
    found[$soname]=$path
    queue+=("$path")
done
while [ ${#queue[@]} -gt 0 ]; do
    next=()
    for file in "${queue[@]}"; do
        while read -r soname path; do
            [ -n "$soname" ] && [ -z "${found[$soname]:-}" ] || continue
            found[$soname]=$path
            next+=("$path")
        done < <(libraries_of "$file")
    done
    queue=("${next[@]+"${next[@]}"}")
done

for soname in "${!found[@]}"; do
    cp -L "${found[$soname]}" "$release/lib/$soname"
    chmod 644 "$release/lib/$soname"
    # The library's licence, from the Debian package that installed it.
    real=$(readlink -f "${found[$soname]}")
    package=$(dpkg-query -S "$real" 2>/dev/null | head -n 1 | cut -d: -f1) || true
    [ -n "$package" ] || package=$(dpkg-query -S "${found[$soname]}" 2>/dev/null | head -n 1 | cut -d: -f1) || true
    [ -n "$package" ] && [ -f "/usr/share/doc/$package/copyright" ] || die "no Debian package or copyright file for ${found[$soname]}: its licence cannot ship"
    cp "/usr/share/doc/$package/copyright" "$release/licenses/$package.copyright"
    echo "$soname $package" >>"$stage/packages.txt"
done
for b in "$release"/bin/*; do
    strip "$b"
    patchelf --force-rpath --set-rpath '$ORIGIN/../lib' "$b"
done

# The release must hold together by itself: every library ldd resolves for a binary outside
# the system's must be one of ours. (The libraries alone would resolve their dependencies
# from the system: they have no rpath of their own.)
for file in "$release"/bin/*; do
    while read -r soname path; do
        case $(readlink -f "$path") in
            "$release"/lib/*) ;;
            *) die "$file loads $soname from $path, not from the release's lib/" ;;
        esac
    done < <(libraries_of "$file")
done

# What the system must provide: the newest glibc and libstdc++ symbol versions used.
newest() { objdump -T "$release"/bin/* "$release"/lib/* | grep -o "$1[0-9.]*" | sort -uV | tail -n 1; }
glibc=$(newest 'GLIBC_2\.')
glibcxx=$(newest 'GLIBCXX_3\.')
build_system=$(. /etc/os-release 2>/dev/null && echo "${PRETTY_NAME:-unknown}")

cp "$root/README.md" "$release/README.md"
cp -r "$root/data" "$release/data"
cp "$root/scripts/demo.sh" "$root/scripts/demo_scenes.sh" "$root/scripts/bench_gpu.sh" "$release/scripts/"
cat >"$release/INSTALL" <<EOF
nimbus $version for Linux x86-64, built on $build_system.

Unpack anywhere and run the tools from bin/ (they find their libraries in lib/ by
themselves; no install step, no LD_LIBRARY_PATH):

    tar -xJf $name.tar.xz
    cd $name
    bin/particles2vdb data/plume.ply --voxel-size 2 | bin/vdbcache | bin/vdbmarch -o plume.exr
    BIN=bin scripts/demo.sh        # the README's demo scenes into out/

Or put bin/ on your PATH. What the system must provide:

  - glibc ${glibc#GLIBC_} or newer, and GCC's libstdc++ with $glibcxx and libgcc_s (as on
    $build_system and newer).
  - For --device gpu (and --device auto picking a GPU) a Vulkan driver (ICD), such as
    NVIDIA's, Mesa's radv or anv, or lavapipe for a software GPU. The Vulkan loader is in
    lib/ (libvulkan.so.1); delete it to use the system's. Without a driver --device auto
    runs on the CPU.

bin/ holds the chain (particles2vdb, vdbphoton, vdbcache, vdbmarch), the frame-sequence
driver nimbus-render, nimbus-scene (test scenes as density VDBs), gen_particles (analytic
particle sets: gen_particles cloud1 cloud1.ply) and nimbus-compare (relative RMSE of an
image against a reference). Each tool's --help lists its flags.
EOF
{
    echo "nimbus $version is licensed under MIT OR Apache-2.0, at your option."
    echo
    echo "lib/ holds these libraries from $build_system, each under its own licence,"
    echo "in licenses/PACKAGE.copyright:"
    echo
    sort "$stage/packages.txt" | awk '{printf "    %-32s %s\n", $1, $2}'
    echo
    echo "data/: see data/README.md."
} >"$release/LICENSE"

mkdir -p "$out_dir"
partial=$tarball.partial
# Owner, order and times fixed, so the same build packs to the same bytes.
tar -C "$stage" --owner=0 --group=0 --numeric-owner --sort=name --mtime=@0 -cf - "$name" \
    | xz -T0 "-$level" >"$partial"
size=$(stat -c %s "$partial")
limit=$((64 * 1024 * 1024))
[ "$size" -lt "$limit" ] || die "$tarball would be $size bytes, over the 64 MiB limit"
mv "$partial" "$tarball"
partial=
echo "dist.sh: $tarball: $((size / 1024)) KiB packed, $(du -sk "$release" | cut -f1) KiB unpacked; needs $glibc, $glibcxx" >&2
echo "$tarball"
