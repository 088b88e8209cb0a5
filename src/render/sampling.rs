//! Per-ray random numbers that depend only on (seed, plane, pixel, sample index) — never on scheduling —
//! and the stratified sampling of the pupil and of the scene pixel's area.
//!
//! The generator is counter-based: SplitMix64's finaliser (Steele, Lea & Flood 2014) applied to the key
//! chained through seed, plane, pixel and sample, so any ray's numbers can be recomputed in isolation (the
//! property dataset mode and thread-count independence rest on).
//!
//! Stratification (the default): the N rays of one pixel at one plane split the unit square into an a×b
//! grid (a·b = N, a the largest divisor of N not above √N); ray k takes pupil cell k and pixel-area cell
//! π(k), π a random permutation per (seed, plane, pixel) — "padded" 2-D + 2-D stratification, unbiased
//! because each ray is uniform over the whole pupil × pixel domain. Pupil cells are mapped to the unit disk
//! by Shirley & Chiu's concentric map (area-preserving, so uniform in the entrance pupil). `Independent`
//! draws all four coordinates uniformly (plain Monte Carlo, variance exactly ∝ 1/N).
//!
//! ```
//! use diffcassi::render::{RaySampler, Sampling};
//! let s = RaySampler::new(20, Sampling::Stratified);
//! let mut out = vec![[0.0; 4]; 20];
//! s.fill(7, 3, 12345, &mut out);
//! let mut again = vec![[0.0; 4]; 20];
//! s.fill(7, 3, 12345, &mut again);
//! assert_eq!(out, again);
//! assert!(out.iter().all(|r| r[0] * r[0] + r[1] * r[1] <= 1.0)); // pupil point in the unit disk
//! ```

/// How the N rays of a pixel-plane are placed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Sampling {
    Stratified,
    Independent,
}

/// SplitMix64 finaliser: a bijective 64-bit mix.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The key of (seed, plane, pixel, index): chained mixes, so nearby keys give unrelated streams.
#[inline]
pub fn key(seed: u64, plane: u64, pixel: u64, index: u64) -> u64 {
    mix64(pixel_key(seed, plane, pixel) ^ index)
}

/// The part of [`key`] shared by every index of one (seed, plane, pixel): `key = mix64(pixel_key ^ index)`,
/// so a pixel's N rays pay one mix each instead of four.
#[inline]
fn pixel_key(seed: u64, plane: u64, pixel: u64) -> u64 {
    mix64(mix64(mix64(seed) ^ plane) ^ pixel)
}

/// Uniform in [0, 1) from the top 53 bits.
#[inline]
fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Shirley–Chiu concentric map of the unit square onto the unit disk (area-preserving).
#[inline]
pub fn concentric_disk(u: f64, v: f64) -> [f64; 2] {
    let (a, b) = (2.0 * u - 1.0, 2.0 * v - 1.0);
    if a == 0.0 && b == 0.0 {
        return [0.0, 0.0];
    }
    let (r, phi) = if a.abs() > b.abs() { (a, std::f64::consts::FRAC_PI_4 * (b / a)) } else { (b, std::f64::consts::FRAC_PI_2 - std::f64::consts::FRAC_PI_4 * (a / b)) };
    [r * phi.cos(), r * phi.sin()]
}

/// Sample generator for N rays per pixel-plane.
#[derive(Clone, Debug)]
pub struct RaySampler {
    pub rays: usize,
    pub mode: Sampling,
    /// Strata grid a × b (a·b = rays).
    grid: (usize, usize),
}

impl RaySampler {
    pub fn new(rays: usize, mode: Sampling) -> Self {
        let rays = rays.max(1);
        let mut a = (rays as f64).sqrt().floor() as usize;
        while a > 1 && rays % a != 0 {
            a -= 1;
        }
        RaySampler { rays, mode, grid: (a.max(1), rays / a.max(1)) }
    }

    /// Fill `out[k] = [px, py, sx, sy]` for the rays of (seed, plane, pixel): (px, py) normalised pupil
    /// coordinates in the unit disk, (sx, sy) ∈ [0, 1)² the position inside the scene pixel (x right, y down).
    pub fn fill(&self, seed: u64, plane: u64, pixel: u64, out: &mut [[f64; 4]]) {
        let n = self.rays;
        debug_assert_eq!(out.len(), n);
        let (a, b) = self.grid;
        let pk = pixel_key(seed, plane, pixel);
        match self.mode {
            Sampling::Independent => {
                for (k, o) in out.iter_mut().enumerate() {
                    let h1 = mix64(pk ^ (2 * k as u64));
                    let h2 = mix64(h1);
                    let h3 = mix64(pk ^ (2 * k as u64 + 1));
                    let h4 = mix64(h3);
                    let p = concentric_disk(unit(h1), unit(h2));
                    *o = [p[0], p[1], unit(h3), unit(h4)];
                }
            }
            Sampling::Stratified => {
                // Fisher–Yates permutation of the pixel-area cells, from the pixel's own stream. The
                // permutation is written into the [2] slots first, then overwritten by the coordinates.
                let base = mix64(pk ^ u64::MAX);
                for (k, o) in out.iter_mut().enumerate() {
                    o[2] = k as f64;
                }
                for k in (1..n).rev() {
                    let j = (mix64(base ^ k as u64) % (k as u64 + 1)) as usize;
                    let t = out[k][2];
                    out[k][2] = out[j][2];
                    out[j][2] = t;
                }
                for (k, o) in out.iter_mut().enumerate() {
                    let h1 = mix64(pk ^ k as u64);
                    let h2 = mix64(h1);
                    let h3 = mix64(h2);
                    let h4 = mix64(h3);
                    let (i, j) = (k % a, k / a);
                    let p = concentric_disk((i as f64 + unit(h1)) / a as f64, (j as f64 + unit(h2)) / b as f64);
                    let m = o[2] as usize;
                    let (i2, j2) = (m % a, m / a);
                    *o = [p[0], p[1], (i2 as f64 + unit(h3)) / a as f64, (j2 as f64 + unit(h4)) / b as f64];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hoisted_pixel_key_is_the_chained_key() {
        for (s, p, q, i) in [(0u64, 0u64, 0u64, 0u64), (7, 3, 12345, 19), (u64::MAX, 111, 1 << 40, u64::MAX)] {
            assert_eq!(key(s, p, q, i), mix64(mix64(mix64(mix64(s) ^ p) ^ q) ^ i));
        }
    }

    #[test]
    fn strata_cover_the_domain_once() {
        let s = RaySampler::new(20, Sampling::Stratified);
        assert_eq!(s.grid, (4, 5));
        let mut out = vec![[0.0; 4]; 20];
        s.fill(1, 2, 3, &mut out);
        // Every pixel-area cell is used exactly once.
        let mut seen = [false; 20];
        for o in &out {
            let cell = (o[2] * 4.0).floor() as usize + 4 * (o[3] * 5.0).floor() as usize;
            assert!(!seen[cell]);
            seen[cell] = true;
        }
        let mut other = vec![[0.0; 4]; 20];
        s.fill(1, 2, 4, &mut other);
        assert_ne!(out, other);
    }

    #[test]
    fn concentric_map_is_area_preserving_in_the_mean() {
        // Mean of r² over a uniform disk is 1/2.
        let n = 200;
        let mut s = 0.0;
        for i in 0..n {
            for j in 0..n {
                let p = concentric_disk((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                s += p[0] * p[0] + p[1] * p[1];
            }
        }
        assert!((s / (n * n) as f64 - 0.5).abs() < 1e-4);
    }
}
