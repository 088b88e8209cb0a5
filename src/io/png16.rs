//! Greyscale PNG in and out (the `image` crate, PNG only): 16-bit previews of acquisitions and masks,
//! and CAVE-style per-band scene images. Reading accepts 8- and 16-bit grey (or colour, which is an error
//! naming the file) and returns values scaled to [0, 1] (÷255 or ÷65535).
//!
//! ```
//! use diffcassi::io::png16::{read_png_gray, write_png_gray16};
//! # fn main() -> Result<(), diffcassi::io::IoError> {
//! let path = std::env::temp_dir().join(format!("diffcassi_png_doc_{}.png", std::process::id()));
//! write_png_gray16(&path, 3, 1, &[0, 32768, 65535])?;
//! let g = read_png_gray(&path)?;
//! assert_eq!((g.width, g.height, g.bit_depth), (3, 1, 16));
//! assert_eq!(g.values[2], 1.0);
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```
use super::{write_atomic, IoError};
use std::path::Path;

/// A greyscale image scaled to [0, 1], row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct GrayImage {
    pub width: usize,
    pub height: usize,
    /// 8 or 16.
    pub bit_depth: u8,
    pub values: Vec<f32>,
}

fn png_err(path: &Path, reason: impl Into<String>) -> IoError {
    IoError::Png { path: path.to_path_buf(), reason: reason.into() }
}

/// Write a 16-bit greyscale PNG (`width × height` samples, row-major), atomically.
pub fn write_png_gray16(path: impl AsRef<Path>, width: usize, height: usize, data: &[u16]) -> Result<(), IoError> {
    let path = path.as_ref();
    if data.len() != width * height || width == 0 || height == 0 {
        return Err(IoError::ShapeMismatch { path: path.to_path_buf(), shape: vec![height, width], expected: width * height, actual: data.len() });
    }
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(width as u32, height as u32, data.to_vec())
        .ok_or_else(|| png_err(path, "buffer size mismatch"))?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png).map_err(|e| png_err(path, format!("cannot encode: {e}")))?;
    write_atomic(path, bytes.get_ref())
}

/// The (width, height) a PNG's header declares, read without decoding the pixels; refused when decoding it
/// (`bytes_per_pixel` bytes per pixel, all copies together) would exceed the memory budget
/// ([`crate::limits::check_memory`]), so a huge image is an error before anything is allocated.
pub fn png_dimensions_within_budget(path: &Path, bytes: &[u8], bytes_per_pixel: f64) -> Result<(usize, usize), IoError> {
    let reader = image::ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::Png);
    let (w, h) = reader.into_dimensions().map_err(|e| png_err(path, format!("not a readable PNG (truncated or malformed?): {e}")))?;
    let what = format!("the {w}×{h} image");
    crate::limits::check_memory(&what, w as f64 * h as f64 * bytes_per_pixel).map_err(|e| png_err(path, e.to_string()))?;
    Ok((w as usize, h as usize))
}

/// Read a greyscale PNG (8 or 16 bit), values scaled to [0, 1]. The header is read first: an image too large
/// for the memory budget is refused before it is decoded.
pub fn read_png_gray(path: impl AsRef<Path>) -> Result<GrayImage, IoError> {
    let path = path.as_ref();
    let bytes = super::input::read_input(path, super::input::binary_limit())?;
    png_dimensions_within_budget(path, &bytes, 8.0)?; // decoded ≤ 2 B (4 B as RGBA8) + f32 values 4 B
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| png_err(path, format!("not a readable PNG (truncated or malformed?): {e}")))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    match img {
        image::DynamicImage::ImageLuma16(b) => Ok(GrayImage { width, height, bit_depth: 16, values: b.into_raw().iter().map(|&v| v as f32 / 65535.0).collect() }),
        image::DynamicImage::ImageLuma8(b) => Ok(GrayImage { width, height, bit_depth: 8, values: b.into_raw().iter().map(|&v| v as f32 / 255.0).collect() }),
        other => Err(png_err(path, format!("expected a greyscale PNG (8 or 16 bit), found colour type {:?}", other.color()))),
    }
}
