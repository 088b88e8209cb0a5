#!/usr/bin/env bash
# Build the CUDA driver emulator (tests/cuda_emu/cuda_emu.cpp) as OUT/libcuda.so.1 (and libcuda.so), from the
# device build's entry points (src/gpu/kernels/device.cu) compiled for the host with the host twin's floating
# point (-ffp-contract=off). Rebuilt only when a source is newer; the library is written whole, then moved.
#     bash tests/cuda_emu/build.sh OUT
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
out="${1:?usage: build.sh OUT}"
mkdir -p "$out"
lib="$out/libcuda.so.1"
src=("$root/tests/cuda_emu/cuda_emu.cpp" "$root"/src/gpu/kernels/*.h "$root/src/gpu/kernels/device.cu")
stale=1
if [[ -f "$lib" ]]; then
    stale=0
    for f in "${src[@]}"; do [[ "$f" -nt "$lib" ]] && stale=1; done
fi
if [[ $stale == 1 ]]; then
    tmp="$(mktemp "$out/.libcuda.XXXXXX")"
    "${CXX:-g++}" -std=c++17 -O2 -ffp-contract=off -fno-fast-math -fPIC -shared -fvisibility=hidden -Wall -Wno-unused-function \
        -I "$root/src/gpu/kernels" -x c++ "$root/tests/cuda_emu/cuda_emu.cpp" -o "$tmp"
    mv -f "$tmp" "$lib"
fi
ln -sf libcuda.so.1 "$out/libcuda.so"
echo "$out"
