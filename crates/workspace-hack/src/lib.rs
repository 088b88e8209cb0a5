//! Feature unification for the diffcassi workspace: no code. Its dependencies ask for the union of the
//! features that the workspace's members enable on the `diffcassi` library's dependencies, so that `cargo test`,
//! the C++ bridge, the CMake build and maturin compile the library once (see this crate's Cargo.toml).
#![no_std]
