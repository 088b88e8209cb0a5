//! OpenEXR images with named `f32` channels (via the `exr` crate): any number of channels, all of the same
//! size; a multi-part file's parts are read together (one data window). Used for acquisitions (`acquisition.exr`, one channel `Y`), rendered cubes
//! (one channel per band, names zero-padded so they sort) and KAIST-style multichannel scenes.
//!
//! Writing is atomic (the file is encoded in memory, then [`super::write_atomic`]). Reading accepts
//! `f16`, `f32` and `u32` channels (converted to `f32`) and reports truncated or malformed files as
//! [`IoError::Exr`] naming the file.
//!
//! ```
//! use diffcassi::io::exr::{read_exr, write_exr, ExrChannel};
//! # fn main() -> Result<(), diffcassi::io::IoError> {
//! let path = std::env::temp_dir().join(format!("diffcassi_exr_doc_{}.exr", std::process::id()));
//! let ch = ExrChannel { name: "band_00_450.0nm".into(), data: vec![0.0, 0.5, 1.0, 2.0] };
//! write_exr(&path, 2, 2, &[ch])?;
//! let img = read_exr(&path)?;
//! assert_eq!((img.width, img.height), (2, 2));
//! assert_eq!(img.channels[0].name, "band_00_450.0nm");
//! assert_eq!(img.channels[0].data[3], 2.0);
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```
use super::{write_atomic, IoError};
use exr::prelude::{read, AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, ReadChannels, ReadLayers, SmallVec, Vec2, WritableImage};
use std::path::Path;

/// One named channel, row-major (row 0 first), `width × height` samples.
#[derive(Clone, Debug, PartialEq)]
pub struct ExrChannel {
    pub name: String,
    pub data: Vec<f32>,
}

/// An EXR image: size and channels (in the file's order, which EXR keeps sorted by name).
#[derive(Clone, Debug, PartialEq)]
pub struct ExrImage {
    pub width: usize,
    pub height: usize,
    pub channels: Vec<ExrChannel>,
}

fn exr_err(path: &Path, reason: impl Into<String>) -> IoError {
    IoError::Exr { path: path.to_path_buf(), reason: reason.into() }
}

/// Write `channels` (each `width × height` f32, row-major) as one EXR layer, lossless (ZIP), atomically.
pub fn write_exr(path: impl AsRef<Path>, width: usize, height: usize, channels: &[ExrChannel]) -> Result<(), IoError> {
    let path = path.as_ref();
    if width == 0 || height == 0 || channels.is_empty() {
        return Err(exr_err(path, format!("cannot write an empty image ({width}×{height}, {} channels)", channels.len())));
    }
    let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
    for c in channels {
        if c.data.len() != width * height {
            return Err(IoError::ShapeMismatch { path: path.to_path_buf(), shape: vec![height, width], expected: width * height, actual: c.data.len() });
        }
        if c.name.is_empty() || !c.name.is_ascii() {
            return Err(exr_err(path, format!("channel name `{}` must be non-empty ASCII", c.name)));
        }
        // Every EXR the project writes (acquisitions, cubes, scenes) goes through here: a NaN or inf is refused
        // before the file exists (a sub-pixel Airy disk once put NaN in a dataset's acquisitions, exit 0).
        if let Some(i) = c.data.iter().position(|v| !v.is_finite()) {
            return Err(exr_err(path, format!("channel {}: pixel {i} (row {}, col {}) is {}; refusing to write a non-finite value", c.name, i / width, i % width, c.data[i])));
        }
        list.push(AnyChannel::new(c.name.as_str(), FlatSamples::F32(c.data.clone())));
    }
    let layer = Layer::new((width, height), LayerAttributes::named("diffcassi"), Encoding::SMALL_LOSSLESS, AnyChannels::sort(list));
    let image = Image::from_layer(layer);
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write().non_parallel().to_buffered(&mut bytes).map_err(|e| exr_err(path, format!("cannot encode: {e}")))?;
    write_atomic(path, bytes.get_ref())
}

/// The decoded size the header declares, checked before the decoder allocates it (a corrupt or hostile
/// header can declare 10⁸ × 10⁸ pixels in a few bytes; found by `tests/fuzz.rs`): within the memory budget
/// ([`crate::limits`]) and at most 10⁴ times the file size (no real compression reaches that) above 256 MB.
fn check_declared_size(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)
        .map_err(|e| exr_err(path, format!("not a readable OpenEXR file (truncated or malformed?): {e}")))?;
    // Every part is read (see [`read_exr`]): the decoded size is the sum over the parts.
    let (mut decoded, mut channels, mut pixels) = (0.0f64, 0usize, String::new());
    for h in meta.headers.iter() {
        let (w, hgt) = (h.layer_size.width() as f64, h.layer_size.height() as f64);
        decoded += w * hgt * h.channels.list.len().max(1) as f64 * 4.0;
        channels += h.channels.list.len();
        if pixels.is_empty() {
            pixels = format!("{w}×{hgt}");
        }
    }
    let parts = if meta.headers.len() > 1 { format!(" in {} parts", meta.headers.len()) } else { String::new() };
    let plausible = (bytes.len() as f64 * 1e4).max(256e6);
    if decoded > plausible {
        return Err(exr_err(path, format!("the header declares {pixels} pixels × {channels} channels{parts} ({decoded:.3e} bytes decoded) from a {}-byte file: corrupt or hostile", bytes.len())));
    }
    crate::limits::check_memory(&format!("{} ({pixels} pixels × {channels} channels{parts})", path.display()), decoded).map_err(|e| exr_err(path, e.to_string()))?;
    Ok(())
}

/// Read an EXR file, every channel of **every part** (layer) as `f32`. A multi-part file's parts must share
/// one data window (size and position): their channels are then one image, in the file's part order (a
/// reader that kept only the first part dropped the other parts' bands without a word; a held-out battery,
/// round 17). Parts of different windows, or one channel name in two parts, are an error naming the parts.
pub fn read_exr(path: impl AsRef<Path>) -> Result<ExrImage, IoError> {
    let path = path.as_ref();
    let bytes = super::input::read_input(path, super::input::binary_limit())?;
    check_declared_size(path, &bytes)?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .pedantic()
        .non_parallel()
        .from_buffered(std::io::Cursor::new(bytes))
        .map_err(|e| exr_err(path, format!("not a readable OpenEXR file (truncated or malformed?): {e}")))?;
    let part_name = |k: usize, a: &LayerAttributes| match &a.layer_name {
        Some(n) => format!("part {k} `{n}`"),
        None => format!("part {k}"),
    };
    let first = image.layer_data.first().ok_or_else(|| exr_err(path, "the file holds no image part"))?;
    let (width, height) = (first.size.width(), first.size.height());
    let origin = first.attributes.layer_position;
    let first_name = part_name(0, &first.attributes);
    let mut channels: Vec<ExrChannel> = Vec::new();
    let mut owner: Vec<String> = Vec::new();
    for (k, layer) in image.layer_data.into_iter().enumerate() {
        let part = part_name(k, &layer.attributes);
        if (layer.size.width(), layer.size.height()) != (width, height) || layer.attributes.layer_position != origin {
            return Err(exr_err(
                path,
                format!(
                    "{part} is {}×{} pixels at ({}, {}) but {first_name} is {width}×{height} at ({}, {}): the parts of a multi-part file must share one data window to be read as one cube",
                    layer.size.width(),
                    layer.size.height(),
                    layer.attributes.layer_position.x(),
                    layer.attributes.layer_position.y(),
                    origin.x(),
                    origin.y()
                ),
            ));
        }
        for c in layer.channel_data.list {
            if c.sampling != Vec2(1, 1) {
                return Err(exr_err(path, format!("{part}: channel `{}` is subsampled ({:?}); only full-resolution channels are supported", c.name, c.sampling)));
            }
            let name = c.name.to_string();
            if let Some(j) = channels.iter().position(|x| x.name == name) {
                return Err(exr_err(path, format!("channel `{name}` is in both {} and {part}: give each band one name", owner[j])));
            }
            let data: Vec<f32> = match c.sample_data {
                FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
                FlatSamples::F32(v) => v,
                FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
            };
            if data.len() != width * height {
                return Err(exr_err(path, format!("{part}: channel `{name}` holds {} samples, expected {width}×{height}", data.len())));
            }
            channels.push(ExrChannel { name, data });
            owner.push(part.clone());
        }
    }
    Ok(ExrImage { width, height, channels })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fuzzer regression: a header declaring a huge data window is refused before the decoder allocates it
    /// (it used to abort the process: "memory allocation of 18301720899686472 bytes failed").
    #[test]
    fn huge_declared_data_window_is_an_error_not_an_abort() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.exr");
        write_exr(&p, 4, 3, &[ExrChannel { name: "Y".into(), data: vec![0.5; 12] }]).unwrap();
        let mut bytes = std::fs::read(&p).unwrap();
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        for (k, v) in [(8usize, 99_999_999i32), (12, 99_999_999)] {
            bytes[at + k..at + k + 4].copy_from_slice(&v.to_le_bytes());
        }
        std::fs::write(&p, &bytes).unwrap();
        let e = read_exr(&p).unwrap_err().to_string();
        assert!(e.contains("h.exr") && e.contains("declares"), "{e}");
    }

    /// A non-finite value is refused before the file exists, naming the channel and the pixel.
    #[test]
    fn non_finite_values_are_never_written() {
        let dir = tempfile::tempdir().unwrap();
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let p = dir.path().join("n.exr");
            let mut data = vec![0.25f32; 12];
            data[7] = bad;
            let e = write_exr(&p, 4, 3, &[ExrChannel { name: "Y".into(), data }]).unwrap_err().to_string();
            assert!(e.contains("n.exr") && e.contains("channel Y: pixel 7 (row 1, col 3)") && e.contains("non-finite"), "{e}");
            assert!(!p.exists(), "{bad}: a refused image was written");
        }
    }

    #[test]
    fn round_trip_many_channels_and_truncation() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.exr");
        let (w, h) = (7, 5);
        let chans: Vec<ExrChannel> = (0..12).map(|k| ExrChannel { name: format!("band_{k:02}"), data: (0..w * h).map(|i| (i * 13 + k) as f32 * 0.25).collect() }).collect();
        write_exr(&p, w, h, &chans).unwrap();
        let img = read_exr(&p).unwrap();
        assert_eq!((img.width, img.height), (w, h));
        assert_eq!(img.channels, chans);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() * 2 / 3]).unwrap();
        let e = read_exr(&p).unwrap_err().to_string();
        assert!(e.contains("c.exr") && e.contains("OpenEXR"), "{e}");
        assert!(write_exr(&p, w, h, &[ExrChannel { name: "Y".into(), data: vec![0.0; 3] }]).is_err());
    }
}
