//! The hyperspectral scene: an H×W×B cube of radiances (or reflectances) at B wavelengths, plus spectral
//! resampling (linear interpolation in λ) and spatial fitting to the render field (centre crop or area resize).
use crate::error::{Error, Result};

/// A hyperspectral cube, C order `[row][col][band]` (the band index varies fastest, like an `(H, W, B)` NPY
/// array). Row 0 is the top of the scene (+y on the object plane), column 0 its left (−x).
#[derive(Clone, Debug, PartialEq)]
pub struct SpectralCube {
    pub height: usize,
    pub width: usize,
    /// Strictly increasing band wavelengths (nm).
    pub wavelengths_nm: Vec<f64>,
    pub data: Vec<f32>,
}

/// How to bring a scene to the render field (`size × size` pixels).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Fit {
    /// Centre crop; a scene smaller than the field is an error.
    Crop,
    /// Area-average (box filter) resize of the shorter side to the field (bilinear when enlarging), then a
    /// centre crop of the longer side.
    Resize,
}

impl Fit {
    /// `crop` or `resize` (the `--fit` option's words); an error names `--fit` and the text.
    pub fn parse(text: &str) -> Result<Fit> {
        match text {
            "crop" => Ok(Fit::Crop),
            "resize" => Ok(Fit::Resize),
            other => Err(crate::error::Error::invalid(format!("--fit `{other}`: use crop or resize"))),
        }
    }

    /// The word [`Fit::parse`] reads: `crop` or `resize`.
    pub fn name(self) -> &'static str {
        match self {
            Fit::Crop => "crop",
            Fit::Resize => "resize",
        }
    }
}

/// A cube's band wavelengths (nm): each finite and > 0, strictly increasing — what every reader of a scene
/// requires, so that a writer (`make-scene`) refuses what they would refuse. `what` names the source.
pub fn check_wavelengths(wavelengths_nm: &[f64], what: &str) -> Result<()> {
    for (k, w) in wavelengths_nm.iter().enumerate() {
        if !(w.is_finite() && *w > 0.0) {
            return Err(Error::invalid(format!("{what}: wavelength {k} = {w} nm must be finite and > 0")));
        }
        if k > 0 && !(*w > wavelengths_nm[k - 1]) {
            return Err(Error::invalid(format!("{what}: wavelengths must increase strictly ({} then {w} nm)", wavelengths_nm[k - 1])));
        }
    }
    Ok(())
}

/// [`SpectralCube::at_wavelengths`]: the cube as it is, resampled, or the first wavelength outside its range (nm).
#[derive(Clone, Debug)]
pub enum AtWavelengths {
    Same,
    Resampled(SpectralCube),
    Outside(f64),
}

impl SpectralCube {
    /// Check shape, finiteness and wavelength order; `what` names the source in messages.
    pub fn new(height: usize, width: usize, wavelengths_nm: Vec<f64>, data: Vec<f32>, what: &str) -> Result<Self> {
        if height == 0 || width == 0 || wavelengths_nm.is_empty() {
            return Err(Error::invalid(format!("{what}: empty cube ({height}×{width}×{})", wavelengths_nm.len())));
        }
        if data.len() != height * width * wavelengths_nm.len() {
            return Err(Error::invalid(format!("{what}: {} values for a {height}×{width}×{} cube", data.len(), wavelengths_nm.len())));
        }
        check_wavelengths(&wavelengths_nm, what)?;
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            let b = wavelengths_nm.len();
            return Err(Error::invalid(format!("{what}: value at row {}, col {}, band {} is {} (not finite)", i / b / width, (i / b) % width, i % b, data[i])));
        }
        Ok(SpectralCube { height, width, wavelengths_nm, data })
    }

    /// A cube filled with `value`.
    pub fn uniform(height: usize, width: usize, wavelengths_nm: Vec<f64>, value: f32) -> Self {
        let n = height * width * wavelengths_nm.len();
        SpectralCube { height, width, wavelengths_nm, data: vec![value; n] }
    }

    pub fn bands(&self) -> usize {
        self.wavelengths_nm.len()
    }

    #[inline]
    pub fn at(&self, row: usize, col: usize, band: usize) -> f32 {
        self.data[(row * self.width + col) * self.bands() + band]
    }

    /// Sum of every value (f64).
    pub fn total(&self) -> f64 {
        self.data.iter().map(|&v| v as f64).sum()
    }

    /// Linear-interpolation weights of wavelength `w` between the scene's bands: (lower band, weight of the
    /// upper band). Outside the scene's range the nearest band is used (constant extrapolation).
    pub fn interpolation(&self, w: f64) -> (usize, f64) {
        let ws = &self.wavelengths_nm;
        if ws.len() == 1 || w <= ws[0] {
            return (0, 0.0);
        }
        if w >= ws[ws.len() - 1] {
            return (ws.len() - 2, 1.0);
        }
        let k = ws.partition_point(|&x| x <= w) - 1;
        (k, (w - ws[k]) / (ws[k + 1] - ws[k]))
    }

    /// The scene at wavelength `w`, one value per pixel (row-major), linearly interpolated in λ.
    pub fn plane(&self, w: f64) -> Vec<f32> {
        let (k, t) = self.interpolation(w);
        let b = self.bands();
        let k1 = (k + 1).min(b - 1);
        let t = t as f32;
        (0..self.height * self.width).map(|p| (1.0 - t) * self.data[p * b + k] + t * self.data[p * b + k1]).collect()
    }

    /// The cube resampled to `wavelengths_nm` (linear interpolation, constant extrapolation).
    pub fn resample(&self, wavelengths_nm: &[f64]) -> Result<SpectralCube> {
        let planes: Vec<Vec<f32>> = wavelengths_nm.iter().map(|&w| self.plane(w)).collect();
        let nb = wavelengths_nm.len();
        let mut data = vec![0.0f32; self.height * self.width * nb];
        for (b, p) in planes.iter().enumerate() {
            for (q, v) in p.iter().enumerate() {
                data[q * nb + b] = *v;
            }
        }
        SpectralCube::new(self.height, self.width, wavelengths_nm.to_vec(), data, "resampled cube")
    }

    /// This cube brought to `wavelengths_nm` for a comparison (`evaluate`, `reconstruct --truth`): the same
    /// wavelengths (within 1e-9 nm), resampled when its bands cover them (within 1e-6 nm; linear in λ, never
    /// extrapolated), or the first wavelength outside its range. Callers word the refusal.
    pub fn at_wavelengths(&self, wavelengths_nm: &[f64]) -> Result<AtWavelengths> {
        let same = self.bands() == wavelengths_nm.len() && self.wavelengths_nm.iter().zip(wavelengths_nm).all(|(a, b)| (a - b).abs() <= 1e-9);
        if same {
            return Ok(AtWavelengths::Same);
        }
        let (lo, hi) = (self.wavelengths_nm[0], self.wavelengths_nm[self.bands() - 1]);
        match wavelengths_nm.iter().find(|&&w| w < lo - 1e-6 || w > hi + 1e-6) {
            Some(&w) => Ok(AtWavelengths::Outside(w)),
            None => Ok(AtWavelengths::Resampled(self.resample(wavelengths_nm)?)),
        }
    }

    /// The `h × w` window starting at (row0, col0).
    pub fn window(&self, row0: usize, col0: usize, h: usize, w: usize) -> Result<SpectralCube> {
        if row0 + h > self.height || col0 + w > self.width {
            return Err(Error::invalid(format!("window {h}×{w} at ({row0}, {col0}) exceeds the {}×{} scene", self.height, self.width)));
        }
        let b = self.bands();
        let mut data = Vec::with_capacity(h * w * b);
        for r in row0..row0 + h {
            let s = (r * self.width + col0) * b;
            data.extend_from_slice(&self.data[s..s + w * b]);
        }
        Ok(SpectralCube { height: h, width: w, wavelengths_nm: self.wavelengths_nm.clone(), data })
    }

    /// Bring the scene to `size × size` pixels.
    pub fn fit(&self, size: usize, fit: Fit) -> Result<SpectralCube> {
        if size == 0 {
            return Err(Error::invalid("scene size must be ≥ 1"));
        }
        if self.height == size && self.width == size {
            return Ok(self.clone());
        }
        match fit {
            Fit::Crop => {
                if self.height < size || self.width < size {
                    return Err(Error::invalid(format!(
                        "the scene is {}×{} pixels, smaller than the {size}×{size} field: use --fit resize or a smaller --scene-size",
                        self.height, self.width
                    )));
                }
                self.window((self.height - size) / 2, (self.width - size) / 2, size, size)
            }
            Fit::Resize => {
                let s = self.height.min(self.width) as f64 / size as f64; // source pixels per output pixel
                let (h, w) = (((self.height as f64 / s).round() as usize).max(size), ((self.width as f64 / s).round() as usize).max(size));
                let resized = self.resize(h, w);
                resized.window((h - size) / 2, (w - size) / 2, size, size)
            }
        }
    }

    /// Resize to `h × w`: area average when shrinking, bilinear when enlarging (per axis).
    fn resize(&self, h: usize, w: usize) -> SpectralCube {
        let rows = axis_weights(self.height, h);
        let cols = axis_weights(self.width, w);
        let b = self.bands();
        let mut data = vec![0.0f32; h * w * b];
        let mut acc = vec![0.0f64; b];
        for (r, rw) in rows.iter().enumerate() {
            for (c, cw) in cols.iter().enumerate() {
                acc.iter_mut().for_each(|a| *a = 0.0);
                for &(sr, wr) in rw {
                    for &(sc, wc) in cw {
                        let base = (sr * self.width + sc) * b;
                        for k in 0..b {
                            acc[k] += wr * wc * self.data[base + k] as f64;
                        }
                    }
                }
                let o = (r * w + c) * b;
                for k in 0..b {
                    data[o + k] = acc[k] as f32;
                }
            }
        }
        SpectralCube { height: h, width: w, wavelengths_nm: self.wavelengths_nm.clone(), data }
    }
}

/// Source samples and weights (summing to 1) of every output index when resampling `n` to `m`.
fn axis_weights(n: usize, m: usize) -> Vec<Vec<(usize, f64)>> {
    let s = n as f64 / m as f64;
    (0..m)
        .map(|i| {
            if s >= 1.0 {
                // Box filter: the output pixel covers [i·s, (i+1)·s) of the source.
                let (a, b) = (i as f64 * s, (i + 1) as f64 * s);
                let mut v = Vec::new();
                let mut j = a.floor() as usize;
                while (j as f64) < b && j < n {
                    let overlap = (b.min(j as f64 + 1.0) - a.max(j as f64)).max(0.0);
                    if overlap > 0.0 {
                        v.push((j, overlap / s));
                    }
                    j += 1;
                }
                v
            } else {
                // Bilinear between source centres.
                let x = ((i as f64 + 0.5) * s - 0.5).clamp(0.0, (n - 1) as f64);
                let j = (x.floor() as usize).min(n.saturating_sub(2));
                let t = x - j as f64;
                if n == 1 {
                    vec![(0, 1.0)]
                } else {
                    vec![(j, 1.0 - t), (j + 1, t)]
                }
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_and_resample() {
        let c = SpectralCube::new(1, 2, vec![400.0, 500.0, 600.0], vec![1.0, 2.0, 4.0, 0.0, 1.0, 2.0], "t").unwrap();
        assert_eq!(c.plane(450.0), vec![1.5, 0.5]);
        assert_eq!(c.plane(300.0), vec![1.0, 0.0]);
        assert_eq!(c.plane(700.0), vec![4.0, 2.0]);
        assert_eq!(c.plane(600.0), vec![4.0, 2.0]);
        let r = c.resample(&[500.0, 550.0]).unwrap();
        assert_eq!(r.data, vec![2.0, 3.0, 1.0, 1.5]);
        assert!(SpectralCube::new(1, 1, vec![500.0, 500.0], vec![0.0, 0.0], "t").is_err());
        assert!(SpectralCube::new(1, 1, vec![500.0], vec![f32::NAN], "t").unwrap_err().to_string().contains("not finite"));
    }

    #[test]
    fn fit_crop_and_resize_conserve_means() {
        let (h, w) = (6, 9);
        let data: Vec<f32> = (0..h * w).map(|i| (i % 7) as f32).collect();
        let c = SpectralCube::new(h, w, vec![500.0], data, "t").unwrap();
        let k = c.fit(4, Fit::Crop).unwrap();
        assert_eq!(k.at(0, 0, 0), c.at(1, 2, 0));
        assert!(c.fit(8, Fit::Crop).is_err());
        let u = SpectralCube::uniform(10, 20, vec![500.0], 3.0);
        let r = u.fit(5, Fit::Resize).unwrap();
        assert!(r.data.iter().all(|v| (v - 3.0).abs() < 1e-6));
        let e = u.fit(40, Fit::Resize).unwrap();
        assert_eq!((e.height, e.width), (40, 40));
        assert!(e.data.iter().all(|v| (v - 3.0).abs() < 1e-6));
    }
}
