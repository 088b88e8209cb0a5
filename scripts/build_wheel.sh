#!/usr/bin/env bash
# Build the installable diffcassi wheel: dist/diffcassi-<version>-cp39-abi3-manylinux_2_28_x86_64.whl, which
# `pip install --no-deps` installs on any x86-64 Linux with glibc >= 2.28 and CPython >= 3.9, no Rust needed
# (docs/python.md, "Installing the wheel"). Prints the wheel's path, size and the newest glibc symbol it needs.
#
# Choices (and why):
# * abi3 (python/Cargo.toml: pyo3 `abi3-py39`): one wheel for every CPython >= 3.9 (the GPU machine's 3.12 too).
# * Embree left out (`--no-default-features`): the analytic tracer only, which is what render, the operators,
#   reconstruction, PyTorch and the GPU path use; asking this build for an `embree-*` backend raises
#   DiffcassiValueError saying so (`diffcassi.EMBREE` is False). Bundling Debian's Embree would not be portable:
#   libembree4.so.4 is 41 MB (+ TBB and libstdc++) and needs GLIBC_2.38, so the wheel could only be tagged
#   manylinux_2_38 (no Ubuntu 22.04, Debian 12, RHEL 8/9) and would come close to the 50 MiB limit.
# * manylinux_2_28, honestly: the extension is linked by zig (`maturin --zig`; PyPI's `ziglang` < 0.13, which
#   setup.sh puts into .venv) against glibc 2.28's symbol versions, whatever the build machine's glibc
#   (2.41 here; a native link needs 2.35+). maturin's auditwheel check refuses newer symbols, and this
#   script checks again (objdump: newest GLIBC_ version, NEEDED libraries). 2.28 is what torch >= 2.6's wheels
#   need, so a machine with a current torch can install it.
# * stripped (`--strip`): the release profile keeps line tables (23.4 MB stripped on 2 Dec 2026; the wheel
#   14.2 MiB).
#
# The zig build is a cross build (`--target x86_64-unknown-linux-gnu`), so cargo keeps it in
# $CARGO_TARGET_DIR/x86_64-unknown-linux-gnu/release, apart from the native build that `cargo test` and
# `maturin develop` (scripts/test.sh) use in $CARGO_TARGET_DIR/release: neither invalidates the other, but none of
# the test build is reused (another linker and C compiler). The first run compiles everything (26–41 min on the
# 2-core dev machine with other builds running; about a `cargo build --release` on an idle one), later runs only
# what changed (36 s after a change in python/src). zig's wrappers are named after the maturin that made them: a maturin from another venv rebuilds
# everything once, so this script always uses .venv's.
#
# `--profile NAME` builds with another cargo profile than `release`: the test command's check uses `wheel-check`
# (Cargo.toml: the workspace at opt-level 1, its dependencies at 0, a shorter cold build, the same results bit for bit); a wheel to
# ship or carry to the GPU machine is built with the default.
#
# Usage: bash scripts/build_wheel.sh [--out DIR] [--profile NAME]   (default dist/, release; older diffcassi
# wheels in DIR are removed)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

out=dist
profile=release
while (($#)); do
    case "$1" in
        --out) out=${2:?--out needs a folder}; shift 2 ;;
        --profile) profile=${2:?--profile needs a cargo profile name}; shift 2 ;;
        -h | --help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        *) echo "build_wheel.sh: unknown argument '$1' (usage: bash scripts/build_wheel.sh [--out DIR] [--profile NAME])" >&2; exit 2 ;;
    esac
done

venv="$PWD/.venv"
die() { echo "build_wheel.sh: error: $*" >&2; exit 1; }
[[ -x "$venv/bin/maturin" ]] || die "$venv/bin/maturin not found: run bash scripts/setup.sh (it makes .venv with maturin and ziglang)"
"$venv/bin/python" -c "import ziglang" 2>/dev/null || die "the ziglang package is not in $venv: run bash scripts/setup.sh (or $venv/bin/pip install 'ziglang<0.13')"
command -v objdump >/dev/null || die "objdump (binutils) not found: apt-get install binutils"

GLIBC_MAX=2.28 # the manylinux_2_28 tag below; the check after the build enforces it
mkdir -p "$out"
rm -f "$out"/diffcassi-*.whl
start=$SECONDS
VIRTUAL_ENV="$venv" PATH="$venv/bin:$PATH" "$venv/bin/maturin" build --profile "$profile" --strip --quiet \
    --no-default-features --zig --target x86_64-unknown-linux-gnu --compatibility manylinux_2_28 --out "$out" \
    || die "maturin build failed (above)"
shopt -s nullglob
wheels=("$out"/diffcassi-*.whl)
((${#wheels[@]} == 1)) || die "expected one wheel in $out, found ${#wheels[@]}"
whl=${wheels[0]}
[[ "$(basename "$whl")" == *-cp39-abi3-manylinux_2_28_x86_64.whl ]] || die "unexpected tag: $(basename "$whl") (want cp39-abi3-manylinux_2_28_x86_64)"

# What the wheel holds: the extension and the pure-Python package (weights files included), nothing of the
# repository's other folders.
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$venv/bin/python" - "$whl" "$tmp" <<'EOF'
import sys, zipfile
whl, tmp = sys.argv[1:]
z = zipfile.ZipFile(whl)
names = set(z.namelist())
need = ["diffcassi/__init__.py", "diffcassi/_native.abi3.so", "diffcassi/_native.pyi", "diffcassi/py.typed",
        "diffcassi/torch.py", "diffcassi/unrolled.py", "diffcassi/denoiser.py", "diffcassi/deadleaves.py",
        "diffcassi/_training.py", "diffcassi/_errors.py", "diffcassi/training_data.py",
        "diffcassi/weights/unrolled-gap-v1-sp.safetensors",
        "diffcassi/weights/unrolled-gap-v1-msp.safetensors"]
missing = [n for n in need if n not in names]
stray = sorted(n for n in names if not (n.startswith("diffcassi/") or n.startswith("diffcassi-")) or "__pycache__" in n
               or n.endswith(".pt"))  # training checkpoints stay in the repository (pyproject.toml exclude)
if missing or stray:
    sys.exit(f"build_wheel.sh: {whl}: missing {missing}, unexpected {stray}")
z.extract("diffcassi/_native.abi3.so", tmp)
EOF
so="$tmp/diffcassi/_native.abi3.so"
newest=$(objdump -T "$so" | grep -o 'GLIBC_[0-9.]*' | sed 's/GLIBC_//' | sort -uV | tail -1)
[[ "$(printf '%s\n%s\n' "$newest" "$GLIBC_MAX" | sort -V | tail -1)" == "$GLIBC_MAX" ]] \
    || die "the extension needs GLIBC_$newest, newer than the tag's $GLIBC_MAX"
needed=$(objdump -p "$so" | awk '/NEEDED/ {print $2}' | sort | tr '\n' ' ')
for lib in $needed; do
    case "$lib" in
        libc.so.6 | libm.so.6 | libgcc_s.so.1 | libpthread.so.0 | libdl.so.2 | librt.so.1 | ld-linux-x86-64.so.2) ;;
        *) die "the extension links $lib, which manylinux does not allow (bundle it or leave it out)" ;;
    esac
done
bytes=$(stat -c %s "$whl")
((bytes <= 50 * 1024 * 1024)) || die "$whl is $bytes bytes, over 50 MiB"
echo "build_wheel.sh: $whl (profile $profile; $((bytes / 1024)) KiB; newest glibc symbol GLIBC_$newest; needs: $needed) in $((SECONDS - start)) s"
