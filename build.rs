//! Build script. Issue 2 (analytic tracer) needs nothing native; the Embree backend (issue 3) and the
//! C++ bridge (issue 6) hook in here.
//!
//! With the `embree` feature: find Embree >= 4.3 (EMBREE_DIR if set, else pkg-config `embree4`, else the
//! CMake package config under /usr/lib/*/cmake/embree-*), generate bindings from the INSTALLED headers with
//! bindgen, compile a C program against the same headers that reports sizeof/alignof/offsetof of the
//! structs we pass to Embree (checked against the Rust layouts at compile time in
//! src/tracer/embree/sys.rs), and a tiny C shim for Embree's `static inline` initialisers.
//! Without the feature this script does nothing.
fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    gpu_twin();
    #[cfg(feature = "embree")]
    embree::build();
}

/// The host build of the GPU kernels (src/gpu/kernels, docs/gpu.md): the same C headers the device PTX is
/// compiled from, built as C99 without floating-point contraction so that the CPU twin computes what the
/// device computes, and linked into the library (src/gpu/twin.rs calls it; the tests compare it with the
/// Rust kernels).
fn gpu_twin() {
    for f in ["dc_common.h", "dc_vec_tmpl.h", "dc_trace.h", "dc_trace_tmpl.h", "dc_sample.h", "dc_render.h", "dc_accum.h", "host.c"] {
        println!("cargo:rerun-if-changed=src/gpu/kernels/{f}");
    }
    cc::Build::new()
        .file("src/gpu/kernels/host.c")
        .include("src/gpu/kernels")
        .std("c99")
        .opt_level(2)
        .flag_if_supported("-ffp-contract=off")
        .flag_if_supported("-fno-fast-math")
        .warnings(true)
        .extra_warnings(true)
        .compile("diffcassi_gpu_twin");
}

#[cfg(feature = "embree")]
mod embree {
    use std::env;
    use std::fs;
    use std::path::{Path, PathBuf};
    use std::process::Command;

    const MIN: (u32, u32) = (4, 3);

    struct Found {
        how: String,
        include: PathBuf,
        lib_dirs: Vec<PathBuf>,
    }

    fn install_hint() -> String {
        "Embree >= 4.3 with its headers is needed for the `embree` feature. Install it with \
         `DIFFCASSI_EMBREE=install bash scripts/setup.sh` (Debian >= 13 / Ubuntu >= 24.04: `apt-get install libembree-dev libclang-dev`; \
         Debian 12: add Debian 13 \"trixie\" as an apt source pinned to priority 100 and run \
         `apt-get install -t trixie libembree-dev` -- note that on Debian 12 this upgrades libc6/libstdc++6, \
         which setup.sh refuses to do unless DIFFCASSI_EMBREE=trixie-force), or build/unpack Embree 4.3 \
         somewhere and set EMBREE_DIR to the directory holding include/embree4/rtcore.h and lib/libembree4.so. \
         Or build without `--features embree`."
            .to_string()
    }

    fn version_of(include: &Path) -> Option<(u32, u32, String)> {
        let cfg = fs::read_to_string(include.join("embree4/rtcore_config.h")).ok()?;
        let get = |name: &str| -> Option<String> {
            cfg.lines().find_map(|l| {
                let mut it = l.split_whitespace();
                (it.next() == Some("#define") && it.next() == Some(name)).then(|| it.next().map(str::to_string)).flatten()
            })
        };
        let major = get("RTC_VERSION_MAJOR")?.parse().ok()?;
        let minor = get("RTC_VERSION_MINOR")?.parse().ok()?;
        let patch = get("RTC_VERSION_PATCH").unwrap_or_else(|| "?".into());
        Some((major, minor, format!("{major}.{minor}.{patch}")))
    }

    fn from_dir(dir: &Path, how: &str) -> Option<Found> {
        let include = dir.join("include");
        if !include.join("embree4/rtcore.h").is_file() {
            return None;
        }
        let lib_dirs = ["lib", "lib64", "lib/x86_64-linux-gnu", "lib/aarch64-linux-gnu"]
            .iter()
            .map(|d| dir.join(d))
            .filter(|d| d.is_dir())
            .collect();
        Some(Found { how: how.to_string(), include, lib_dirs })
    }

    fn from_pkg_config() -> Option<Found> {
        let out = Command::new("pkg-config").args(["--cflags-only-I", "--libs-only-L", "embree4"]).output().ok()?;
        if !out.status.success() {
            return None;
        }
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        let mut include = None;
        let mut lib_dirs = Vec::new();
        for tok in text.split_whitespace() {
            if let Some(p) = tok.strip_prefix("-I") {
                if Path::new(p).join("embree4/rtcore.h").is_file() {
                    include = Some(PathBuf::from(p));
                }
            } else if let Some(p) = tok.strip_prefix("-L") {
                lib_dirs.push(PathBuf::from(p));
            }
        }
        let include = include.or_else(|| {
            ["/usr/include", "/usr/local/include"].iter().map(PathBuf::from).find(|p| p.join("embree4/rtcore.h").is_file())
        })?;
        Some(Found { how: "pkg-config embree4".into(), include, lib_dirs })
    }

    fn from_cmake() -> Option<Found> {
        let mut candidates = Vec::new();
        for base in ["/usr/lib", "/usr/local/lib", "/usr/lib64", "/usr/local/lib64"] {
            let mut dirs = vec![PathBuf::from(base)];
            if let Ok(rd) = fs::read_dir(base) {
                dirs.extend(rd.flatten().map(|e| e.path()).filter(|p| p.is_dir()));
            }
            for d in dirs {
                if let Ok(rd) = fs::read_dir(d.join("cmake")) {
                    for e in rd.flatten() {
                        let name = e.file_name().to_string_lossy().to_string();
                        if name.starts_with("embree-") && e.path().join("embree-config.cmake").is_file() {
                            candidates.push((d.clone(), e.path()));
                        }
                    }
                }
            }
        }
        candidates.sort();
        for (libdir, cfgdir) in candidates.into_iter().rev() {
            // <prefix>/lib[/<triplet>]/cmake/embree-X.Y.Z: find <prefix>/include/embree4.
            let mut prefix = libdir.parent().map(Path::to_path_buf);
            while let Some(p) = prefix {
                if p.join("include/embree4/rtcore.h").is_file() {
                    return Some(Found {
                        how: format!("CMake config {}", cfgdir.join("embree-config.cmake").display()),
                        include: p.join("include"),
                        lib_dirs: vec![libdir],
                    });
                }
                prefix = p.parent().map(Path::to_path_buf);
            }
        }
        None
    }

    pub fn build() {
        println!("cargo:rerun-if-env-changed=EMBREE_DIR");
        println!("cargo:rerun-if-env-changed=PKG_CONFIG_PATH");
        let found = match env::var_os("EMBREE_DIR") {
            // An explicit EMBREE_DIR wins; a wrong one is an error rather than silently ignored.
            Some(dir) => from_dir(Path::new(&dir), "EMBREE_DIR").unwrap_or_else(|| {
                panic!("EMBREE_DIR={} has no include/embree4/rtcore.h.\n{}", Path::new(&dir).display(), install_hint())
            }),
            None => from_pkg_config()
                .or_else(from_cmake)
                .unwrap_or_else(|| panic!("Embree 4 not found (tried EMBREE_DIR, pkg-config embree4, /usr/lib/*/cmake/embree-*/embree-config.cmake).\n{}", install_hint())),
        };
        let (major, minor, version) = version_of(&found.include)
            .unwrap_or_else(|| panic!("{}: cannot read RTC_VERSION_* from embree4/rtcore_config.h.\n{}", found.include.display(), install_hint()));
        if (major, minor) < MIN {
            panic!("Embree {version} found via {} ({}), but >= {}.{} is needed.\n{}", found.how, found.include.display(), MIN.0, MIN.1, install_hint());
        }
        for d in &found.lib_dirs {
            println!("cargo:rustc-link-search=native={}", d.display());
        }
        println!("cargo:rustc-link-lib=dylib=embree4");
        println!("cargo:rerun-if-changed={}", found.include.join("embree4/rtcore_config.h").display());
        println!("cargo:rerun-if-changed=src/tracer/embree/shim.cpp");
        println!("cargo:rustc-env=DIFFCASSI_EMBREE_VERSION={version}");
        println!("cargo:rustc-env=DIFFCASSI_EMBREE_FOUND_VIA={}", found.how);

        let out = PathBuf::from(env::var("OUT_DIR").unwrap());
        let include = found.include.display().to_string();

        // 1. Bindings from the installed headers.
        let bindings = bindgen::Builder::default()
            .header_contents("embree_wrapper.h", "#include <embree4/rtcore.h>\n")
            .clang_arg(format!("-I{include}"))
            .allowlist_function("rtc.*")
            .allowlist_type("RTC.*")
            .allowlist_var("RTC.*")
            .default_enum_style(bindgen::EnumVariation::Consts)
            .prepend_enum_name(false)
            .derive_default(true)
            .layout_tests(true)
            .generate()
            .unwrap_or_else(|e| panic!("bindgen over {include}/embree4/rtcore.h failed: {e} (is libclang-dev installed? `DIFFCASSI_EMBREE=install bash scripts/setup.sh`)"));
        bindings.write_to_file(out.join("embree_bindings.rs")).expect("write embree_bindings.rs");

        // 2. The C++ shim for the `static inline` initialisers and the RTCRayHitN accessors (same headers).
        cc::Build::new().cpp(true).file("src/tracer/embree/shim.cpp").include(&found.include).warnings(true).compile("diffcassi_embree_shim");

        // 3. C layout probe: compile and run a program that prints the C layouts as Rust constants.
        let probe_src = out.join("embree_layout_probe.c");
        let probe_exe = out.join("embree_layout_probe");
        let mut c = String::from("#include <stdio.h>\n#include <stddef.h>\n#include <embree4/rtcore.h>\n#define P(n, v) printf(\"pub const %s: usize = %zu;\\n\", n, (size_t)(v))\nint main(void) {\n");
        for ty in [
            "RTCRay",
            "RTCHit",
            "RTCRayHit",
            "RTCRay16",
            "RTCHit16",
            "RTCRayHit16",
            "RTCRayQueryContext",
            "RTCIntersectArguments",
            "RTCBounds",
            "RTCBoundsFunctionArguments",
            "RTCIntersectFunctionNArguments",
        ] {
            c += &format!("  P(\"C_SIZEOF_{ty}\", sizeof(struct {ty}));\n  P(\"C_ALIGNOF_{ty}\", _Alignof(struct {ty}));\n");
        }
        for (ty, field) in [
            ("RTCRayHit", "hit"),
            ("RTCRayHit16", "hit"),
            ("RTCHit", "Ng_x"),
            ("RTCHit", "u"),
            ("RTCHit", "primID"),
            ("RTCHit", "geomID"),
            ("RTCHit", "instID"),
            ("RTCRay", "tfar"),
            ("RTCRay", "mask"),
            ("RTCHit16", "geomID"),
            ("RTCRay16", "tfar"),
            ("RTCIntersectArguments", "context"),
            ("RTCIntersectArguments", "filter"),
            ("RTCIntersectArguments", "intersect"),
            ("RTCIntersectArguments", "flags"),
            ("RTCBounds", "upper_x"),
            ("RTCBoundsFunctionArguments", "geometryUserPtr"),
            ("RTCBoundsFunctionArguments", "bounds_o"),
            ("RTCIntersectFunctionNArguments", "valid"),
            ("RTCIntersectFunctionNArguments", "geometryUserPtr"),
            ("RTCIntersectFunctionNArguments", "rayhit"),
            ("RTCIntersectFunctionNArguments", "N"),
        ] {
            c += &format!("  P(\"C_OFFSETOF_{ty}_{field}\", offsetof(struct {ty}, {field}));\n");
        }
        c += "  printf(\"pub const C_RTC_INVALID_GEOMETRY_ID: u32 = %u;\\n\", (unsigned)RTC_INVALID_GEOMETRY_ID);\n  return 0;\n}\n";
        fs::write(&probe_src, c).expect("write layout probe");
        let compiler = cc::Build::new().include(&found.include).cargo_metadata(false).get_compiler();
        let status = compiler
            .to_command()
            .arg(&probe_src)
            .arg("-o")
            .arg(&probe_exe)
            .status()
            .unwrap_or_else(|e| panic!("cannot run the C compiler for the Embree layout probe: {e}"));
        assert!(status.success(), "compiling the Embree layout probe {} failed", probe_src.display());
        // The probe only uses compile-time facts (it does not call Embree), so running it is fine even
        // though it is not linked against libembree4.
        let output = Command::new(&probe_exe).output().expect("run the Embree layout probe");
        assert!(output.status.success(), "the Embree layout probe failed");
        fs::write(out.join("embree_c_layout.rs"), &output.stdout).expect("write embree_c_layout.rs");
    }
}
