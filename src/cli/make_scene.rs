//! `make-scene`: write a hyperspectral test scene (an RGB photograph uplifted to spectra, the measured
//! ColorChecker chart, or the synthetic scene) as an NPY cube + wavelength list, or a multichannel EXR, with an
//! sRGB preview beside it.
//!
//! ```text
//! diffcassi make-scene --rgb data/scenes/coffee.png --out out/coffee.npy          # + coffee_wavelengths_nm.npy, coffee_rgb.png
//! diffcassi make-scene --colour-checker --size 256 --bands 450:650:28 --out out/chart.exr
//! ```
use super::shared::parse_wavelengths;
use crate::error::{Error, Result};
use crate::scene::{colorimetry, natural, save_exr, save_npy, synthetic_scene, Fit};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct MakeSceneArgs {
    /// An RGB PNG photograph, uplifted to reflectance spectra (Smits 1999).
    #[arg(long, conflicts_with_all = ["colour_checker", "synthetic"])]
    pub rgb: Option<PathBuf>,
    /// The 24-patch ColorChecker with its measured reflectances (Ohta 1997).
    #[arg(long = "colour-checker", alias = "color-checker", conflicts_with = "synthetic")]
    pub colour_checker: bool,
    /// The synthetic scene of this seed.
    #[arg(long)]
    pub synthetic: Option<u64>,
    /// Side N of the square scene (pixels). An RGB photograph is area-resized to N (shorter side) and centre-cropped;
    /// without --size it keeps its own size. Default 256 for the chart and the synthetic scene.
    #[arg(long)]
    pub size: Option<usize>,
    /// Band wavelengths (nm): list or first:last:count.
    #[arg(long, default_value = "450:650:28")]
    pub bands: String,
    /// Output: .npy (with <stem>_wavelengths_nm.npy) or .exr (one channel per band). An sRGB preview
    /// <stem>_rgb.png is written beside it.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn make_scene(a: MakeSceneArgs) -> Result<()> {
    let ws = parse_wavelengths(&a.bands)?;
    if a.size == Some(0) {
        return Err(Error::invalid("--size must be ≥ 1"));
    }
    let ext = a.out.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    if !matches!(ext.as_deref(), Some("npy") | Some("exr")) {
        return Err(Error::File { path: a.out.display().to_string(), message: "--out must end in .npy or .exr".into() });
    }
    // Limits before any allocation: the method's wavelength range (no silent extrapolation) and the memory
    // of the cube (an RGB photograph's own size is checked from its PNG header before decoding).
    let range = if a.rgb.is_some() {
        Some(("the Smits RGB → spectrum uplift (--rgb)", natural::SMITS_RANGE_NM))
    } else if a.colour_checker {
        Some(("the measured ColorChecker reflectances (--colour-checker)", natural::COLORCHECKER_RANGE_NM))
    } else {
        None
    };
    if let Some((method, r)) = range {
        natural::check_uplift_range(method, r, &ws).map_err(|e| Error::invalid(format!("--bands `{}`: {e}", a.bands)))?;
    }
    if let Some(n) = a.size.or((a.rgb.is_none()).then_some(256)) {
        crate::limits::check_memory(&format!("--size {n} (× {} bands)", ws.len()), crate::limits::bytes_cube(n, n, ws.len()))?;
    }
    let (cube, what) = match (&a.rgb, a.colour_checker, a.synthetic) {
        (Some(p), _, _) => {
            let c = natural::load_rgb_scene(p, Some(&ws))?;
            let c = match a.size {
                Some(n) => c.fit(n, Fit::Resize).map_err(|e| Error::File { path: p.display().to_string(), message: e.to_string() })?,
                None => c,
            };
            (c, format!("{} (Smits RGB → spectrum)", p.display()))
        }
        (None, true, _) => (natural::colour_checker_scene(a.size.unwrap_or(256), &ws), "ColorChecker (Ohta 1997 reflectances)".to_string()),
        (None, false, Some(s)) => {
            let n = a.size.unwrap_or(256);
            (synthetic_scene(n, n, &ws, s), format!("synthetic scene, seed {s}"))
        }
        (None, false, None) => return Err(Error::invalid("give one of --rgb FILE.png, --colour-checker, --synthetic SEED")),
    };
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create: {e}") })?;
    }
    match ext.as_deref() {
        Some("exr") => save_exr(&cube, &a.out)?,
        _ => save_npy(&cube, &a.out)?,
    }
    let stem = a.out.file_stem().unwrap_or_default().to_string_lossy().into_owned();
    let preview = a.out.with_file_name(format!("{stem}_rgb.png"));
    colorimetry::save_srgb_png(&cube, 1.0, &preview)?;
    println!("{what}: {}×{}×{} cube ({:.1}–{:.1} nm) → {}, preview {}", cube.height, cube.width, cube.bands(), ws[0], ws[ws.len() - 1], a.out.display(), preview.display());
    Ok(())
}
