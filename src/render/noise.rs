//! Sensor noise applied to a rendered acquisition (off by default): photon shot noise, Gaussian read noise
//! and ADC quantisation, seeded and deterministic (see `docs/noise.md`).
//!
//! Model, per detector pixel with clean value v (acquisition units, ≥ 0):
//! 1. **Exposure**: the mean photo-electron count is λ = K·v with K electrons per acquisition unit (quantum
//!    efficiency folded in). K is given ([`NoiseConfig::electrons_per_unit`]) or, by default, set so the
//!    acquisition's peak fills the well: K = full_well / max(v) ("auto exposure to the peak").
//! 2. **Shot noise**: n ~ Poisson(λ) (photon arrivals; variance = mean = λ electrons).
//! 3. **Read noise**: n ← n + N(0, σ_read²) electrons (Gaussian, signal-independent).
//! 4. **ADC**: gain g = full_well / (2^bits − 1) electrons per DN (full well = full scale);
//!    DN = clamp(round(n / g), 0, 2^bits − 1), n ← DN·g. Clipping (saturation, no negative counts) happens
//!    only here; without the ADC, read noise can leave small negative values, as in an ideal analogue chain.
//! 5. The result is written back in acquisition units, v' = n / K, so noisy and clean acquisitions compare
//!    directly and downstream code (reconstruction) needs no change.
//!
//! Randomness: counter-based, one ChaCha8 stream per (pixel, source): key = `seed`, stream = 2·pixel + source
//! (shot = 0, read = 1; pixel = row-major index), word position 0. A pixel's draws therefore depend on its own
//! mean count only: the Poisson sampler's variable number of uniforms cannot shift the draws of the pixels
//! after it (with one row-major stream it did, so clean acquisitions 1e-7 apart — `--device cpu` and
//! `cuda` — took different noise over runs of hundreds of pixels; docs/gpu.md). Turning read noise on or off
//! does not change the shot-noise draws, and the result does not depend on the thread count or the order
//! the pixels are visited in.
//!
//! ```
//! use diffcassi::render::noise::NoiseConfig;
//! let cfg = NoiseConfig { shot: true, read_noise_e: 2.0, adc_bits: Some(12), ..NoiseConfig::default() };
//! let mut image = vec![0.25f64; 1000];
//! image[0] = 1.0; // the peak: 20 000 e⁻ by default
//! let report = cfg.apply(&mut image)?;
//! assert_eq!(report.electrons_per_unit, 20_000.0);
//! assert!(image.iter().all(|v| v.is_finite() && *v >= 0.0));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use crate::error::{Error, Result};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use rand_distr::{Distribution, Normal, Poisson};

/// The largest mean electron count per pixel accepted (far beyond any sensor's well; keeps Poisson sampling
/// in its accurate range).
pub const MAX_ELECTRONS: f64 = 1e9;

/// How the noise's random numbers are drawn (render.json's `noise.rng`, and part of a dataset's configuration,
/// so a dataset rendered with the earlier single row-major stream is another configuration).
pub const RNG: &str = "ChaCha8 per pixel: key = seed, stream = 2·pixel + source (0 shot, 1 read), pixel row-major";

/// The random-number stream of one (pixel, source): a clone of the seeded generator moved to its own stream,
/// word position 0.
fn pixel_stream(base: &ChaCha8Rng, pixel: usize, source: u64) -> ChaCha8Rng {
    let mut rng = base.clone();
    rng.set_stream(2 * pixel as u64 + source);
    rng.set_word_pos(0);
    rng
}

/// Sensor-noise settings. [`NoiseConfig::default`] is the default sensor with every source off.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct NoiseConfig {
    /// Poisson photon shot noise.
    pub shot: bool,
    /// Gaussian read noise σ (electrons); 0 = none.
    pub read_noise_e: f64,
    /// ADC bit depth (1–24); `None` = no quantisation.
    pub adc_bits: Option<u32>,
    /// Full-well capacity (electrons): the ADC's full scale and, without `electrons_per_unit`, the electrons
    /// at the acquisition's peak.
    pub full_well_e: f64,
    /// Exposure: electrons per acquisition unit; `None` = full_well_e / (acquisition peak).
    pub electrons_per_unit: Option<f64>,
    /// Seed of the noise's random numbers.
    pub seed: u64,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        NoiseConfig { shot: false, read_noise_e: 0.0, adc_bits: None, full_well_e: 20_000.0, electrons_per_unit: None, seed: 0 }
    }
}

/// What one application of the noise did (recorded in `render.json`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct NoiseReport {
    /// The exposure K used (electrons per acquisition unit; 0 when the noise is off and K is undefined).
    pub electrons_per_unit: f64,
    /// The clean acquisition's peak value and its mean electron count K·peak.
    pub clean_peak: f64,
    pub peak_electrons: f64,
    /// ADC gain (electrons per DN), when the ADC is on.
    pub adc_gain_e_per_dn: Option<f64>,
    /// Pixels clipped at the ADC's full scale.
    pub saturated_pixels: u64,
    pub clean_total: f64,
    pub noisy_total: f64,
}

impl NoiseConfig {
    /// Whether any noise source is on.
    pub fn is_on(&self) -> bool {
        self.shot || self.read_noise_e > 0.0 || self.adc_bits.is_some()
    }

    /// Check every number (finite, in range).
    pub fn validate(&self) -> Result<()> {
        if !(self.read_noise_e.is_finite() && self.read_noise_e >= 0.0 && self.read_noise_e <= MAX_ELECTRONS) {
            return Err(Error::invalid(format!("read noise {} e⁻ must be finite, in [0, {MAX_ELECTRONS:e}]", crate::limits::fmt_num(self.read_noise_e))));
        }
        if !(self.full_well_e.is_finite() && self.full_well_e >= 1.0 && self.full_well_e <= MAX_ELECTRONS) {
            return Err(Error::invalid(format!("full well {} e⁻ must be finite, in [1, {MAX_ELECTRONS:e}]", crate::limits::fmt_num(self.full_well_e))));
        }
        if let Some(k) = self.electrons_per_unit {
            if !(k.is_finite() && k > 0.0) {
                return Err(Error::invalid(format!("electrons per unit {} must be finite and > 0", crate::limits::fmt_num(k))));
            }
        }
        if let Some(b) = self.adc_bits {
            if !(1..=24).contains(&b) {
                return Err(Error::invalid(format!("ADC bit depth {b} must be in 1–24")));
            }
        }
        Ok(())
    }

    /// The exposure K for an acquisition whose peak is `peak` (electrons per unit).
    pub fn exposure(&self, peak: f64) -> Result<f64> {
        let k = match self.electrons_per_unit {
            Some(k) => k,
            None if peak > 0.0 => self.full_well_e / peak,
            None => return Err(Error::invalid("the acquisition is black (peak 0): noise with auto exposure needs --electrons-per-unit")),
        };
        // Auto exposure puts the full well (≤ MAX_ELECTRONS, validated) in the peak by construction; K·peak
        // can round one ulp above it (a full well of 1e9 was refused, blaming electrons per unit nobody gave).
        if self.electrons_per_unit.is_some() && k * peak > MAX_ELECTRONS {
            return Err(Error::invalid(format!("{} electrons per unit put {:.3e} e⁻ in the peak pixel; at most {MAX_ELECTRONS:e} are supported: lower --electrons-per-unit", crate::limits::fmt_num(k), k * peak)));
        }
        self.check_steps(k)?;
        Ok(k)
    }

    /// The ADC gain (electrons per DN: the full well over the largest code), when the ADC is on.
    pub fn adc_gain(&self) -> Option<f64> {
        self.adc_bits.map(|b| self.full_well_e / ((1u64 << b) - 1) as f64)
    }

    /// One ADC step and the read noise's σ in acquisition units (g/K, σ/K) within the ±[`MAX_SCENE_VALUE`]
    /// an acquisition holds: beyond it no pixel but 0 can be written, and the noise's norm, which
    /// `reconstruct` estimates from them, is not a number (`--electrons-per-unit 1e-150` with the ADC on
    /// wrote a zero acquisition, exit 0, that `reconstruct` refused as "δ = inf"; round 16).
    ///
    /// [`MAX_SCENE_VALUE`]: crate::limits::MAX_SCENE_VALUE
    pub fn check_steps(&self, k: f64) -> Result<()> {
        let max = crate::limits::MAX_SCENE_VALUE;
        for (what, e) in [("one ADC step", self.adc_gain()), ("the read noise σ", (self.read_noise_e > 0.0).then_some(self.read_noise_e))] {
            if let Some(e) = e {
                if !(e / k <= max) {
                    return Err(Error::invalid(format!(
                        "{what} ({:.4e} e⁻) is {:.3e} acquisition units at {} electrons per unit, beyond the ±{max:.3e} an acquisition holds within f32's range (what `reconstruct` reads): raise the exposure (--electrons-per-unit)",
                        e,
                        e / k,
                        crate::limits::fmt_num(k)
                    )));
                }
            }
        }
        Ok(())
    }

    /// Apply the noise to `image` (acquisition units, in place; see the module docs). With every source off
    /// the image is left untouched.
    pub fn apply(&self, image: &mut [f64]) -> Result<NoiseReport> {
        self.validate()?;
        if let Some(i) = image.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(format!("acquisition pixel {i} is {} (not finite)", image[i])));
        }
        let peak = image.iter().cloned().fold(0.0, f64::max);
        let clean_total: f64 = image.iter().sum();
        if !self.is_on() {
            let k = self.exposure(peak).unwrap_or(0.0);
            return Ok(NoiseReport { electrons_per_unit: k, clean_peak: peak, peak_electrons: k * peak, adc_gain_e_per_dn: None, saturated_pixels: 0, clean_total, noisy_total: clean_total });
        }
        let k = self.exposure(peak)?;
        let gain = self.adc_gain();
        let mut report = NoiseReport { electrons_per_unit: k, clean_peak: peak, peak_electrons: k * peak, adc_gain_e_per_dn: gain, saturated_pixels: 0, clean_total, noisy_total: clean_total };
        let base = ChaCha8Rng::seed_from_u64(self.seed);
        let read = Normal::new(0.0, self.read_noise_e).map_err(|e| Error::invalid(format!("read noise: {e}")))?;
        let max_dn = self.adc_bits.map(|b| ((1u64 << b) - 1) as f64).unwrap_or(0.0);
        // Into a copy, so that an error leaves `image` as it was. Each pixel draws from its own streams, so
        // the pixels are independent and run in parallel; the first error in pixel order is reported.
        let noisy: Vec<Result<(f64, bool)>> = image
            .par_iter()
            .enumerate()
            .map(|(i, v)| {
                let mean_e = (*v * k).max(0.0);
                let mut e = mean_e;
                if self.shot {
                    // rand_distr 0.4's Knuth sampler returns −1 when e^{−λ} rounds to 1 (λ ≲ 1.1e-16): there
                    // the Poisson draw is 0 with probability 1 − λ, i.e. to f64's resolution.
                    e = if mean_e > 0.0 && (-mean_e).exp() < 1.0 {
                        Poisson::new(mean_e).map_err(|err| Error::invalid(format!("shot noise at {mean_e} e⁻: {err}")))?.sample(&mut pixel_stream(&base, i, 0))
                    } else {
                        0.0
                    };
                }
                if self.read_noise_e > 0.0 {
                    e += read.sample(&mut pixel_stream(&base, i, 1));
                }
                let mut saturated = false;
                if let Some(g) = gain {
                    let dn = (e / g).round();
                    saturated = dn > max_dn;
                    e = dn.clamp(0.0, max_dn) * g;
                }
                // `+ 0.0`: a read-noise draw rounded to −0 DN is written as 0, not −0.
                let v = e / k + 0.0;
                // Written as f32 (EXR, NPY) and read back by `reconstruct`, whose limit is the scene radiance
                // limit: a noisy value beyond it (a tiny exposure K dividing the electrons back) is refused here,
                // naming the exposure, rather than written as inf or refused later as "scale the scene down".
                if !(v.abs() <= crate::limits::MAX_SCENE_VALUE) {
                    return Err(Error::invalid(format!(
                        "the noisy acquisition reaches {:.3e} ({:.3e} e⁻ / {} electrons per unit), beyond ±{:.3e}, within f32's range what `reconstruct` accepts: raise the exposure (--electrons-per-unit) or lower the read noise ({} e⁻)",
                        e / k,
                        e,
                        crate::limits::fmt_num(k),
                        crate::limits::MAX_SCENE_VALUE,
                        crate::limits::fmt_num(self.read_noise_e)
                    )));
                }
                Ok((v, saturated))
            })
            .collect();
        let mut values = Vec::with_capacity(image.len());
        for r in noisy {
            let (v, saturated) = r?;
            report.saturated_pixels += saturated as u64;
            values.push(v);
        }
        image.copy_from_slice(&values);
        report.noisy_total = image.iter().sum();
        Ok(report)
    }

    /// The sources that are on, as `--noise` and render.json's `noise.sources` name them (shot, read, adc).
    pub fn sources(&self) -> Vec<&'static str> {
        let mut sources = Vec::new();
        if self.shot {
            sources.push("shot");
        }
        if self.read_noise_e > 0.0 {
            sources.push("read");
        }
        if self.adc_bits.is_some() {
            sources.push("adc");
        }
        sources
    }

    /// The `noise` object of `render.json`: the settings and the report; keys of sources that are off are
    /// left out (no null numbers).
    pub fn to_json(&self, report: &NoiseReport) -> serde_json::Value {
        let sources = self.sources();
        let mut j = serde_json::json!({
            "sources": sources,
            "model": "electrons = Poisson(K·v) [shot] + N(0, read_noise_e²) [read]; ADC: DN = clamp(round(e/gain), 0, 2^bits−1), e = DN·gain; written back as e/K (acquisition units)",
            "full_well_e": self.full_well_e,
            "exposure": if self.electrons_per_unit.is_some() { "given (electrons_per_unit)" } else { "auto: the clean peak maps to full_well_e" },
            "electrons_per_unit": report.electrons_per_unit,
            "clean_peak": report.clean_peak,
            "peak_electrons": report.peak_electrons,
            "seed": self.seed,
            "rng": RNG,
            "clean_total": report.clean_total,
            "noisy_total": report.noisy_total,
        });
        let o = j.as_object_mut().expect("an object");
        if self.read_noise_e > 0.0 {
            o.insert("read_noise_e".into(), self.read_noise_e.into());
        }
        if let (Some(b), Some(g)) = (self.adc_bits, report.adc_gain_e_per_dn) {
            o.insert("adc_bits".into(), b.into());
            o.insert("adc_gain_e_per_dn".into(), g.into());
            o.insert("saturated_pixels".into(), report.saturated_pixels.into());
        }
        j
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Mean and unbiased variance.
    fn moments(v: &[f64]) -> (f64, f64) {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        (m, v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0))
    }

    const N: usize = 200_000;

    /// Read noise rounded to 0 DN by the ADC was written as −0 (≈ 345 pixels a scene; round 9): now +0.
    #[test]
    fn the_adc_writes_no_negative_zero() {
        let cfg = NoiseConfig { read_noise_e: 2.0, adc_bits: Some(12), electrons_per_unit: Some(1000.0), seed: 3, ..NoiseConfig::default() };
        let mut img = vec![0.0; 10_000];
        img[0] = 1.0;
        cfg.apply(&mut img).unwrap();
        assert!(img.iter().any(|v| *v == 0.0), "some pixels round to 0 DN");
        assert!(img.iter().all(|v| !(v.is_sign_negative() && *v == 0.0)), "a −0 was written");
    }

    #[test]
    fn shot_noise_mean_and_variance_are_poisson() {
        // Flat image v = 0.5 with K = 400 e⁻/unit: λ = 200 e⁻; in units mean 0.5, variance λ/K² = 1.25e-3.
        let cfg = NoiseConfig { shot: true, electrons_per_unit: Some(400.0), seed: 7, ..NoiseConfig::default() };
        let mut img = vec![0.5; N];
        let r = cfg.apply(&mut img).unwrap();
        assert_eq!(r.electrons_per_unit, 400.0);
        let (m, var) = moments(&img);
        let (lambda, k) = (200.0, 400.0);
        let var_theory = lambda / (k * k);
        // 5 standard errors: SE(mean) = √(var/N); SE(var) = √((μ₄ − σ⁴)/N), μ₄ = λ + 3λ² (Poisson), in units /K⁴.
        let se_m = (var_theory / N as f64).sqrt();
        let se_v = ((lambda + 2.0 * lambda * lambda) / N as f64).sqrt() / (k * k);
        assert!((m - 0.5).abs() < 5.0 * se_m, "mean {m}");
        assert!((var - var_theory).abs() < 5.0 * se_v, "variance {var} vs {var_theory}");
        // Counts are integers of electrons.
        assert!(img.iter().all(|v| ((v * k) - (v * k).round()).abs() < 1e-9));
    }

    #[test]
    fn read_noise_mean_and_variance_are_gaussian() {
        // Auto exposure: peak 2.0 ↦ 20 000 e⁻, K = 10 000; σ = 5 e⁻ → 5e-4 units.
        let cfg = NoiseConfig { read_noise_e: 5.0, seed: 3, ..NoiseConfig::default() };
        let mut img = vec![1.0; N];
        img[0] = 2.0;
        let r = cfg.apply(&mut img).unwrap();
        assert_eq!(r.electrons_per_unit, 10_000.0);
        let (m, var) = moments(&img[1..]);
        let var_theory = (5.0f64 / 10_000.0).powi(2);
        let n = (N - 1) as f64;
        assert!((m - 1.0).abs() < 5.0 * (var_theory / n).sqrt(), "mean {m}");
        assert!((var - var_theory).abs() < 5.0 * (2.0 / n).sqrt() * var_theory, "variance {var} vs {var_theory}");
        // Independent of the value: the same draws on a zero image give negatives (no clipping without an ADC).
        let mut zero = vec![0.0; 10];
        NoiseConfig { electrons_per_unit: Some(1.0), ..cfg.clone() }.apply(&mut zero).unwrap();
        assert!(zero.iter().any(|&v| v < 0.0));
    }

    #[test]
    fn adc_quantises_to_levels_and_clips() {
        // 4 bits, full well 15 e⁻: gain 1 e⁻/DN; K = 10 e⁻/unit: levels are multiples of 0.1 units in [0, 1.5].
        let cfg = NoiseConfig { adc_bits: Some(4), full_well_e: 15.0, electrons_per_unit: Some(10.0), ..NoiseConfig::default() };
        let mut img: Vec<f64> = (0..=40).map(|i| i as f64 * 0.05 - 0.2).map(|v: f64| v.max(0.0)).collect();
        img.push(3.0);
        let r = cfg.apply(&mut img).unwrap();
        assert_eq!(r.adc_gain_e_per_dn, Some(1.0));
        for v in &img {
            let dn = v * 10.0;
            assert!((dn - dn.round()).abs() < 1e-12 && (0.0..=15.0).contains(&dn.round()), "{v}");
        }
        let levels: std::collections::BTreeSet<i64> = img.iter().map(|v| (v * 10.0).round() as i64).collect();
        assert_eq!(levels.len(), 16, "{levels:?}"); // 0..=15 all reached
        assert_eq!(img[img.len() - 1], 1.5); // 30 e⁻ clipped to full scale
        assert!(r.saturated_pixels >= 1);
        // Rounding to the nearest level: 0.34 units = 3.4 e⁻ → 3 DN.
        let mut one = vec![0.34, 1.0];
        cfg.apply(&mut one).unwrap();
        assert!((one[0] - 0.3).abs() < 1e-12);
    }

    #[test]
    fn deterministic_seeded_and_off_is_identity() {
        let img: Vec<f64> = (0..5000).map(|i| ((i * 37) % 101) as f64 / 100.0).collect();
        let cfg = NoiseConfig { shot: true, read_noise_e: 3.0, adc_bits: Some(12), seed: 11, ..NoiseConfig::default() };
        let (mut a, mut b, mut c) = (img.clone(), img.clone(), img.clone());
        cfg.apply(&mut a).unwrap();
        cfg.apply(&mut b).unwrap();
        NoiseConfig { seed: 12, ..cfg.clone() }.apply(&mut c).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(a.iter().all(|v| v.is_finite()));
        // Shot draws do not depend on whether read noise is on (separate streams).
        let (mut s1, mut s2) = (img.clone(), img.clone());
        NoiseConfig { shot: true, seed: 11, ..NoiseConfig::default() }.apply(&mut s1).unwrap();
        let r = NoiseConfig { shot: true, read_noise_e: 1e-9, seed: 11, ..NoiseConfig::default() }.apply(&mut s2).unwrap();
        assert!(s1.iter().zip(&s2).all(|(x, y)| (x - y).abs() * r.electrons_per_unit < 1e-6));
        // Off: untouched, bit for bit.
        let mut d = img.clone();
        let off = NoiseConfig::default();
        assert!(!off.is_on());
        off.apply(&mut d).unwrap();
        assert_eq!(d, img);
    }

    /// Pixels whose mean count λ is so small that e^{−λ} rounds to 1 (rand_distr's Knuth sampler returned −1
    /// there: a negative photon count, found by a held-out battery) draw 0, and the other pixels' draws stay
    /// those of the same stream.
    #[test]
    fn shot_noise_is_never_negative_at_tiny_counts() {
        let mut img = vec![1e-22; 64];
        img[10] = 1.0;
        img[20] = 1e-3;
        let cfg = NoiseConfig { shot: true, seed: 5, ..NoiseConfig::default() };
        let mut a = img.clone();
        let r = cfg.apply(&mut a).unwrap();
        assert!(r.electrons_per_unit * 1e-22 < 1e-16);
        assert!(a.iter().all(|v| *v >= 0.0), "{a:?}");
        assert!(a.iter().enumerate().all(|(i, v)| i == 10 || i == 20 || *v == 0.0));
        // The bright pixels' draws are those of the stream without the tiny ones (they consume no draw).
        let mut b = vec![0.0; 64];
        (b[10], b[20]) = (1.0, 1e-3);
        cfg.apply(&mut b).unwrap();
        assert_eq!((a[10], a[20]), (b[10], b[20]));
    }

    /// A pixel's noise depends on its own mean count only: changing another pixel's value (so that its
    /// Poisson sampler draws another number of uniforms) leaves every other pixel's draw unchanged. With the
    /// earlier single row-major stream it shifted the draws of the pixels after it (docs/gpu.md: CPU and GPU
    /// acquisitions 1e-7 apart took different noise over 263 pixels).
    #[test]
    fn each_pixel_draws_from_its_own_streams() {
        let img: Vec<f64> = (0..4000).map(|i| 0.05 + ((i * 37) % 101) as f64 / 100.0).collect();
        let cfg = NoiseConfig { shot: true, read_noise_e: 3.0, adc_bits: Some(12), electrons_per_unit: Some(2_000.0), seed: 8, ..NoiseConfig::default() };
        let mut a = img.clone();
        cfg.apply(&mut a).unwrap();
        // Pixel 100 across the Knuth/rejection boundary (λ 10 → 14 e⁻) and to 0: no other pixel changes.
        for v in [0.005, 0.007, 0.0, 0.3] {
            let mut changed = img.clone();
            changed[100] = v;
            cfg.apply(&mut changed).unwrap();
            assert!(a.iter().zip(&changed).enumerate().all(|(i, (x, y))| i == 100 || x == y), "pixel 100 = {v} moved other pixels");
        }
        // The same pixels in a shorter image (a crop from the start) draw the same numbers.
        let mut head = img[..1000].to_vec();
        cfg.apply(&mut head).unwrap();
        assert_eq!(head, a[..1000]);
        // Independent of the thread count.
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut t = img.clone();
            pool.install(|| cfg.apply(&mut t)).unwrap();
            assert_eq!(t, a, "{threads} threads");
        }
        // Neighbouring pixels are not correlated (their streams differ): lag-1 correlation of the residuals.
        let r: Vec<f64> = a.iter().zip(&img).map(|(x, y)| x - y).collect();
        let (m, var) = moments(&r);
        let lag1 = r.windows(2).map(|w| (w[0] - m) * (w[1] - m)).sum::<f64>() / ((r.len() - 1) as f64 * var);
        assert!(lag1.abs() < 5.0 / (r.len() as f64).sqrt(), "lag-1 correlation {lag1}");
    }

    #[test]
    fn bad_settings_are_refused() {
        let mut img = vec![0.5; 4];
        for (cfg, what) in [
            (NoiseConfig { read_noise_e: -1.0, ..NoiseConfig::default() }, "read noise"),
            (NoiseConfig { read_noise_e: f64::NAN, ..NoiseConfig::default() }, "read noise"),
            (NoiseConfig { full_well_e: 0.0, shot: true, ..NoiseConfig::default() }, "full well"),
            (NoiseConfig { electrons_per_unit: Some(-2.0), shot: true, ..NoiseConfig::default() }, "electrons per unit"),
            (NoiseConfig { adc_bits: Some(0), ..NoiseConfig::default() }, "bit depth"),
            (NoiseConfig { adc_bits: Some(32), ..NoiseConfig::default() }, "bit depth"),
            (NoiseConfig { electrons_per_unit: Some(1e12), shot: true, ..NoiseConfig::default() }, "at most"),
            (NoiseConfig { read_noise_e: 1e308, ..NoiseConfig::default() }, "read noise"),
            // A tiny exposure divides the electrons back into values beyond f32 (written as inf before).
            (NoiseConfig { read_noise_e: 2.0, electrons_per_unit: Some(1e-300), ..NoiseConfig::default() }, "f32's range"),
        ] {
            let e = cfg.apply(&mut img).unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        }
        // The largest full well with auto exposure, whose K·peak rounds one ulp above it (0.23 × (1e9/0.23)).
        let mut top = vec![0.23, 0.1];
        let r = NoiseConfig { shot: true, full_well_e: MAX_ELECTRONS, ..NoiseConfig::default() }.apply(&mut top).unwrap();
        assert!(r.peak_electrons > MAX_ELECTRONS && r.peak_electrons < MAX_ELECTRONS * (1.0 + 1e-15), "{}", r.peak_electrons);
        let mut black = vec![0.0; 4];
        assert!(NoiseConfig { shot: true, ..NoiseConfig::default() }.apply(&mut black).unwrap_err().to_string().contains("black"));
        assert_eq!(img, vec![0.5; 4]);
    }
}
