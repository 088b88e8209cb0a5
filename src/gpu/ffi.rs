//! The host twin's entry points (`src/gpu/kernels/host.c`, built by `build.rs`): their declarations, the
//! check that the Rust `repr(C)` structs of [`super::pack`] have the C compiler's sizes, and the kernels'
//! status codes as [`RayStatus`].
use super::pack::{AiryBatch, Batch, DepositBatch, LandingBatch, Step, Window};
use crate::tracer::RayStatus;

extern "C" {
    pub(crate) fn dc_footprint_size_host(u: *const f64, v: *const f64, w: *const f64, n: u32, det_w: i64, det_h: i64, wins: *mut Window, begin: u64, end: u64);
    pub(crate) fn dc_footprint_fill_host(u: *const f64, v: *const f64, w: *const f64, n: u32, wins: *mut Window, offsets: *const u64, scratch: *mut f64, weights: *mut f32, begin: u64, end: u64);
    fn dc_sizeof_window() -> u64;
    pub(crate) fn dc_trace_batch_host(batch: *const Batch, begin: u64, end: u64, mode: u32);
    fn dc_sizeof_step() -> u64;
    fn dc_sizeof_batch() -> u64;
    pub(crate) fn dc_landing_host(batch: *const LandingBatch, begin: u64, end: u64, f32: i32);
    fn dc_sizeof_landing_batch() -> u64;
    pub(crate) fn dc_deposit_host(batch: *const DepositBatch, begin: u64, end: u64, counts: *mut u64);
    pub(crate) fn dc_airy_host(batch: *const AiryBatch, begin: u64, end: u64);
    pub(crate) fn dc_finish_host(band: *const f64, n_bands: u32, npix: u64, image: *mut f64, bands_f32: *mut f32, begin: u64, end: u64);
    fn dc_sizeof_deposit_batch() -> u64;
    fn dc_sizeof_airy_batch() -> u64;
}

/// `DC_TRACE_*` of dc_trace.h: which trace `dc_trace_batch_host` runs.
pub(crate) const TRACE_F64: u32 = 0;
pub(crate) const TRACE_F32: u32 = 1;
/// The landing kernel's f32 input rule (the renderer's `set_raw` + `normalize_inputs`), for the tests.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) const TRACE_F32_RAW: u32 = 2;

/// Whether the Rust `repr(C)` structs have the C compiler's sizes (a layout mismatch would be undefined
/// behaviour, so every trace checks it first; it costs two calls).
pub(crate) fn layouts_match() -> bool {
    // SAFETY: plain functions returning sizeof of two structs.
    unsafe {
        dc_sizeof_step() as usize == std::mem::size_of::<Step>()
            && dc_sizeof_batch() as usize == std::mem::size_of::<Batch>()
            && dc_sizeof_landing_batch() as usize == std::mem::size_of::<LandingBatch>()
            && dc_sizeof_window() as usize == std::mem::size_of::<Window>()
            && dc_sizeof_deposit_batch() as usize == std::mem::size_of::<DepositBatch>()
            && dc_sizeof_airy_batch() as usize == std::mem::size_of::<AiryBatch>()
    }
}

/// The kernel's status byte as a [`RayStatus`] (`DC_OK` … `DC_INVALID_INPUT` are `RayStatus`'s codes).
pub(crate) fn status_of(code: u8) -> RayStatus {
    match code {
        0 => RayStatus::Ok,
        1 => RayStatus::Missed,
        2 => RayStatus::Vignetted,
        3 => RayStatus::TotalInternalReflection,
        4 => RayStatus::NoConvergence,
        5 => RayStatus::InvalidInput,
        8 => RayStatus::OutOfRange,
        9 => RayStatus::Evanescent,
        _ => RayStatus::InvalidInput,
    }
}

