//! The device build of the kernels, embedded: `src/gpu/kernels/trace.ptx`, compiled from the same headers as
//! the CPU twin by `scripts/gpu/build_ptx.py` (NVRTC, `compute_90`, `--fmad=false`) and committed, so that a
//! build needs no CUDA. The test command rebuilds it and fails when the committed copy is stale (its first
//! lines name the SHA-256 of the sources it came from, checked here against the sources compiled into the
//! twin).

/// PTX of `dc_trace_kernel` / `dc_trace_f32_kernel` (one thread a ray over a `dc_batch`, f64 / f32),
/// `dc_landing_kernel` / `dc_landing_f32_kernel` (one thread a renderer ray over a `dc_landing_batch`) and the
/// footprint kernels.
pub const TRACE_PTX: &str = include_str!("kernels/trace.ptx");

/// The kernel sources, embedded too: a driver older than the PTX's ISA version can JIT them with the
/// machine's own NVRTC (docs/gpu.md).
pub const SOURCES: [(&str, &str); 8] = [
    ("dc_common.h", include_str!("kernels/dc_common.h")),
    ("dc_vec_tmpl.h", include_str!("kernels/dc_vec_tmpl.h")),
    ("dc_trace.h", include_str!("kernels/dc_trace.h")),
    ("dc_trace_tmpl.h", include_str!("kernels/dc_trace_tmpl.h")),
    ("dc_sample.h", include_str!("kernels/dc_sample.h")),
    ("dc_render.h", include_str!("kernels/dc_render.h")),
    ("dc_accum.h", include_str!("kernels/dc_accum.h")),
    ("device.cu", include_str!("kernels/device.cu")),
];

/// `device.cu` with every `#include "…"` of the kernel headers replaced by the header's text (each once:
/// they are include-guarded): one translation unit for a compiler that takes no header list (the launcher's
/// NVRTC fallback, or `nvcc -ptx -arch=compute_90 --fmad=false` on a GPU machine; docs/gpu.md).
pub fn amalgamated_source() -> String {
    // Every include is expanded where it stands: the guarded headers then skip themselves, and the templates
    // (dc_trace_tmpl.h, dc_vec_tmpl.h, included once per precision) expand each time, as the preprocessor does.
    fn expand(name: &str, depth: usize, out: &mut String) {
        let Some((_, text)) = SOURCES.iter().find(|(n, _)| *n == name) else {
            out.push_str(&format!("#error \"missing kernel source {name}\"\n"));
            return;
        };
        if depth > 16 {
            out.push_str("#error \"kernel includes nested too deep\"\n");
            return;
        }
        for line in text.lines() {
            match line.trim().strip_prefix("#include \"").and_then(|r| r.strip_suffix('"')) {
                Some(inc) => expand(inc, depth + 1, out),
                None => {
                    out.push_str(line);
                    out.push('\n');
                }
            }
        }
    }
    let mut out = String::new();
    expand("device.cu", 0, &mut out);
    out
}

/// The `source-sha256` line of the embedded PTX.
pub fn ptx_source_hash() -> Option<&'static str> {
    TRACE_PTX.lines().find_map(|l| l.strip_prefix("// source-sha256: ")).map(str::trim)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_ptx_holds_the_kernel_entry() {
        for entry in ["dc_trace_kernel", "dc_trace_f32_kernel", "dc_landing_kernel", "dc_landing_f32_kernel", "dc_landing_aimed_kernel", "dc_landing_aimed_f32_kernel", "dc_deposit_aimed_kernel"] {
            assert!(TRACE_PTX.contains(&format!(".visible .entry {entry}")), "no {entry} entry in trace.ptx");
        }
        assert_eq!(ptx_source_hash().map(str::len), Some(64));
    }

    #[test]
    fn the_amalgamated_source_holds_every_kernel_and_no_local_include() {
        let src = amalgamated_source();
        assert!(!src.contains("#include \"dc_") && !src.contains("#error"), "an include was not expanded");
        for k in ["dc_trace_kernel", "dc_landing_kernel", "dc_deposit_kernel", "dc_airy_kernel", "dc_finish_kernel", "dc_landing_f32_kernel", "dc_landing_aimed_kernel", "dc_landing_aimed_f32_kernel", "dc_deposit_aimed_kernel"] {
            assert!(src.contains(&format!("void {k}(")), "{k} missing");
            assert!(TRACE_PTX.contains(&format!(".visible .entry {k}")), "no {k} entry in trace.ptx");
        }
        // The f32 kernels are there too (the trace template expanded for both precisions).
        for k in ["dc_trace_f32_kernel", "dc_landing_f32_kernel"] {
            assert!(src.contains(&format!("void {k}(")), "{k} missing");
        }
    }
}
