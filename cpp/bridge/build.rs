//! Build script of the C++ bridge: cxx-build generates the C++ side of `src/lib.rs`'s `#[cxx::bridge]`
//! (compiled into this crate's static library) and its header. The header and cxx's `rust/cxx.h` are then
//! refreshed in `cpp/include/` (written only when their content changed, with a cargo warning), so the
//! committed headers are the ones C++ code compiles against; `scripts/test.sh` fails when the build
//! changed them and the change is not committed (a stale header).
use std::env;
use std::fs;
use std::path::{Path, PathBuf};

fn refresh(generated: &Path, committed: &Path) {
    let text = fs::read(generated).unwrap_or_else(|e| panic!("cannot read the generated header {}: {e}", generated.display()));
    if fs::read(committed).ok().as_deref() == Some(text.as_slice()) {
        return;
    }
    if let Some(dir) = committed.parent() {
        fs::create_dir_all(dir).unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
    }
    match fs::write(committed, &text) {
        Ok(()) => println!("cargo:warning=regenerated {} from the cxx bridge: commit it", committed.display()),
        Err(e) => println!("cargo:warning={} is stale and cannot be rewritten ({e}); C++ builds would use the stale copy", committed.display()),
    }
}

fn main() {
    cxx_build::bridge("src/lib.rs").std("c++17").flag_if_supported("-Wno-unused-parameter").compile("diffcassi_cpp_bridge");
    println!("cargo:rerun-if-changed=src/lib.rs");

    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let include = manifest.parent().expect("cpp/bridge has a parent").join("include");
    let bridge_h = include.join("diffcassi/bridge.h");
    let cxx_h = include.join("rust/cxx.h");
    refresh(&out.join("cxxbridge/include/diffcassi-cpp/src/lib.rs.h"), &bridge_h);
    // The cxx crate (links = "cxxbridge1") tells its dependents where its header is.
    let cxx_src = env::var_os("DEP_CXXBRIDGE1_HEADER").map(PathBuf::from).expect("the cxx crate exports DEP_CXXBRIDGE1_HEADER");
    refresh(&cxx_src, &cxx_h);
    // Re-run (and restore them) when someone edits or deletes the committed copies.
    println!("cargo:rerun-if-changed={}", bridge_h.display());
    println!("cargo:rerun-if-changed={}", cxx_h.display());
}
