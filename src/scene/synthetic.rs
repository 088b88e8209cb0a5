//! A seeded synthetic hyperspectral scene for tests and demos (real datasets are not shipped): a smooth
//! two-spectrum background gradient, then rectangles and discs with sharp edges, each with its own smooth
//! reflectance spectrum (a sum of Gaussians over an offset), some textured by a grating or a checkerboard.
//! Values lie in [0, 1]. The same seed gives the same cube at any wavelengths.
//!
//! ```
//! use diffcassi::scene::synthetic_scene;
//! let ws: Vec<f64> = (0..31).map(|k| 400.0 + 10.0 * k as f64).collect();
//! let a = synthetic_scene(64, 64, &ws, 7);
//! assert_eq!(a, synthetic_scene(64, 64, &ws, 7));
//! assert!(a.data.iter().all(|v| (0.0..=1.0).contains(v)));
//! ```
use super::SpectralCube;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A smooth reflectance spectrum: offset + Σ aᵢ exp(−(λ − cᵢ)² / 2σᵢ²), clamped to [0.02, 0.98].
#[derive(Clone, Debug)]
struct Spectrum {
    offset: f64,
    lobes: Vec<(f64, f64, f64)>, // (amplitude, centre nm, sigma nm)
}

impl Spectrum {
    fn random(rng: &mut ChaCha8Rng) -> Self {
        let n = rng.gen_range(1..=3);
        Spectrum {
            offset: rng.gen_range(0.02..0.3),
            lobes: (0..n).map(|_| (rng.gen_range(0.2..0.7), rng.gen_range(420.0..680.0), rng.gen_range(15.0..90.0))).collect(),
        }
    }
    fn at(&self, w: f64) -> f64 {
        let v = self.offset + self.lobes.iter().map(|&(a, c, s)| a * (-(w - c).powi(2) / (2.0 * s * s)).exp()).sum::<f64>();
        v.clamp(0.02, 0.98)
    }
}

enum Shape {
    Rect { r0: f64, c0: f64, r1: f64, c1: f64 },
    Disc { r: f64, c: f64, radius: f64 },
}

enum Texture {
    Flat,
    /// 0.5 + 0.5·cos(2π(k·x)) modulation, k in cycles per pixel.
    Grating { kr: f64, kc: f64, depth: f64 },
    Checker { period: f64, depth: f64 },
}

/// Generate the scene (`height × width` pixels at `wavelengths_nm`) for `seed`.
pub fn synthetic_scene(height: usize, width: usize, wavelengths_nm: &[f64], seed: u64) -> SpectralCube {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5CE9_E5CE_9E00_0000);
    let (h, w) = (height as f64, width as f64);
    let bg = (Spectrum::random(&mut rng), Spectrum::random(&mut rng));
    let angle: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
    let n_objects = 6 + rng.gen_range(0..6);
    let mut objects = Vec::new();
    for _ in 0..n_objects {
        let shape = if rng.gen_bool(0.5) {
            let (r0, c0) = (rng.gen_range(0.0..h), rng.gen_range(0.0..w));
            let (dh, dw) = (rng.gen_range(0.08..0.4) * h, rng.gen_range(0.08..0.4) * w);
            Shape::Rect { r0, c0, r1: r0 + dh, c1: c0 + dw }
        } else {
            Shape::Disc { r: rng.gen_range(0.0..h), c: rng.gen_range(0.0..w), radius: rng.gen_range(0.05..0.2) * h.min(w) }
        };
        let texture = match rng.gen_range(0..3) {
            0 => Texture::Flat,
            1 => Texture::Grating { kr: rng.gen_range(-0.15..0.15), kc: rng.gen_range(-0.15..0.15), depth: rng.gen_range(0.2..0.8) },
            _ => Texture::Checker { period: rng.gen_range(3.0..12.0), depth: rng.gen_range(0.2..0.8) },
        };
        objects.push((shape, texture, Spectrum::random(&mut rng)));
    }
    // Spectra tabulated once per wavelength.
    let tab = |s: &Spectrum| -> Vec<f64> { wavelengths_nm.iter().map(|&l| s.at(l)).collect() };
    let (bg0, bg1) = (tab(&bg.0), tab(&bg.1));
    let obj_tabs: Vec<Vec<f64>> = objects.iter().map(|o| tab(&o.2)).collect();
    let nb = wavelengths_nm.len();
    let mut data = vec![0.0f32; height * width * nb];
    let (ca, sa) = (angle.cos(), angle.sin());
    for r in 0..height {
        for c in 0..width {
            let (y, x) = (r as f64 + 0.5, c as f64 + 0.5);
            // Background: a linear blend of two spectra along a random direction.
            let t = (((x / w - 0.5) * ca + (y / h - 0.5) * sa) + 0.75) / 1.5;
            let mut top: Option<(usize, f64)> = None;
            for (k, (shape, texture, _)) in objects.iter().enumerate() {
                let inside = match *shape {
                    Shape::Rect { r0, c0, r1, c1 } => y >= r0 && y < r1 && x >= c0 && x < c1,
                    Shape::Disc { r, c, radius } => (y - r).powi(2) + (x - c).powi(2) <= radius * radius,
                };
                if inside {
                    let m = match *texture {
                        Texture::Flat => 1.0,
                        Texture::Grating { kr, kc, depth } => 1.0 - depth * 0.5 * (1.0 - (std::f64::consts::TAU * (kr * y + kc * x)).cos()),
                        Texture::Checker { period, depth } => {
                            if ((y / period).floor() as i64 + (x / period).floor() as i64) % 2 == 0 { 1.0 } else { 1.0 - depth }
                        }
                    };
                    top = Some((k, m)); // later objects are drawn over earlier ones
                }
            }
            let o = (r * width + c) * nb;
            for b in 0..nb {
                let v = match top {
                    Some((k, m)) => obj_tabs[k][b] * m,
                    None => (1.0 - t) * bg0[b] + t * bg1[b],
                };
                data[o + b] = v.clamp(0.0, 1.0) as f32;
            }
        }
    }
    SpectralCube { height, width, wavelengths_nm: wavelengths_nm.to_vec(), data }
}

/// The demo scene's native wavelengths: 31 bands, 400–700 nm by 10 nm (CAVE's sampling).
pub fn synthetic_wavelengths() -> Vec<f64> {
    (0..31).map(|k| 400.0 + 10.0 * k as f64).collect()
}
