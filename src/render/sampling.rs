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

/// ⌈2¹²⁸ / d⌉ for [`fast_mod`] (d ≥ 2).
fn mod_magic(d: u64) -> u128 {
    u128::MAX / d as u128 + 1
}

/// `x % d` (d ≥ 2, `c = mod_magic(d)`) without a division instruction: Lemire, Kaser & Kurz, "Faster
/// remainder by direct computation" (2019), x mod d = ⌊((c·x) mod 2¹²⁸) · d / 2¹²⁸⌋ with c = ⌈2¹²⁸/d⌉,
/// exact for every 64-bit x because 128 ≥ 64 + log₂ d. A few multiplications instead of a 64-bit `div`
/// whose latency the Fisher–Yates shuffle waits on.
#[inline(always)]
fn fast_mod(x: u64, c: u128, d: u64) -> u64 {
    let low = c.wrapping_mul(x as u128);
    let hi = (low >> 64) * d as u128;
    let lo = ((low as u64) as u128 * d as u128) >> 64;
    ((hi + lo) >> 64) as u64
}

/// Uniform in [0, 1) from the top 53 bits.
#[inline]
fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Shirley–Chiu concentric map of the unit square onto the unit disk (area-preserving).
///
/// Branch-free, so a loop over samples vectorises: both wedges' angles are computed and one selected, and
/// the sine and cosine come from [`super::trig::sin_cos`] (faithfully rounded, within 1 ulp of libm's;
/// before, `f64::sin`/`f64::cos` were called, so a sample's pupil point may differ from the former one by
/// an ulp of sin/cos — the same map, the same strata).
#[inline(always)]
pub fn concentric_disk(u: f64, v: f64) -> [f64; 2] {
    let (a, b) = (2.0 * u - 1.0, 2.0 * v - 1.0);
    // Wedge |a| > |b|: r = a, φ = π/4 · b/a; else r = b, φ = π/2 − π/4 · a/b (φ ∈ [−π/4, 3π/4]).
    let first = a.abs() > b.abs();
    let (r, num, den) = if first { (a, b, a) } else { (b, a, b) };
    let t = std::f64::consts::FRAC_PI_4 * (num / den);
    let phi = if first { t } else { std::f64::consts::FRAC_PI_2 - t };
    let (s, c) = super::trig::sin_cos(phi);
    // The centre (a = b = 0, where 0/0 made φ NaN) maps to the origin.
    let centre = a == 0.0 && b == 0.0;
    [if centre { 0.0 } else { r * c }, if centre { 0.0 } else { r * s }]
}

/// One ray's sample from its four hashes, its pupil cell (pi, pj) and pixel-area cell (ai, aj) of an
/// na × nb grid: `[px, py, sx, sy]` (see [`RaySampler::fill`]). `Independent` sampling is the 1 × 1 grid.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn sample(h: [u64; 4], pi: f64, pj: f64, ai: f64, aj: f64, na: f64, nb: f64) -> [f64; 4] {
    let p = concentric_disk((pi + unit(h[0])) / na, (pj + unit(h[1])) / nb);
    [p[0], p[1], (ai + unit(h[2])) / na, (aj + unit(h[3])) / nb]
}

/// The four hashes of a ray from its key (`pixel_key ^ k` stratified, `pixel_key ^ 2k` independent).
#[inline(always)]
fn hashes(key: u64, independent: bool) -> [u64; 4] {
    let h1 = mix64(key);
    let h2 = mix64(h1);
    let h3 = if independent { mix64(key ^ 1) } else { mix64(h2) };
    [h1, h2, h3, mix64(h3)]
}

/// The samples of many pixels' rays, structure of arrays (ray `t` of the list is entry `t` of each),
/// filled by [`RaySampler::fill_pixels`]; the other vectors are its reusable scratch.
#[derive(Clone, Debug, Default)]
pub struct SampleRow {
    /// Normalised pupil point (unit disk).
    pub px: Vec<f64>,
    pub py: Vec<f64>,
    /// Position in the scene pixel, [0, 1)² (x right, y down).
    pub sx: Vec<f64>,
    pub sy: Vec<f64>,
    key: Vec<u64>,
    pupil_i: Vec<f64>,
    pupil_j: Vec<f64>,
    area_i: Vec<f64>,
    area_j: Vec<f64>,
}

impl SampleRow {
    pub fn len(&self) -> usize {
        self.px.len()
    }
    pub fn is_empty(&self) -> bool {
        self.px.is_empty()
    }
    /// Ray `t`'s `[px, py, sx, sy]`.
    pub fn get(&self, t: usize) -> [f64; 4] {
        [self.px[t], self.py[t], self.sx[t], self.sy[t]]
    }
}

/// The vectorised part of [`RaySampler::fill_pixels`]: hashes, strata and disk map of every ray.
struct SampleLoop<'a> {
    row: &'a mut SampleRow,
    independent: bool,
    na: f64,
    nb: f64,
}

impl super::vector::VectorLoop for SampleLoop<'_> {
    #[inline(always)]
    fn run(self) {
        let r = self.row;
        let n = r.key.len();
        let (key, pi, pj, ai, aj) = (&r.key[..n], &r.pupil_i[..n], &r.pupil_j[..n], &r.area_i[..n], &r.area_j[..n]);
        let (px, py, sx, sy) = (&mut r.px[..n], &mut r.py[..n], &mut r.sx[..n], &mut r.sy[..n]);
        for t in 0..n {
            let o = sample(hashes(key[t], self.independent), pi[t], pj[t], ai[t], aj[t], self.na, self.nb);
            px[t] = o[0];
            py[t] = o[1];
            sx[t] = o[2];
            sy[t] = o[3];
        }
    }
}

/// Sample generator for N rays per pixel-plane.
#[derive(Clone, Debug)]
pub struct RaySampler {
    pub rays: usize,
    pub mode: Sampling,
    /// Strata grid a × b (a·b = rays).
    grid: (usize, usize),
    /// Cell (k mod a, k div a) of stratum k, as f64.
    cell_i: Vec<f64>,
    cell_j: Vec<f64>,
    /// `mod_magic(k + 1)` for the shuffle's step k (entry 0 unused).
    shuffle_magic: Vec<u128>,
    /// Instruction set of the vectorised sampling loop (every level gives the same numbers).
    level: crate::tracer::SimdLevel,
}

impl RaySampler {
    pub fn new(rays: usize, mode: Sampling) -> Self {
        let rays = rays.max(1);
        let mut a = (rays as f64).sqrt().floor() as usize;
        while a > 1 && rays % a != 0 {
            a -= 1;
        }
        let a = a.max(1);
        let cell_i = (0..rays).map(|k| (k % a) as f64).collect();
        let cell_j = (0..rays).map(|k| (k / a) as f64).collect();
        let shuffle_magic = (0..rays as u64).map(|k| mod_magic((k + 1).max(2))).collect();
        RaySampler { rays, mode, grid: (a, rays / a), cell_i, cell_j, shuffle_magic, level: crate::tracer::SimdLevel::detect() }
    }

    /// The strata grid a × b (a·b = rays; a the largest divisor of N not above √N): the GPU kernels' sampler
    /// (src/gpu/kernels/dc_sample.h) takes it as it is.
    pub(crate) fn grid(&self) -> (usize, usize) {
        self.grid
    }

    /// The same sampler with its vectorised loop compiled for `level` (for tests: the numbers are the same).
    pub fn with_level(mut self, level: crate::tracer::SimdLevel) -> Self {
        self.level = level;
        self
    }

    /// Fill `out[k] = [px, py, sx, sy]` for the rays of (seed, plane, pixel): (px, py) normalised pupil
    /// coordinates in the unit disk, (sx, sy) ∈ [0, 1)² the position inside the scene pixel (x right, y down).
    /// The same numbers as [`RaySampler::fill_pixels`].
    pub fn fill(&self, seed: u64, plane: u64, pixel: u64, out: &mut [[f64; 4]]) {
        let n = self.rays;
        debug_assert_eq!(out.len(), n);
        let mut row = SampleRow::default();
        self.prepare(seed, plane, &[pixel], &mut row);
        let (independent, na, nb) = self.divisors();
        for (t, o) in out.iter_mut().enumerate() {
            *o = sample(hashes(row.key[t], independent), row.pupil_i[t], row.pupil_j[t], row.area_i[t], row.area_j[t], na, nb);
        }
    }

    /// The samples of the N rays of each of `pixels` (in order) at (seed, plane), into `out` (ray `t` of
    /// pixel `q` at index `q·N + t`); vectorised over all the rays.
    pub fn fill_pixels(&self, seed: u64, plane: u64, pixels: &[u64], out: &mut SampleRow) {
        self.prepare(seed, plane, pixels, out);
        let len = out.key.len();
        for v in [&mut out.px, &mut out.py, &mut out.sx, &mut out.sy] {
            v.resize(len, 0.0);
        }
        let (independent, na, nb) = self.divisors();
        super::vector::run_at(self.level, SampleLoop { row: out, independent, na, nb });
    }

    fn divisors(&self) -> (bool, f64, f64) {
        match self.mode {
            Sampling::Independent => (true, 1.0, 1.0),
            Sampling::Stratified => (false, self.grid.0 as f64, self.grid.1 as f64),
        }
    }

    /// The serial part: each ray's key and cells. Stratified: ray k takes pupil cell k and pixel-area
    /// cell π(k), π the Fisher–Yates permutation from the pixel's own stream; independent: all cells 0
    /// (a 1 × 1 grid, `(0 + u) / 1 = u` exactly).
    fn prepare(&self, seed: u64, plane: u64, pixels: &[u64], r: &mut SampleRow) {
        let n = self.rays;
        let len = pixels.len() * n;
        for v in [&mut r.pupil_i, &mut r.pupil_j, &mut r.area_i, &mut r.area_j] {
            v.clear();
            v.reserve(len);
        }
        r.key.clear();
        r.key.reserve(len);
        for &pixel in pixels {
            let pk = pixel_key(seed, plane, pixel);
            match self.mode {
                Sampling::Independent => {
                    r.key.extend((0..n as u64).map(|k| pk ^ (2 * k)));
                    for v in [&mut r.pupil_i, &mut r.pupil_j, &mut r.area_i, &mut r.area_j] {
                        v.resize(v.len() + n, 0.0);
                    }
                }
                Sampling::Stratified => {
                    r.key.extend((0..n as u64).map(|k| pk ^ k));
                    r.pupil_i.extend_from_slice(&self.cell_i);
                    r.pupil_j.extend_from_slice(&self.cell_j);
                    let t0 = r.area_i.len();
                    r.area_i.extend_from_slice(&self.cell_i);
                    r.area_j.extend_from_slice(&self.cell_j);
                    let (ai, aj) = (&mut r.area_i[t0..t0 + n], &mut r.area_j[t0..t0 + n]);
                    let base = mix64(pk ^ u64::MAX);
                    for k in (1..n).rev() {
                        let j = fast_mod(mix64(base ^ k as u64), self.shuffle_magic[k], k as u64 + 1) as usize;
                        ai.swap(k, j);
                        aj.swap(k, j);
                    }
                }
            }
        }
    }
}


/// The object-space rays of a row's samples, as a structure of arrays (shared by the production renderer's
/// `RayLoop` and the differentiable renderer's `RayGen`): the field point — the scene-pixel centre
/// (`centre_x[t]`, `centre_y`, mm) moved by the sample's position in the pixel of `pitch_mm` — into `ox`, `oy`,
/// and the direction of [`PupilAim::direction`] into `dx`, `dy`, `dz`, divided by its length when `UNIT`
/// (glam's `length`, (x·x + y·y + z·z)^½, and `/ len` per component). Only `+ − × ÷ √`, so the same bits at
/// every SIMD level; `#[inline(always)]` so that it vectorises inside the caller's `VectorLoop::run`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn object_rays<const UNIT: bool>(
    s: &SampleRow,
    centre_x: &[f64],
    centre_y: f64,
    pitch_mm: f64,
    aim: crate::rays::PupilAim,
    ox: &mut [f64],
    oy: &mut [f64],
    dx: &mut [f64],
    dy: &mut [f64],
    dz: &mut [f64],
) {
    let n = s.len();
    let (px, py, sx, sy, cx) = (&s.px[..n], &s.py[..n], &s.sx[..n], &s.sy[..n], &centre_x[..n]);
    let (ox, oy, dx, dy, dz) = (&mut ox[..n], &mut oy[..n], &mut dx[..n], &mut dy[..n], &mut dz[..n]);
    for t in 0..n {
        let fx = cx[t] + (sx[t] - 0.5) * pitch_mm;
        let fy = centre_y - (sy[t] - 0.5) * pitch_mm;
        let d = aim.direction(fx, fy, px[t], py[t]);
        ox[t] = fx;
        oy[t] = fy;
        if UNIT {
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            dx[t] = d[0] / len;
            dy[t] = d[1] / len;
            dz[t] = d[2] / len;
        } else {
            dx[t] = d[0];
            dy[t] = d[1];
            dz[t] = d[2];
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

    /// The map as it was before the branch-free version (libm's cos and sin, a branch per wedge).
    fn concentric_disk_libm(u: f64, v: f64) -> [f64; 2] {
        let (a, b) = (2.0 * u - 1.0, 2.0 * v - 1.0);
        if a == 0.0 && b == 0.0 {
            return [0.0, 0.0];
        }
        let (r, phi) = if a.abs() > b.abs() { (a, std::f64::consts::FRAC_PI_4 * (b / a)) } else { (b, std::f64::consts::FRAC_PI_2 - std::f64::consts::FRAC_PI_4 * (a / b)) };
        [r * phi.cos(), r * phi.sin()]
    }

    use crate::render::trig::ulps;

    #[test]
    fn branch_free_disk_map_is_the_libm_map_to_two_ulp() {
        let n = 1500;
        let (mut worst, mut moved) = (0u64, 0usize);
        let mut check = |u: f64, v: f64| {
            let (p, q) = (concentric_disk(u, v), concentric_disk_libm(u, v));
            let d = ulps(p[0], q[0]).max(ulps(p[1], q[1]));
            worst = worst.max(d);
            moved += (d > 0) as usize;
        };
        for i in 0..=n {
            for j in 0..=n {
                check(i as f64 / n as f64, j as f64 / n as f64);
            }
        }
        // The centre, the diagonals (wedge boundaries) and the edges exactly.
        for &(u, v) in &[(0.5, 0.5), (0.0, 0.0), (1.0, 1.0), (0.0, 1.0), (1.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.75, 0.75), (0.25, 0.75)] {
            check(u, v);
        }
        assert_eq!(concentric_disk(0.5, 0.5), [0.0, 0.0]);
        assert!(worst <= 2, "worst {worst} ulp");
        println!("{moved} of {} points moved, by at most {worst} ulp", (n + 1) * (n + 1));
        // A minority of points move at all.
        assert!(moved * 10 < (n + 1) * (n + 1), "{moved} of {} points moved", (n + 1) * (n + 1));
    }

    #[test]
    fn the_row_fill_is_the_per_pixel_fill_at_every_level() {
        for mode in [Sampling::Stratified, Sampling::Independent] {
            for rays in [1, 7, 20, 64] {
                let pixels = [0u64, 5, 6, 1000, 65535];
                let reference = RaySampler::new(rays, mode);
                let mut want = Vec::new();
                for &q in &pixels {
                    let mut out = vec![[0.0; 4]; rays];
                    reference.fill(9, 4, q, &mut out);
                    want.extend(out);
                }
                for level in crate::tracer::SimdLevel::available() {
                    let s = RaySampler::new(rays, mode).with_level(level);
                    let mut row = SampleRow::default();
                    s.fill_pixels(9, 4, &pixels, &mut row);
                    assert_eq!(row.len(), want.len());
                    for (t, w) in want.iter().enumerate() {
                        let got = row.get(t);
                        assert!(got.iter().zip(w).all(|(a, b)| a.to_bits() == b.to_bits()), "{mode:?} {rays} {level:?} ray {t}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_fill_follows_the_documented_key_chain() {
        // Stratified ray k: hashes mix64(pk ^ k), then chained; pupil cell (k mod a, k div a).
        let s = RaySampler::new(20, Sampling::Stratified);
        let mut out = vec![[0.0; 4]; 20];
        s.fill(3, 1, 77, &mut out);
        let pk = pixel_key(3, 1, 77);
        for (k, o) in out.iter().enumerate() {
            let h1 = mix64(pk ^ k as u64);
            let h2 = mix64(h1);
            let p = concentric_disk(((k % 4) as f64 + unit(h1)) / 4.0, ((k / 4) as f64 + unit(h2)) / 5.0);
            assert_eq!([o[0], o[1]], p);
        }
        // Independent ray k: mix64(pk ^ 2k) chained for the pupil, mix64(pk ^ (2k+1)) for the area.
        let s = RaySampler::new(5, Sampling::Independent);
        let mut out = vec![[0.0; 4]; 5];
        s.fill(3, 1, 77, &mut out);
        for (k, o) in out.iter().enumerate() {
            let (h1, h3) = (mix64(pk ^ (2 * k as u64)), mix64(pk ^ (2 * k as u64 + 1)));
            let p = concentric_disk(unit(h1), unit(mix64(h1)));
            assert_eq!(*o, [p[0], p[1], unit(h3), unit(mix64(h3))]);
        }
    }

    #[test]
    fn fast_mod_is_the_remainder() {
        let mut xs = vec![0u64, 1, 2, 3, u64::MAX, u64::MAX - 1, 1 << 63, (1 << 63) - 1, 1 << 32, (1 << 32) - 1];
        xs.extend((0..2000u64).map(mix64));
        for d in (2..=5000u64).chain([65535, 65536, 1 << 31, (1 << 32) - 1, 1 << 32, u64::MAX / 3, u64::MAX]) {
            let c = mod_magic(d);
            for &x in xs.iter().chain(&[d, d - 1, d + 1, d * 2, d.wrapping_mul(12345), u64::MAX - u64::MAX % d]) {
                assert_eq!(fast_mod(x, c, d), x % d, "{x} mod {d}");
            }
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
