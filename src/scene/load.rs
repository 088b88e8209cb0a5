//! Scene loaders: KAIST-style multichannel EXR, CAVE-style folders of per-band 16-bit PNGs, and NPY cubes
//! with a wavelength list. Every failure names the file and what is wrong with it.
//!
//! Wavelengths come from, in order: the caller's explicit list; the channel / file names (the number that
//! carries the unit `nm`, 100–20 000 nm, e.g. `w450nm`, `band_03_472.2nm`; in a name with no `nm` number,
//! the last number within 200–3000); for PNG folders a
//! `wavelengths.txt` / `wavelengths_nm.txt` file, or CAVE's convention (31 files = 400–700 nm by 10 nm); for
//! NPY cubes a companion `<stem>_wavelengths_nm.npy`.
use super::SpectralCube;
use crate::error::{Error, Result};
use crate::io::exr::{read_exr, write_exr, ExrChannel};
use crate::io::png16::{read_png_gray, write_png_gray16};
use crate::io::{read_npy_f32, read_npy_f64, write_npy_f32, write_npy_f64};
use std::path::{Path, PathBuf};

fn file_err(path: &Path, message: impl Into<String>) -> Error {
    Error::File { path: path.display().to_string(), message: message.into() }
}

/// The numbers in a name, each with whether the unit `nm` follows it (directly or after one space,
/// any case): `band_200_3500nm` → `[(200, false), (3500, true)]`.
fn numbers_in_name(name: &str) -> Vec<(f64, bool)> {
    let mut out = Vec::new();
    let bytes = name.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit() {
            let s = i;
            while i < bytes.len() && (bytes[i].is_ascii_digit() || bytes[i] == b'.') {
                i += 1;
            }
            let text = name[s..i].trim_end_matches('.');
            let rest = name[i..].strip_prefix(' ').unwrap_or(&name[i..]);
            let nm = rest.len() >= 2 && rest.as_bytes()[..2].eq_ignore_ascii_case(b"nm");
            if let Ok(v) = text.parse::<f64>() {
                out.push((v, nm));
            }
        } else {
            i += 1;
        }
    }
    out
}

/// The wavelength (nm) a channel or file name carries. The number that carries the unit `nm` (the last one,
/// e.g. `w450nm`, `band_03_472.2nm`, `band_200_3500nm`) is the wavelength, read as written (bit for bit
/// what [`band_channel_name`] wrote), and must lie in the wavelength window the program accepts
/// ([`crate::limits::WAVELENGTH_RANGE_NM`], 100–20 000 nm); outside it the name carries **no** wavelength
/// (an error for the caller), never another number in the name. Only a name with no `nm` number falls back
/// to its last number within 200–3000 (`450.png`, CAVE-style names). The band index written before the
/// wavelength (`band_200_…` for 201+ bands) was once read as 200 nm (a held-out battery, round 17).
pub fn wavelength_from_name(name: &str) -> Option<f64> {
    let numbers = numbers_in_name(name);
    if let Some(&(v, _)) = numbers.iter().rev().find(|n| n.1) {
        let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
        return (lo..=hi).contains(&v).then_some(v);
    }
    numbers.iter().rev().map(|n| n.0).find(|v| (200.0..=3000.0).contains(v))
}

/// Why `name` carries no wavelength, for messages.
fn no_wavelength_reason(name: &str) -> String {
    let (lo, hi) = crate::limits::WAVELENGTH_RANGE_NM;
    match numbers_in_name(name).iter().rev().find(|n| n.1) {
        Some((v, _)) => format!("`{name}` names {v} nm, outside the {lo}–{hi} nm the program accepts"),
        None => format!("`{name}` carries no wavelength in its name (a number followed by `nm`, {lo}–{hi} nm, or a bare number in 200–3000)"),
    }
}

/// That a scene path leads somewhere: `metadata` follows links, so a missing file is "no such file or folder"
/// and anything else (a symbolic-link loop, a permission) is said as the system says it (`exists()` called a
/// link loop "no such file"; a held-out battery, round 17).
pub fn check_present(path: &Path) -> Result<()> {
    match std::fs::metadata(path) {
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(file_err(path, "no such file or folder")),
        Err(e) => Err(file_err(path, format!("cannot read: {e}"))),
    }
}

/// Load a scene from a `.exr` file, a `.npy` file, a folder of PNGs, or one RGB `.png` photograph (uplifted to
/// reflectance spectra, [`super::natural`]). `wavelengths_nm` overrides the wavelengths found in the files (its
/// length must match the number of bands); for an RGB photograph it gives the wavelengths to evaluate (default
/// 28 bands 450–650 nm).
pub fn load_scene(path: &Path, wavelengths_nm: Option<&[f64]>) -> Result<SpectralCube> {
    if path.is_dir() {
        // A command's output folder is no PNG stack (its acquisition.png would be read as a band).
        for (marker, what) in [("render.json", "a render folder"), ("reconstruct.json", "a reconstruction folder (its cube is cube.npy)"), ("dataset.json", "a render-dataset output"), ("study.json", "a study output")] {
            if path.join(marker).is_file() {
                return Err(file_err(path, &format!("{what}, not a scene: give a scene file (.npy, .exr, an RGB .png) or a folder of per-band PNGs")));
            }
        }
        return load_png_stack(path, wavelengths_nm);
    }
    check_present(path)?;
    match path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref() {
        Some("exr") => load_exr(path, wavelengths_nm),
        Some("npy") => load_npy(path, wavelengths_nm),
        Some("png") => super::natural::load_rgb_scene(path, wavelengths_nm),
        _ => Err(file_err(path, "unknown scene format: give a .exr file, a .npy cube (H, W, B), an RGB .png photograph (uplifted to spectra) or a folder of per-band PNGs")),
    }
}

fn check_override(path: &Path, given: Option<&[f64]>, bands: usize) -> Result<Option<Vec<f64>>> {
    match given {
        None => Ok(None),
        Some(w) if w.len() == bands => Ok(Some(w.to_vec())),
        Some(w) => Err(file_err(path, format!("{} wavelengths given for {bands} bands", w.len()))),
    }
}

/// Assemble a cube from per-band planes (each `h × w`), sorted by wavelength.
fn from_planes(path: &Path, h: usize, w: usize, mut bands: Vec<(f64, Vec<f32>)>) -> Result<SpectralCube> {
    // Checked before sorting, so that the index is the band's in the file's order (a NaN sorted last was
    // reported at another index).
    super::check_wavelengths(&bands.iter().map(|b| b.0).collect::<Vec<_>>(), &path.display().to_string()).or_else(|e| {
        // Only a bad value is reported here; the order is the sort's business.
        if bands.iter().any(|b| !(b.0.is_finite() && b.0 > 0.0)) {
            Err(e)
        } else {
            Ok(())
        }
    })?;
    bands.sort_by(|a, b| a.0.total_cmp(&b.0));
    let nb = bands.len();
    let mut data = vec![0.0f32; h * w * nb];
    for (k, (_, plane)) in bands.iter().enumerate() {
        for (q, v) in plane.iter().enumerate() {
            data[q * nb + k] = *v;
        }
    }
    SpectralCube::new(h, w, bands.iter().map(|b| b.0).collect(), data, &path.display().to_string())
}

/// KAIST-style multichannel EXR: one channel per band, named with its wavelength.
pub fn load_exr(path: &Path, wavelengths_nm: Option<&[f64]>) -> Result<SpectralCube> {
    let img = read_exr(path)?;
    let names: Vec<String> = img.channels.iter().map(|c| c.name.clone()).collect();
    let ws = match check_override(path, wavelengths_nm, names.len())? {
        Some(w) => w,
        None => names
            .iter()
            .map(|n| wavelength_from_name(n).ok_or_else(|| file_err(path, format!("channel {}; give the wavelengths explicitly (--scene-wavelengths)", no_wavelength_reason(n)))))
            .collect::<Result<_>>()?,
    };
    let bands = ws.into_iter().zip(img.channels.into_iter().map(|c| c.data)).collect();
    from_planes(path, img.height, img.width, bands)
}

/// CAVE-style folder: one greyscale PNG (8 or 16 bit) per band, values scaled to [0, 1].
pub fn load_png_stack(dir: &Path, wavelengths_nm: Option<&[f64]>) -> Result<SpectralCube> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| file_err(dir, format!("cannot list: {e}")))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().and_then(|e| e.to_str()).map(|e| e.eq_ignore_ascii_case("png")).unwrap_or(false))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(file_err(dir, "no .png files in this folder"));
    }
    let stems: Vec<String> = files.iter().map(|f| f.file_stem().unwrap_or_default().to_string_lossy().into_owned()).collect();
    let ws: Vec<f64> = if let Some(w) = check_override(dir, wavelengths_nm, files.len())? {
        w
    } else if let Some(list) = ["wavelengths.txt", "wavelengths_nm.txt"].iter().map(|n| dir.join(n)).find(|p| p.exists()) {
        let text = crate::io::input::read_input_text(&list, crate::limits::MAX_TEXT_FILE_BYTES)?;
        let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
        let w: Vec<f64> = text
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .enumerate()
            .map(|(k, s)| match s.parse::<f64>() {
                // `1e400` parses to inf: name the text, and the value's place in the file.
                Ok(v) if !v.is_finite() => Err(file_err(&list, format!("wavelength {k} (`{s}`) is not a finite number"))),
                Ok(v) => Ok(v),
                Err(_) => Err(file_err(&list, format!("wavelength {k}: `{s}` is not a number"))),
            })
            .collect::<Result<_>>()?;
        if w.len() != files.len() {
            return Err(file_err(&list, format!("{} wavelengths for {} PNG files", w.len(), files.len())));
        }
        w
    } else if let Some(w) = stems.iter().map(|s| wavelength_from_name(s)).collect::<Option<Vec<f64>>>() {
        w
    } else if let Some(s) = stems.iter().find(|s| wavelength_from_name(s).is_none() && numbers_in_name(s).iter().any(|n| n.1)) {
        // A name that says `nm` but lies outside the window is an error, never CAVE's 400–700 nm.
        return Err(file_err(dir, format!("file {}", no_wavelength_reason(s))));
    } else if files.len() == 31 {
        (0..31).map(|k| 400.0 + 10.0 * k as f64).collect() // CAVE: 400–700 nm in 10 nm steps
    } else {
        return Err(file_err(dir, format!("{} PNG files and no wavelengths: name them with their wavelength, add wavelengths.txt, or give --scene-wavelengths", files.len())));
    };
    let mut bands = Vec::with_capacity(files.len());
    let mut size = None;
    for (f, w) in files.iter().zip(ws) {
        let g = read_png_gray(f)?;
        match size {
            None => size = Some((g.width, g.height)),
            Some(s) if s != (g.width, g.height) => {
                return Err(file_err(f, format!("is {}×{} but the first band ({}) is {}×{}", g.width, g.height, files[0].display(), s.0, s.1)));
            }
            _ => {}
        }
        bands.push((w, g.values));
    }
    let (w, h) = size.expect("at least one file");
    from_planes(dir, h, w, bands)
}

/// NPY cube of shape (H, W, B) (f32, f64, u8 or u16), wavelengths from `<stem>_wavelengths_nm.npy`.
pub fn load_npy(path: &Path, wavelengths_nm: Option<&[f64]>) -> Result<SpectralCube> {
    // A value beyond float32 or a cube beyond the memory budget is a value error (as a NaN in the cube is),
    // not an unreadable file.
    let (shape, data) = read_npy_f32(path).map_err(|e| match e {
        crate::io::IoError::NpyContent { .. } => Error::invalid(e.to_string()),
        e => e.into(),
    })?;
    if shape.len() != 3 {
        return Err(file_err(path, format!("a scene cube must have shape (H, W, B), found {shape:?}")));
    }
    let ws = match check_override(path, wavelengths_nm, shape[2])? {
        Some(w) => w,
        None => {
            let stem = path.file_stem().unwrap_or_default().to_string_lossy();
            let wl = path.with_file_name(format!("{stem}_wavelengths_nm.npy"));
            if !wl.exists() {
                return Err(file_err(path, format!("no wavelength list: expected {} beside it, or give the wavelengths explicitly (--scene-wavelengths)", wl.display())));
            }
            let (ws_shape, ws) = read_npy_f64(&wl)?;
            if ws_shape.len() != 1 {
                return Err(file_err(&wl, format!("a wavelength list must be 1-D (shape (B,)), found shape {ws_shape:?}")));
            }
            if ws.len() != shape[2] {
                return Err(file_err(&wl, format!("{} wavelengths (shape {ws_shape:?}) for a cube with {} bands", ws.len(), shape[2])));
            }
            ws
        }
    };
    SpectralCube::new(shape[0], shape[1], ws, data, &path.display().to_string())
}

/// Zero-padded channel name of band `k` (sorts in band order): `band_03_472.2222222222222nm`. The wavelength
/// is written in its shortest round-trip form, so a cube read back from its EXR has the same wavelengths, bit
/// for bit (two decimals made it another cube, "resampled" by `evaluate`; a held-out battery, round 7).
pub fn band_channel_name(k: usize, count: usize, wavelength_nm: f64) -> String {
    let digits = count.saturating_sub(1).to_string().len().max(2);
    format!("band_{k:0digits$}_{wavelength_nm}nm")
}

/// Write a cube as a multichannel EXR (one channel per band, [`band_channel_name`]).
pub fn save_exr(cube: &SpectralCube, path: &Path) -> Result<()> {
    let b = cube.bands();
    let channels: Vec<ExrChannel> = (0..b)
        .map(|k| ExrChannel { name: band_channel_name(k, b, cube.wavelengths_nm[k]), data: (0..cube.height * cube.width).map(|q| cube.data[q * b + k]).collect() })
        .collect();
    Ok(write_exr(path, cube.width, cube.height, &channels)?)
}

/// Write a cube as an (H, W, B) f32 NPY plus `<stem>_wavelengths_nm.npy`.
pub fn save_npy(cube: &SpectralCube, path: &Path) -> Result<()> {
    write_npy_f32(path, &[cube.height, cube.width, cube.bands()], &cube.data)?;
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    write_npy_f64(path.with_file_name(format!("{stem}_wavelengths_nm.npy")), &[cube.bands()], &cube.wavelengths_nm)?;
    Ok(())
}

/// Write a cube as a folder of 16-bit PNGs named `band_NN_<λ>nm.png` (values clamped to [0, 1]).
pub fn save_png_stack(cube: &SpectralCube, dir: &Path) -> Result<()> {
    let b = cube.bands();
    for k in 0..b {
        let v: Vec<u16> = (0..cube.height * cube.width).map(|q| (cube.data[q * b + k].clamp(0.0, 1.0) * 65535.0).round() as u16).collect();
        write_png_gray16(dir.join(format!("{}.png", band_channel_name(k, b, cube.wavelengths_nm[k]))), cube.width, cube.height, &v)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn an_exr_cube_keeps_its_wavelengths_bit_for_bit() {
        let ws = crate::analysis::linspace(450.0, 650.0, 28);
        let cube = SpectralCube::new(2, 3, ws.clone(), (0..2 * 3 * 28).map(|v| v as f32).collect(), "t").unwrap();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.exr");
        save_exr(&cube, &p).unwrap();
        let back = load_exr(&p, None).unwrap();
        assert_eq!(back.wavelengths_nm.iter().map(|w| w.to_bits()).collect::<Vec<_>>(), ws.iter().map(|w| w.to_bits()).collect::<Vec<_>>());
        assert_eq!(back.data, cube.data);
    }

    #[test]
    fn names_carry_wavelengths() {
        assert_eq!(wavelength_from_name("w450nm"), Some(450.0));
        assert_eq!(wavelength_from_name("band_03_472.22nm"), Some(472.22));
        assert_eq!(wavelength_from_name("balloons_ms_01"), None);
        assert_eq!(wavelength_from_name("R"), None);
        assert_eq!(band_channel_name(3, 28, 472.2222), "band_03_472.2222nm");
        assert_eq!(band_channel_name(3, 112, 450.0), "band_003_450nm");
    }
}
