//! The chief-ray mapping cube f(x_s, y_s, λ) = (x_d, y_d): where the chief ray of every scene pixel centre
//! lands on the detector at every wavelength.
//!
//! With the analytic tracer (the usual case) the cube is traced by its f64 kernel directly
//! ([`trace_chief_rays`]): rayon tasks of one scene row each make their row's chief rays, trace them
//! [`LANES`] at a time one wavelength after the other (a block of one wavelength shares one index table)
//! and write the landings straight into their own slice of the cube — no cube-sized ray batch. Every entry
//! depends on its own ray only, and the kernel is the analytic tracer's (SIMD or scalar, the same bits), so
//! the cube equals the batched trace through [`crate::tracer::AnalyticTracer`] exactly and does not depend
//! on the thread count. Other backends are traced through [`Tracer::trace`], one batch per wavelength.
//!
//! ```
//! use diffcassi::prelude::*;
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let cube = analysis::mapping_cube(&sys, &AnalyticTracer::default(), 4, 6, 0.01, &[450.0, 650.0])?;
//! let [x, y] = cube.get(0, 0, 1).expect("the corner chief ray arrives");
//! // The same chief ray as a one-ray batch: the same bits.
//! let field = analysis::MappingCube::scene_xy(4, 6, 0.01, 0, 0);
//! let one = AnalyticTracer::default().trace(&sys, &RayBatch::chief_rays(&sys, &[field], 650.0)?)?;
//! assert_eq!((x, y), (one.x[0], one.y[0]));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::error::{Error, Result};
use crate::rays::{aimed_ray, RayBatch};
use crate::spec::RayAiming;
use crate::system::SequentialSystem;
use crate::tracer::kernel::{trace_steps, unit_direction};
use crate::tracer::simd::{self, LaneBlock, Real, LANES, LANES_F32};
use crate::tracer::Precision;
use crate::tracer::{RayStatus, Tracer};
use glam::DVec3;
use rayon::prelude::*;

/// The scene → detector mapping f(x_s, y_s, λ) = (x_d, y_d) of the reference paper: the chief ray of every
/// scene pixel centre at every wavelength.
#[derive(Clone, Debug)]
pub struct MappingCube {
    pub height: usize,
    pub width: usize,
    pub wavelength_nm: Vec<f64>,
    pub pixel_pitch_mm: f64,
    /// Detector (x, y) mm, C order `[row][col][λ][xy]`. Entries of rays that did not arrive are 0 and
    /// flagged in `valid`.
    pub positions_mm: Vec<f64>,
    /// 1 where the chief ray arrived, 0 otherwise, C order `[row][col][λ]`.
    pub valid: Vec<u8>,
}

impl MappingCube {
    /// Scene coordinates (mm) of pixel (row, col): centred grid, row 0 at +y (top), col 0 at −x.
    pub fn scene_xy(height: usize, width: usize, pitch_mm: f64, row: usize, col: usize) -> [f64; 2] {
        [(col as f64 + 0.5 - width as f64 / 2.0) * pitch_mm, (height as f64 / 2.0 - row as f64 - 0.5) * pitch_mm]
    }

    /// The renderer's sample point in pixel (row, col) for the jitter `sx`, `sy` ∈ [0, 1) of a sample
    /// [px, py, sx, sy]: the pixel centre ([`Self::scene_xy`]) moved by (sx − ½) pitches along +x and (sy − ½)
    /// along −y (mm; radians for an object at infinity, where the pitch is angular). One definition for the
    /// scalar renderer (`PlaneContext::ray`), the tolerance probe, the GPU twin's checks and their tests; the
    /// lane kernels (`render::sampling`) and the GPU kernels compute the same sums from their own centres.
    pub fn sample_xy(height: usize, width: usize, pitch_mm: f64, row: usize, col: usize, sx: f64, sy: f64) -> [f64; 2] {
        let c = Self::scene_xy(height, width, pitch_mm, row, col);
        [c[0] + (sx - 0.5) * pitch_mm, c[1] - (sy - 0.5) * pitch_mm]
    }

    pub fn get(&self, row: usize, col: usize, band: usize) -> Option<[f64; 2]> {
        let k = (row * self.width + col) * self.wavelength_nm.len() + band;
        (self.valid[k] == 1).then(|| [self.positions_mm[2 * k], self.positions_mm[2 * k + 1]])
    }
    pub fn invalid_count(&self) -> usize {
        self.valid.iter().filter(|v| **v == 0).count()
    }
}

/// Where one chief ray ended: its detector (x, y) mm, or why it did not arrive.
pub(crate) type Landing = std::result::Result<[f64; 2], RayStatus>;

/// The wavelengths of a cube with their refractive indices after each surface.
pub(crate) struct Bands {
    pub wavelength_nm: Vec<f64>,
    pub indices: Vec<Vec<f64>>,
}

impl Bands {
    pub(crate) fn new(system: &SequentialSystem, wavelengths_nm: &[f64]) -> Result<Self> {
        Ok(Bands { wavelength_nm: wavelengths_nm.to_vec(), indices: wavelengths_nm.iter().map(|&w| system.indices(w)).collect::<Result<_>>()? })
    }
    pub(crate) fn len(&self) -> usize {
        self.wavelength_nm.len()
    }
}

/// The same check as [`RayBatch::chief_rays`]: a field point must be finite.
fn check_field(f: [f64; 2]) -> Result<()> {
    if f[0].is_finite() && f[1].is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(format!("field point ({}, {}) mm is not finite", f[0], f[1])))
    }
}

/// The analytic tracer's classification of a landing ([`crate::tracer::TracedBatch::classify_out_of_range`]):
/// an arrived ray at a non-finite or implausible position or direction is `OutOfRange`, never a position.
#[inline]
fn landing(r: std::result::Result<(DVec3, DVec3), (RayStatus, usize)>) -> Landing {
    match r {
        Ok((p, d)) if p.is_finite() && p.abs().max_element() <= crate::limits::MAX_IMAGE_COORD_MM && d.is_finite() => Ok([p.x, p.y]),
        Ok(_) => Err(RayStatus::OutOfRange),
        Err((s, _)) => Err(s),
    }
}

/// Trace the chief rays of `fields` (object-plane points, mm) at every band with the analytic tracer's
/// f64 `kernel` (a [`crate::tracer::SimdLevel`], or the scalar kernel for `None`), band after band, and hand
/// each outcome to `store(field index, band index, landing)`. The one place where the mapping chooses its
/// kernel. Per ray the arithmetic is exactly [`crate::tracer::AnalyticTracer`]'s on
/// [`RayBatch::chief_rays`] (the same aiming, input check [`unit_direction`] and kernel), so the landings are
/// bit for bit the batched ones. Serial: callers run it in parallel on disjoint sets of fields.
pub(crate) fn trace_chief_rays(system: &SequentialSystem, kernel: Option<simd::SimdLevel>, precision: Precision, fields: &[[f64; 2]], bands: &Bands, mut store: impl FnMut(usize, usize, Landing)) -> Result<()> {
    for &f in fields {
        check_field(f)?;
    }
    // Object-space rays (origin, unit direction or None for an invalid input) of the current band. With
    // ray aiming off the chief ray does not depend on the wavelength: made once.
    let aim = system.spec.ray_aiming != RayAiming::Off;
    let mut rays: Vec<(DVec3, Option<DVec3>)> = Vec::with_capacity(fields.len());
    let make = |n: &[f64], rays: &mut Vec<(DVec3, Option<DVec3>)>| -> Result<()> {
        rays.clear();
        for &f in fields {
            let (o, d) = aimed_ray(system, n, f, 0.0, 0.0)?;
            rays.push((o, unit_direction(d).filter(|_| o.is_finite())));
        }
        Ok(())
    };
    let path = &system.path;
    for (b, n) in bands.indices.iter().enumerate() {
        if aim || b == 0 {
            make(n, &mut rays)?;
        }
        match kernel {
            Some(level) => match precision {
                Precision::F64 => trace_lanes::<f64, LANES>(level, path, n, &rays, b, &mut store),
                Precision::F32 => trace_lanes::<f32, LANES_F32>(level, path, n, &rays, b, &mut store),
            },
            None => {
                for (i, &(o, d)) in rays.iter().enumerate() {
                    store(i, b, landing(d.map_or(Err((RayStatus::InvalidInput, 0)), |d| trace_steps(path, n, o, d))));
                }
            }
        }
    }
    Ok(())
}

/// One band of [`trace_chief_rays`] through the lane kernel in `T` ([`LANES`] f64 lanes: bit for bit the
/// scalar kernel; [`LANES_F32`] f32 lanes: `--precision f32`, loaded and checked as
/// [`crate::tracer::AnalyticF32Tracer`] loads them, so both mapping routes agree).
fn trace_lanes<T: Real, const N: usize>(level: simd::SimdLevel, path: &[crate::system::PathStep], n: &[f64], rays: &[(DVec3, Option<DVec3>)], band: usize, store: &mut impl FnMut(usize, usize, Landing)) {
    let tables = [n; N];
    for (c, chunk) in rays.chunks(N).enumerate() {
        let mut block = LaneBlock::<T, N>::default();
        for (k, &(o, d)) in chunk.iter().enumerate() {
            match d {
                // f64 accepts every finite origin: `set_checked` is `set`.
                Some(d) => block.set_checked(k, o, d),
                None => block.set_invalid(k),
            }
        }
        simd::trace_block(level, path, &tables, &mut block);
        for k in 0..chunk.len() {
            store(c * N + k, band, landing(block.result(k)));
        }
    }
}

/// The same outcomes as [`trace_chief_rays`] through any tracer: one batch of every field per band.
pub(crate) fn trace_chief_rays_batched(system: &SequentialSystem, tracer: &dyn Tracer, fields: &[[f64; 2]], bands: &Bands, mut store: impl FnMut(usize, usize, Landing)) -> Result<()> {
    for (b, &w) in bands.wavelength_nm.iter().enumerate() {
        let out = tracer.trace(system, &RayBatch::chief_rays(system, fields, w)?)?;
        for p in 0..fields.len() {
            store(p, b, if out.status[p] == RayStatus::Ok { Ok([out.x[p], out.y[p]]) } else { Err(out.status[p]) });
        }
    }
    Ok(())
}

/// How a cube's chief rays are traced.
pub(crate) enum Route<'a> {
    /// The analytic tracer's kernel, directly: a SIMD level (or `None` for the scalar f64 kernel) and the
    /// precision (f32 always with a SIMD level).
    Direct(Option<simd::SimdLevel>, Precision),
    /// Any other backend, through [`Tracer::trace`].
    Batched(&'a dyn Tracer),
}

impl<'a> Route<'a> {
    /// Direct for the analytic tracer (an error when its forced SIMD level is not on this CPU).
    pub(crate) fn of(tracer: &'a dyn Tracer) -> Result<Self> {
        if let Some(a) = tracer.as_analytic_f32() {
            return Ok(Route::Direct(Some(a.level.check()?), Precision::F32));
        }
        Ok(match tracer.as_analytic() {
            Some(a) => Route::Direct(a.kernel.resolve()?, Precision::F64),
            None => Route::Batched(tracer),
        })
    }
}

/// Trace the H×W×Nλ chief rays. With the analytic tracer: in parallel, one scene row per task, written in
/// place (module docs); otherwise one batch per wavelength through `tracer`.
pub fn mapping_cube(system: &SequentialSystem, tracer: &dyn Tracer, height: usize, width: usize, pixel_pitch_mm: f64, wavelengths_nm: &[f64]) -> Result<MappingCube> {
    if height == 0 || width == 0 || wavelengths_nm.is_empty() {
        return Err(Error::invalid(format!("mapping cube {height}×{width}×{}: every dimension must be ≥ 1", wavelengths_nm.len())));
    }
    if !(pixel_pitch_mm.is_finite() && pixel_pitch_mm > 0.0) {
        return Err(Error::invalid(format!("pixel pitch {pixel_pitch_mm} mm: must be finite and > 0")));
    }
    // The scene's half extent within the plausible lengths (a 1e300 mm pitch gave an all-invalid cube and no
    // error), and the cube within the memory budget (sizes from C++ aborted on allocation).
    let half_extent_mm = pixel_pitch_mm * height.max(width) as f64 / 2.0;
    if half_extent_mm > crate::limits::MAX_LENGTH_MM {
        return Err(Error::invalid(format!(
            "mapping cube {height}×{width} at a {} mm pitch: the scene reaches {} mm from the axis, beyond ±{:e} mm",
            crate::limits::fmt_num(pixel_pitch_mm),
            crate::limits::fmt_num(half_extent_mm),
            crate::limits::MAX_LENGTH_MM
        )));
    }
    // The cube (two f64 coordinates and a validity flag per entry) and, off the analytic kernel's direct route,
    // one wavelength's batch of every pixel's chief ray. Front ends check their whole job (a render, the copy
    // written) before any work; this is the library's own check, for callers that did not.
    let route = Route::of(tracer)?;
    let batch = if matches!(route, Route::Batched(_)) { crate::limits::bytes_mapping_batch(height, width) } else { 0.0 };
    crate::limits::check_memory(&format!("mapping cube height × width × wavelengths ({height} × {width} × {})", wavelengths_nm.len()), crate::limits::bytes_mapping(height, width, wavelengths_nm.len()) + batch)?;
    let bands = Bands::new(system, wavelengths_nm)?;
    let nl = bands.len();
    let mut positions_mm = vec![0.0; height * width * nl * 2];
    let mut valid = vec![0u8; height * width * nl];
    match route {
        Route::Direct(kernel, precision) => {
            let results: Vec<Result<()>> = positions_mm
                .par_chunks_mut(width * nl * 2)
                .zip(valid.par_chunks_mut(width * nl))
                .enumerate()
                .map(|(r, (pos, ok))| {
                    let fields: Vec<[f64; 2]> = (0..width).map(|c| MappingCube::scene_xy(height, width, pixel_pitch_mm, r, c)).collect();
                    trace_chief_rays(system, kernel, precision, &fields, &bands, |c, b, land| {
                        if let Ok([x, y]) = land {
                            let k = c * nl + b;
                            pos[2 * k] = x;
                            pos[2 * k + 1] = y;
                            ok[k] = 1;
                        }
                    })
                })
                .collect();
            results.into_iter().collect::<Result<()>>()?; // the first error in row order, whatever the threads
        }
        Route::Batched(tracer) => {
            let fields: Vec<[f64; 2]> = (0..height * width).map(|p| MappingCube::scene_xy(height, width, pixel_pitch_mm, p / width, p % width)).collect();
            trace_chief_rays_batched(system, tracer, &fields, &bands, |p, b, land| {
                if let Ok([x, y]) = land {
                    let k = p * nl + b;
                    positions_mm[2 * k] = x;
                    positions_mm[2 * k + 1] = y;
                    valid[k] = 1;
                }
            })?;
        }
    }
    Ok(MappingCube { height, width, wavelength_nm: wavelengths_nm.to_vec(), pixel_pitch_mm, positions_mm, valid })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tracer::{AnalyticTracer, Kernel, SimdLevel};

    /// The direct, parallel cube equals the batched trace through the analytic tracer bit for bit, for
    /// every kernel, on a preset with off-axis fields and several bands (and thread counts do not matter).
    #[test]
    fn direct_cube_equals_the_batched_trace_for_every_kernel() {
        for name in ["sp", "map"] {
            let sys = SequentialSystem::build(&crate::presets::spec(name).unwrap()).unwrap();
            let (h, w, pitch) = (7, 45, 0.05); // 45 columns: one full block of 32 lanes and a partial one
            let ws = [450.0, 520.0, 650.0];
            let fields: Vec<[f64; 2]> = (0..h * w).map(|p| MappingCube::scene_xy(h, w, pitch, p / w, p % w)).collect();
            let mut kernels = vec![Kernel::Scalar];
            kernels.extend(SimdLevel::available().into_iter().map(|l| Kernel::Simd(Some(l))));
            for k in kernels {
                let tracer = AnalyticTracer::with_kernel(k);
                let cube = mapping_cube(&sys, &tracer, h, w, pitch, &ws).unwrap();
                let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| mapping_cube(&sys, &tracer, h, w, pitch, &ws).unwrap());
                assert_eq!(cube.positions_mm, one.positions_mm, "{name} {}", k.name());
                for (b, &wl) in ws.iter().enumerate() {
                    let out = tracer.trace(&sys, &RayBatch::chief_rays(&sys, &fields, wl).unwrap()).unwrap();
                    for p in 0..fields.len() {
                        let got = cube.get(p / w, p % w, b);
                        let want = (out.status[p] == RayStatus::Ok).then(|| [out.x[p], out.y[p]]);
                        assert_eq!(got, want, "{name} {} pixel {p} band {b}", k.name());
                    }
                }
            }
        }
    }

    /// Another tracer (the analytic one behind another name) takes the batched route: the same cube.
    #[test]
    fn batched_route_gives_the_same_cube() {
        struct Batched(AnalyticTracer);
        impl Tracer for Batched {
            fn name(&self) -> String {
                "batched-analytic".into()
            }
            fn trace(&self, system: &SequentialSystem, rays: &RayBatch) -> Result<crate::tracer::TracedBatch> {
                self.0.trace(system, rays)
            }
        }
        let sys = SequentialSystem::build(&crate::presets::spec("sp").unwrap()).unwrap();
        // 1 mm pixels: the corners are vignetted, so `valid` is exercised too.
        let direct = mapping_cube(&sys, &AnalyticTracer::default(), 16, 16, 1.0, &[450.0, 650.0]).unwrap();
        let batched = mapping_cube(&sys, &Batched(AnalyticTracer::default()), 16, 16, 1.0, &[450.0, 650.0]).unwrap();
        assert!(direct.invalid_count() > 0);
        assert_eq!((direct.positions_mm, direct.valid), (batched.positions_mm, batched.valid));
    }

    #[test]
    fn implausible_extents_are_an_error() {
        // A scene beyond ±1e6 mm (1e308 mm: non-finite fields; 1e300 mm gave an all-invalid cube, no error).
        let sys = SequentialSystem::build(&crate::presets::spec("sp").unwrap()).unwrap();
        for pitch in [1e308, 1e300, 2.6e5] {
            let e = mapping_cube(&sys, &AnalyticTracer::default(), 8, 8, pitch, &[520.0]).unwrap_err().to_string();
            assert!(e.contains("from the axis") && e.contains("beyond ±1e6 mm"), "{e}");
        }
    }
}
