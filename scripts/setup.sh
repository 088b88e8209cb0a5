#!/usr/bin/env bash
# Idempotent build-environment setup for diffcassi (Debian/Ubuntu).
#
# Checks that the Rust toolchain is present and installs the Debian packages the build needs,
# only when they are missing. Silent when everything is already there; prints one line per
# package installed. Later native dependencies are added by appending to APT_PACKAGES.
#
# Embree >= 4.3 (the default `embree` cargo feature) and libclang (bindgen) are installed too, unless
# DIFFCASSI_EMBREE=skip (for `cargo build --no-default-features`, the analytic tracer alone). Embree comes from
# the distribution on Debian >= 13 / Ubuntu >= 24.04. On Debian 12 it comes from Debian 13 ("trixie"): the script
# adds trixie as an apt source (/etc/apt/sources.list.d/diffcassi-trixie.sources) pinned to priority 100
# (/etc/apt/preferences.d/diffcassi-trixie), so nothing moves to trixie unless asked for, and runs
# `apt-get install -t trixie libembree-dev`: only libembree and what it requires move. Measured on a fresh
# Debian 12 (debootstrap bookworm, 2026-11-22): that upgrades 21 packages -- libc6 2.36 -> 2.41, libstdc++6 and the
# gcc runtime libraries 12 -> 14, dpkg, base-files (so /etc/os-release then reads 13) -- and installs 8
# (libembree4-4 4.3.3, TBB 2022); afterwards gcc-12/g++-12, cargo/rustc and the whole test suite
# (including `--features embree`) still build and pass. Environment:
#   DIFFCASSI_EMBREE unset or =install   install Embree >= 4.3 + libclang-dev (default);
#   DIFFCASSI_EMBREE=skip                do nothing Embree-related (build with --no-default-features).
#
# The plot font is vendored in assets/fonts/, so fonts-dejavu-core is NOT needed.
set -euo pipefail

APT_PACKAGES=(
    pkg-config
    build-essential
    cmake # the C++ API's CMake package and tests (cpp/)
    g++   # C++17 compiler for the C++ API (also in build-essential; listed because cpp/ needs it)
    # The real Slurm test (tests/slurm/run.sh, docs/slurm.md): a one-node cluster started by the test itself
    # (Debian 12 ships Slurm 22.05). With systemd, installing these enables the distribution's munge/slurm
    # services; the test does not use them (its daemons run in a private network namespace with their own
    # key, socket and configuration in a temporary folder).
    munge
    jq # JSON in tests/slurm/run.sh (the tasks' JSON Lines, render.json without timings)
    slurm-client
    slurmctld
    slurmd
    python3-venv # the Python package's venv (.venv/, below)
)
case "${DIFFCASSI_EMBREE:-install}" in
    install) WANT_EMBREE=1 ;;
    skip) WANT_EMBREE=0 ;;
    *) echo "setup.sh: error: DIFFCASSI_EMBREE=${DIFFCASSI_EMBREE} (expected install or skip)" >&2; exit 1 ;;
esac
if ((WANT_EMBREE)); then
    APT_PACKAGES+=(libclang-dev) # bindgen, for the embree feature
fi
EMBREE_MIN_VERSION=4.3
TRIXIE_SOURCES=/etc/apt/sources.list.d/diffcassi-trixie.sources
TRIXIE_PREFERENCES=/etc/apt/preferences.d/diffcassi-trixie

# --- Python package (docs/python.md) -------------------------------------------------------
# A venv under the repository (.venv/) with maturin, ziglang, numpy, scipy, pytest and PyTorch (PyPI's default wheel;
# DIFFCASSI_TORCH=skip leaves torch out and the torch tests then SKIP with the reason); DIFFCASSI_PYTHON=skip
# skips the whole venv. Silent when everything is there.
REPO_ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
python_setup() {
    [[ "${DIFFCASSI_PYTHON:-install}" == skip ]] && return 0
    local venv="$REPO_ROOT/.venv" py=python3
    [[ -x /usr/bin/python3 ]] && py=/usr/bin/python3
    if [[ ! -x "$venv/bin/python" ]]; then
        "$py" -m venv "$venv" || die "cannot create the Python venv $venv (python3-venv missing?)"
        echo "setup.sh: created the Python venv .venv/"
    fi
    # module=pip-name where they differ. The learned denoiser (docs/reconstruction.md, src/recon/prior/MODEL.md)
    # needs safetensors (its weights files) and colour-science (BSD-3: the measured reflectances of its training data);
    # the unrolled network's v2 training data (diffcassi/training_data.py) also lifts textures from the sample images
    # shipped inside the scikit-image wheel (brick, grass, … only; nothing downloaded); rayoptics is the independent .zmx reader of tests/python/test_zmx.py. ziglang: the linker of the portable
    # wheel (scripts/build_wheel.sh: `maturin --zig`, glibc 2.28 symbols; maturin supports zig < 0.13).
    local want=(maturin numpy scipy pytest rayoptics "ziglang=ziglang<0.13")
    [[ "${DIFFCASSI_TORCH:-install}" == skip ]] || want+=(torch safetensors colour=colour-science skimage=scikit-image)
    local missing_py=()
    for m in "${want[@]}"; do
        "$venv/bin/python" -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('${m%%=*}') is None)" 2>/dev/null || missing_py+=("${m#*=}")
    done
    if ((${#missing_py[@]} > 0)); then
        "$venv/bin/pip" install -q "${missing_py[@]}" || die "pip install ${missing_py[*]} into .venv failed"
        echo "setup.sh: installed into .venv: ${missing_py[*]}"
    fi
    # The GPU kernels' device build (docs/gpu.md, scripts/gpu/build_ptx.py): NVRTC and ptxas at CUDA 13.0, the
    # GPU machine's driver (580.159: a driver takes the PTX ISA of its own CUDA version and older ones, and NVRTC
    # 13.2 — torch's — writes ISA 9.2, which that driver refuses), in a folder of their own (.venv/cuda-ptx:
    # torch pins its own NVRTC). No GPU or driver is needed for either.
    [[ "${DIFFCASSI_TORCH:-install}" == skip ]] && return 0
    # The GPU machine has no colour-science and no network: scripts/gpu/train_run.sh installs the wheel carried in
    # .whl/ (pure Python, 9 MB), downloaded here from PyPI at the version .venv holds. Not needed by the tests: a
    # failed download is a warning.
    local cs_version
    cs_version=$("$venv/bin/python" -c "import importlib.metadata as m; print(m.version('colour-science'))" 2>/dev/null) || cs_version=""
    if [[ -n "$cs_version" ]] && ! compgen -G "$REPO_ROOT/.whl/colour_science-$cs_version-*.whl" >/dev/null; then
        if "$venv/bin/pip" download -q --disable-pip-version-check --no-deps --only-binary=:all: -d "$REPO_ROOT/.whl" "colour-science==$cs_version"; then
            echo "setup.sh: downloaded colour-science $cs_version's wheel into .whl/ (carried to the GPU machine)"
        else
            echo "setup.sh: warning: could not download colour-science $cs_version's wheel into .whl/ (only a GPU training run needs it)" >&2
        fi
    fi
    local ptx_dir="$venv/cuda-ptx" ptx_version=13.0.88
    if [[ "$(cat "$ptx_dir/VERSION" 2>/dev/null)" != "$ptx_version" ]]; then
        rm -rf "$ptx_dir"
        "$venv/bin/pip" install -q --disable-pip-version-check --no-deps --target "$ptx_dir" \
            "nvidia-cuda-nvrtc==$ptx_version" "nvidia-cuda-nvcc==$ptx_version" || die "pip install of NVRTC and ptxas $ptx_version into $ptx_dir failed"
        echo "$ptx_version" > "$ptx_dir/VERSION"
        echo "setup.sh: installed NVRTC and ptxas $ptx_version (the GPU machine's CUDA 13.0) into .venv/cuda-ptx"
    fi
}

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
    ((WANT_EMBREE)) || return 1
    [[ -z "${EMBREE_DIR:-}" ]] || return 1 # the user points build.rs at their own Embree
    local v
    v=$(embree_version) || return 0
    ! dpkg --compare-versions "$v" ge "$EMBREE_MIN_VERSION"
}

os_id=$(. /etc/os-release 2>/dev/null && echo "${ID:-}")
os_version=$(. /etc/os-release 2>/dev/null && echo "${VERSION_ID:-}")

if ((${#missing[@]} == 0)) && ! embree_wanted; then
    python_setup
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

trap 'rm -f "$log"' EXIT

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
    die "Embree >= $EMBREE_MIN_VERSION cannot be installed: $*. Set EMBREE_DIR to an Embree 4.3 install, or build without Embree (DIFFCASSI_EMBREE=skip, cargo --no-default-features)."
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
    python_setup
    exit 0
fi

if [[ "$os_id" == debian && "${os_version%%.*}" -ge 13 ]] 2>/dev/null \
    || { [[ "$os_id" == ubuntu ]] && dpkg --compare-versions "$os_version" ge 24.04; }; then
    apt_install libembree-dev libembree-dev
    embree_done
    python_setup
    exit 0
fi

if [[ "$os_id" != debian || "$os_version" != 12 ]]; then
    embree_unavailable "no known source of libembree-dev >= $EMBREE_MIN_VERSION for $os_id $os_version (install Embree 4.3 and set EMBREE_DIR, see README)"
fi

# Debian 12: from Debian 13 (trixie), pinned to 100 so only libembree and what it requires move.
trixie_source | "${SUDO[@]}" tee "$TRIXIE_SOURCES" >/dev/null
trixie_preferences | "${SUDO[@]}" tee "$TRIXIE_PREFERENCES" >/dev/null
apt_install "libembree-dev (Debian 13)" -t trixie libembree-dev
"${SUDO[@]}" rm -rf /var/lib/diffcassi/embree-trixie.refused
embree_done
python_setup
