#!/usr/bin/env bash
# Idempotent build-environment setup for diffcassi (Debian/Ubuntu).
#
# Checks that the Rust toolchain is present and installs the Debian packages the build needs,
# only when they are missing. Silent when everything is already there; prints one line per
# package installed. Later native dependencies are added by appending to APT_PACKAGES.
#
# Embree >= 4.3 and libclang (for the optional, not yet complete `embree` cargo feature) are installed only
# when asked for with DIFFCASSI_EMBREE=install: the default build does not need them. Embree comes from the
# distribution on Debian >= 13 / Ubuntu >= 24.04. On Debian 12 it can only come from Debian 13 ("trixie"): the script
# first simulates `apt-get install -t trixie libembree-dev` against a temporary apt configuration and
# only if that upgrades NO installed package (libc6, libstdc++6, gcc, dpkg, ...) does it add trixie as a
# pinned source (/etc/apt/sources.list.d/diffcassi-trixie.sources, Pin-Priority 100 in
# /etc/apt/preferences.d/diffcassi-trixie) and install from it. Otherwise it prints one warning line, records
# what would have moved in /var/lib/diffcassi/embree-trixie.refused, and carries on: the default build does
# not need Embree. (Measured on Debian 12.11: trixie's libembree4-4 needs libc6 >= 2.38 and libstdc++6 >= 14,
# so it would upgrade 25 packages, libc6 2.36 -> 2.41 among them; the script therefore refuses there.)
# Environment:
#   DIFFCASSI_EMBREE unset          nothing Embree-related is done (default);
#   DIFFCASSI_EMBREE=install        install libclang-dev and Embree >= 4.3 where that moves no installed package;
#   DIFFCASSI_EMBREE=trixie-force   the same, accepting the upgrades trixie's Embree drags in (throwaway
#                                   containers only).
#
# The plot font is vendored in assets/fonts/, so fonts-dejavu-core is NOT needed.
set -euo pipefail

APT_PACKAGES=(
    pkg-config
    build-essential
    cmake # the C++ API's CMake package and tests (cpp/)
    g++   # C++17 compiler for the C++ API (also in build-essential; listed because cpp/ needs it)
)
if [[ "${DIFFCASSI_EMBREE:-}" == install || "${DIFFCASSI_EMBREE:-}" == trixie-force ]]; then
    APT_PACKAGES+=(libclang-dev) # bindgen, for the embree feature
fi
EMBREE_MIN_VERSION=4.3
TRIXIE_SOURCES=/etc/apt/sources.list.d/diffcassi-trixie.sources
TRIXIE_PREFERENCES=/etc/apt/preferences.d/diffcassi-trixie
TRIXIE_REFUSED=/var/lib/diffcassi/embree-trixie.refused

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

embree_version() {
    is_installed libembree-dev && dpkg-query -W -f='${Version}' libembree-dev 2>/dev/null
}

# True when Embree >= EMBREE_MIN_VERSION should be installed and is not.
embree_wanted() {
    [[ "${DIFFCASSI_EMBREE:-}" == install || "${DIFFCASSI_EMBREE:-}" == trixie-force ]] || return 1
    local v
    v=$(embree_version) || return 0
    ! dpkg --compare-versions "$v" ge "$EMBREE_MIN_VERSION"
}

os_id=$(. /etc/os-release 2>/dev/null && echo "${ID:-}")
os_version=$(. /etc/os-release 2>/dev/null && echo "${VERSION_ID:-}")

if ((${#missing[@]} == 0)) && ! embree_wanted; then
    exit 0
fi

if ! command -v apt-get >/dev/null 2>&1; then
    die "missing Debian packages: ${missing[*]} libembree-dev; apt-get is not available to install them."
fi

SUDO=()
if [[ "$(id -u)" -ne 0 ]]; then
    if command -v sudo >/dev/null 2>&1; then
        SUDO=(sudo)
    else
        die "missing Debian packages: ${missing[*]} libembree-dev; not running as root and sudo is not available. Run: apt-get install ${missing[*]} (and see scripts/setup.sh for Embree)"
    fi
fi

export DEBIAN_FRONTEND=noninteractive
log=$(mktemp)
tmpapt=$(mktemp -d)
trap 'rm -rf "$log" "$tmpapt"' EXIT

apt_install() { # apt_install <description> <apt-get install args...>
    local what=$1
    shift
    if ! "${SUDO[@]}" apt-get update -qq >"$log" 2>&1; then
        cat "$log" >&2
        die "apt-get update failed (needed to install: $what)"
    fi
    if ! "${SUDO[@]}" apt-get install -y -qq --no-install-recommends "$@" >"$log" 2>&1; then
        cat "$log" >&2
        die "apt-get install $* failed"
    fi
}

# --- Base packages ----------------------------------------------------------------------------
if ((${#missing[@]} > 0)); then
    apt_install "${missing[*]}" "${missing[@]}"
    for pkg in "${missing[@]}"; do
        is_installed "$pkg" || die "apt-get reported success but $pkg is still not installed"
        echo "setup.sh: installed $pkg"
    done
fi

# --- Embree >= 4.3 ----------------------------------------------------------------------------
embree_done() {
    local v
    v=$(embree_version) || die "apt-get reported success but libembree-dev is still not installed"
    dpkg --compare-versions "$v" ge "$EMBREE_MIN_VERSION" \
        || die "installed libembree-dev $v but the embree feature needs >= $EMBREE_MIN_VERSION"
    echo "setup.sh: installed libembree-dev $v"
}

embree_unavailable() {
    echo "setup.sh: warning: Embree >= $EMBREE_MIN_VERSION not installed: $*; the optional 'embree' cargo feature is unavailable (the default build does not need it)." >&2
    exit 0
}

trixie_source() {
    cat <<'EOF'
# Added by diffcassi scripts/setup.sh: Debian 13 for libembree-dev >= 4.3 only (pinned to 100 in
# /etc/apt/preferences.d/diffcassi-trixie, so nothing else moves unless asked for with -t trixie).
Types: deb
URIs: http://deb.debian.org/debian
Suites: trixie
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
}

trixie_preferences() {
    cat <<'EOF'
# Added by diffcassi scripts/setup.sh: never prefer Debian 13 packages unless installed with -t trixie.
Package: *
Pin: release n=trixie
Pin-Priority: 100
EOF
}

if ! embree_wanted; then
    exit 0
fi

if [[ "$os_id" == debian && "${os_version%%.*}" -ge 13 ]] 2>/dev/null \
    || { [[ "$os_id" == ubuntu ]] && dpkg --compare-versions "$os_version" ge 24.04; }; then
    apt_install libembree-dev libembree-dev
    embree_done
    exit 0
fi

if [[ "$os_id" != debian || "$os_version" != 12 ]]; then
    embree_unavailable "no known source of libembree-dev >= $EMBREE_MIN_VERSION for $os_id $os_version (install Embree 4.3 and set EMBREE_DIR, see README)"
fi

# Debian 12: trixie, but only if it moves nothing that is already installed.
libc_version=$(dpkg-query -W -f='${Version}' libc6 2>/dev/null || true)
if [[ "${DIFFCASSI_EMBREE:-}" != trixie-force && -f "$TRIXIE_REFUSED" ]] \
    && [[ "$(head -n1 "$TRIXIE_REFUSED")" == "libc6 $libc_version" ]]; then
    embree_unavailable "trixie's libembree-dev would upgrade installed packages (list in $TRIXIE_REFUSED; delete it to re-check)"
fi

mkdir -p "$tmpapt/sources" "$tmpapt/preferences" "$tmpapt/lists/partial"
for f in /etc/apt/sources.list.d/*.sources /etc/apt/sources.list.d/*.list; do
    [[ -f "$f" && "$f" != "$TRIXIE_SOURCES" ]] && cp "$f" "$tmpapt/sources/"
done
[[ -f /etc/apt/sources.list ]] && cp /etc/apt/sources.list "$tmpapt/sources/00-sources.list"
trixie_source >"$tmpapt/sources/diffcassi-trixie.sources"
trixie_preferences >"$tmpapt/preferences/diffcassi-trixie"
chmod -R a+rX "$tmpapt"
tmp_opts=(-o Dir::Etc::SourceList=/dev/null -o "Dir::Etc::SourceParts=$tmpapt/sources"
          -o "Dir::Etc::PreferencesParts=$tmpapt/preferences" -o "Dir::State::Lists=$tmpapt/lists")
if ! "${SUDO[@]}" apt-get "${tmp_opts[@]}" update -qq >"$log" 2>&1; then
    cat "$log" >&2
    die "apt-get update with Debian 13 (trixie) added failed (needed to check libembree-dev)"
fi
if ! "${SUDO[@]}" apt-get "${tmp_opts[@]}" -s install -y --no-install-recommends -t trixie libembree-dev >"$log" 2>&1; then
    cat "$log" >&2
    die "simulated 'apt-get install -t trixie libembree-dev' failed"
fi
# "Inst pkg [installed-version] (new-version ...)": an upgrade of something already installed.
upgrades=$(sed -n 's/^Inst \([^ ]*\) \[\([^]]*\)\] (\([^ ]*\) .*/\1 \2 -> \3/p' "$log")
if [[ -n "$upgrades" && "${DIFFCASSI_EMBREE:-}" != trixie-force ]]; then
    "${SUDO[@]}" mkdir -p "$(dirname "$TRIXIE_REFUSED")"
    { echo "libc6 $libc_version"; echo "$upgrades"; } | "${SUDO[@]}" tee "$TRIXIE_REFUSED" >/dev/null
    embree_unavailable "on Debian 12, 'apt-get install -t trixie libembree-dev' would upgrade $(echo "$upgrades" | wc -l) installed packages ($(echo "$upgrades" | grep -E '^(libc6|libstdc\+\+6|libgcc-s1) ' | tr '\n' ',' | sed 's/,$//; s/,/, /g'), ...; full list in $TRIXIE_REFUSED), which would replace the toolchain's runtime"
fi

trixie_source | "${SUDO[@]}" tee "$TRIXIE_SOURCES" >/dev/null
trixie_preferences | "${SUDO[@]}" tee "$TRIXIE_PREFERENCES" >/dev/null
apt_install "libembree-dev (Debian 13)" -t trixie libembree-dev
"${SUDO[@]}" rm -f "$TRIXIE_REFUSED"
embree_done
