#!/usr/bin/env bash
# Installs hood's C libraries under PREFIX, for CMake (find_package(hood) -> hood::hood) and
# pkg-config (hood):
#
#   ffi/install.sh PREFIX
#
#   PREFIX/include/hood.h
#   PREFIX/lib/libhood_ffi.so.X.Y.Z, with the SONAME link and libhood_ffi.so
#   PREFIX/lib/libhood_ffi.a
#   PREFIX/lib/cmake/hood/hoodConfig.cmake, hoodConfigVersion.cmake
#   PREFIX/lib/pkgconfig/hood.pc
#
# It first builds the libraries with the ffi-release profile (release code, no debug info), unless
# HOOD_FFI_LIB_DIR names a directory that already holds libhood_ffi.a and libhood_ffi.so. The
# layout is that of ELF systems (Linux, the BSDs).
set -euo pipefail
prefix=${1:?usage: ffi/install.sh PREFIX}
here=$(cd "$(dirname "$0")" && pwd)

version=$(sed -n 's/^version = "\(.*\)"$/\1/p' "$here/Cargo.toml" | head -n 1)
major=${version%%.*}
minor=${version#*.}
minor=${minor%%.*}
if [ "$major" = 0 ]; then abi="0.$minor"; else abi="$major"; fi

if [ -n "${HOOD_FFI_LIB_DIR:-}" ]; then
  libs=$HOOD_FFI_LIB_DIR
else
  cargo build --manifest-path "$here/Cargo.toml" -p hood-ffi --lib --profile ffi-release
  libs=${CARGO_TARGET_DIR:-$here/../target}/ffi-release
fi
for f in libhood_ffi.a libhood_ffi.so; do
  [ -f "$libs/$f" ] || { echo "install.sh: $libs/$f is missing" >&2; exit 1; }
done

mkdir -p "$prefix"
prefix=$(cd "$prefix" && pwd)
mkdir -p "$prefix/include" "$prefix/lib/cmake/hood" "$prefix/lib/pkgconfig"
install -m 644 "$here/include/hood.h" "$prefix/include/hood.h"
install -m 644 "$libs/libhood_ffi.a" "$prefix/lib/libhood_ffi.a"
install -m 755 "$libs/libhood_ffi.so" "$prefix/lib/libhood_ffi.so.$version"
if command -v strip >/dev/null 2>&1; then
  # The static library carries the Rust standard library's debug info: drop it.
  strip --strip-debug "$prefix/lib/libhood_ffi.a" "$prefix/lib/libhood_ffi.so.$version"
fi
ln -sf "libhood_ffi.so.$version" "$prefix/lib/libhood_ffi.so.$abi"
ln -sf "libhood_ffi.so.$abi" "$prefix/lib/libhood_ffi.so"

fill() {
  sed -e "s|@PREFIX@|$prefix|g" -e "s|@VERSION@|$version|g" -e "s|@MAJOR@|$major|g" \
      -e "s|@MINOR@|$minor|g" -e "s|@ABI@|$abi|g" "$1" > "$2"
}
fill "$here/cmake/hoodConfig.cmake.in" "$prefix/lib/cmake/hood/hoodConfig.cmake"
fill "$here/cmake/hoodConfigVersion.cmake.in" "$prefix/lib/cmake/hood/hoodConfigVersion.cmake"
fill "$here/hood.pc.in" "$prefix/lib/pkgconfig/hood.pc"
echo "installed hood $version under $prefix"
