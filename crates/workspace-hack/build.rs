//! Present so that the `[build-dependencies]` of this feature-unification crate take part in the host-side
//! feature resolution (see Cargo.toml); it builds nothing.
fn main() {}
