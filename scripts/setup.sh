#!/usr/bin/env bash
# Idempotent build-environment setup for diffcassi (Debian/Ubuntu).
#
# Checks that the Rust toolchain is present and installs the Debian packages the build needs,
# only when they are missing. Silent when everything is already there; prints one line per
# package installed. Later native dependencies (Embree, libclang, cmake...) are added by
# appending to APT_PACKAGES.
#
# The plot font is vendored in assets/fonts/, so fonts-dejavu-core is NOT needed.
set -euo pipefail

APT_PACKAGES=(
    pkg-config
    build-essential
)

die() {
    echo "setup.sh: error: $*" >&2
    exit 1
}

# --- Rust toolchain ---------------------------------------------------------------------------
for tool in cargo rustc; do
    if ! command -v "$tool" >/dev/null 2>&1; then
        die "'$tool' not found in PATH. Install Rust (https://rustup.rs: curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh), then open a new shell or run 'source \"\$HOME/.cargo/env\"'."
    fi
done

# --- Debian packages --------------------------------------------------------------------------
is_installed() {
    dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"
}

missing=()
if command -v dpkg-query >/dev/null 2>&1; then
    for pkg in "${APT_PACKAGES[@]}"; do
        is_installed "$pkg" || missing+=("$pkg")
    done
else
    # Not a dpkg-based system: we cannot check, so only complain if apt is expected to work.
    die "dpkg-query not found: this script supports Debian/Ubuntu only. Install the equivalents of: ${APT_PACKAGES[*]}"
fi

if ((${#missing[@]} == 0)); then
    exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
    die "missing Debian packages: ${missing[*]}; apt-get is not available to install them."
fi

SUDO=()
if [[ "$(id -u)" -ne 0 ]]; then
    if command -v sudo >/dev/null 2>&1; then
        SUDO=(sudo)
    else
        die "missing Debian packages: ${missing[*]}; not running as root and sudo is not available. Run: apt-get install ${missing[*]}"
    fi
fi

export DEBIAN_FRONTEND=noninteractive
log=$(mktemp)
trap 'rm -f "$log"' EXIT
if ! "${SUDO[@]}" apt-get update -qq >"$log" 2>&1; then
    cat "$log" >&2
    die "apt-get update failed (needed to install: ${missing[*]})"
fi
if ! "${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >"$log" 2>&1; then
    cat "$log" >&2
    die "apt-get install ${missing[*]} failed"
fi
for pkg in "${missing[@]}"; do
    is_installed "$pkg" || die "apt-get reported success but $pkg is still not installed"
    echo "setup.sh: installed $pkg"
done
