//! Build script. Issue 2 (analytic tracer) needs nothing native; the Embree backend (issue 3) and the
//! C++ bridge (issue 6) hook in here.
fn main() {
    println!("cargo:rerun-if-changed=build.rs");
}
