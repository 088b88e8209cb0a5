//! The coded aperture on the object plane: a transmission per scene pixel (binary for a real mask), the
//! same for every wavelength and every scene. Random binary masks draw each pixel open with probability
//! `opening` from a counter-based hash of (seed, pixel), so any pixel's state is reproducible alone.
//!
//! ```
//! use diffcassi::render::Mask;
//! let m = Mask::random(64, 64, 0.5, 3).unwrap();
//! let open = m.values.iter().filter(|&&v| v == 1.0).count();
//! assert!((open as f64 / 4096.0 - 0.5).abs() < 0.05);
//! assert_eq!(m, Mask::random(64, 64, 0.5, 3).unwrap());
//! ```
use super::sampling::key;
use crate::error::{Error, Result};
use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct Mask {
    pub height: usize,
    pub width: usize,
    /// Transmission in [0, 1], row-major.
    pub values: Vec<f32>,
    /// How it was made (for the JSON sidecar).
    pub description: String,
}

impl Mask {
    /// Every pixel open.
    pub fn open(height: usize, width: usize) -> Self {
        Mask { height, width, values: vec![1.0; height * width], description: "open".into() }
    }

    /// Random binary mask with opening ratio `opening` ∈ [0, 1].
    pub fn random(height: usize, width: usize, opening: f64, seed: u64) -> Result<Self> {
        if !(0.0..=1.0).contains(&opening) {
            return Err(Error::invalid(format!("mask opening ratio {opening} must be in [0, 1]")));
        }
        let values = (0..height * width)
            .map(|q| if ((key(seed, 0x4D41_534B, q as u64, 0) >> 11) as f64) < opening * (1u64 << 53) as f64 { 1.0 } else { 0.0 })
            .collect();
        Ok(Mask { height, width, values, description: format!("random binary, opening {opening}, seed {seed}") })
    }

    /// A vertical slit: only column `col` open.
    pub fn slit(height: usize, width: usize, col: usize) -> Self {
        let values = (0..height * width).map(|q| if q % width == col { 1.0 } else { 0.0 }).collect();
        Mask { height, width, values, description: format!("slit at column {col}") }
    }

    /// Read a mask from a greyscale PNG (values scaled to [0, 1]) or an (H, W) NPY of transmissions.
    pub fn load(path: &Path) -> Result<Self> {
        let ferr = |m: String| Error::File { path: path.display().to_string(), message: m };
        let (h, w, values) = match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
            Some("png") => {
                let g = crate::io::png16::read_png_gray(path)?;
                (g.height, g.width, g.values)
            }
            Some("npy") => {
                let (shape, data) = crate::io::read_npy_f64(path)?;
                if shape.len() != 2 {
                    return Err(ferr(format!("a mask must have shape (H, W), found {shape:?}")));
                }
                (shape[0], shape[1], data.iter().map(|&v| v as f32).collect())
            }
            _ => return Err(ferr("a mask is a greyscale .png or an (H, W) .npy".into())),
        };
        if let Some(v) = values.iter().find(|v| !(v.is_finite() && (0.0..=1.0).contains(*v))) {
            return Err(ferr(format!("mask value {v} is not a transmission in [0, 1]")));
        }
        // An NPY's transmissions are taken at the 16-bit steps the render folder's mask.png keeps: otherwise the
        // render used values its own mask.png does not hold, and the operator `reconstruct` rebuilds from that PNG
        // was no oracle (5e-6 of the peak apart; a held-out battery, round 7).
        Ok(Mask { height: h, width: w, values, description: format!("file {}", path.display()) }.at_png_steps())
    }

    /// The mask with its transmissions at the 16-bit steps `mask.png` keeps (t = code/65535, as a PNG reads
    /// back; [`Mask::png_codes`]), so that what a render used is what its folder records. A binary mask (or one
    /// already at those steps) is returned unchanged; otherwise the description says so. Mask files and the
    /// arrays Python's render, `Transport` and `exact` take go through it (Python took a greyscale array as
    /// given while recording the PNG's digest; round 9).
    pub fn at_png_steps(mut self) -> Mask {
        if self.values.iter().zip(self.png_codes()).any(|(&t, c)| t != c as f32 / 65535.0) {
            self.values = self.png_codes().iter().map(|&c| c as f32 / 65535.0).collect();
            self.description += " (transmissions at 16-bit steps, as mask.png holds them)";
        }
        self
    }

    /// Fraction of the area open (mean transmission).
    pub fn opening(&self) -> f64 {
        self.values.iter().map(|&v| v as f64).sum::<f64>() / self.values.len().max(1) as f64
    }

    /// Write as a 16-bit PNG (transmission × 65535).
    pub fn save_png(&self, path: &Path) -> Result<()> {
        Ok(crate::io::png16::write_png_gray16(path, self.width, self.height, &self.png_codes())?)
    }

    /// The 16-bit codes [`Mask::save_png`] stores, round(t·65535) of each transmission t (clamped to [0, 1]),
    /// row-major. A mask read back from that PNG ([`Mask::load`], t = code/65535) gives the same codes, and so
    /// does an 8-bit PNG of the same transmissions (k/255 → 257·k).
    pub fn png_codes(&self) -> Vec<u16> {
        self.values.iter().map(|&t| (t.clamp(0.0, 1.0) * 65535.0).round() as u16).collect()
    }

    /// SHA-256 of [`Mask::png_codes`] as little-endian bytes: `render.json`'s `mask_png_sha256`, recomputed by
    /// `reconstruct` from the mask file it reads, so a render folder whose mask was replaced is refused
    /// rather than reconstructed with the wrong mask.
    pub fn png_sha256(&self) -> String {
        let bytes: Vec<u8> = self.png_codes().iter().flat_map(|c| c.to_le_bytes()).collect();
        crate::io::sha256::sha256_hex(&bytes)
    }
}
