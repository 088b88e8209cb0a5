//! `make-scene`: write a hyperspectral test scene (an RGB photograph uplifted to spectra, the measured
//! ColorChecker chart, or the synthetic scene) as an NPY cube + wavelength list, or a multichannel EXR, with an
//! sRGB preview beside it.
//!
//! ```text
//! diffcassi make-scene --rgb data/scenes/coffee.png --out out/coffee.npy          # + coffee_wavelengths_nm.npy, coffee_rgb.png
//! diffcassi make-scene --colour-checker --size 256 --bands 450:650:28 --out out/chart.exr
//! ```
use super::shared::parse_wavelengths_for;
use crate::error::{Error, Result};
use crate::io::{write_npy_f32, write_npy_f64, OutputSet};
use crate::scene::{colorimetry, natural, save_exr, synthetic_scene, Fit};
use clap::Args;
use std::path::{Path, PathBuf};

/// The files `make-scene --out OUT` writes, as (what, path): OUT, `<stem>_wavelengths_nm.npy` (NPY only; the
/// name [`crate::scene::load_npy`] reads back) and the preview `<stem>_rgb.png`.
fn scene_outputs(out: &Path, npy: bool) -> Vec<(&'static str, PathBuf)> {
    let stem = out.file_stem().unwrap_or_default().to_string_lossy().into_owned();
    let mut v = vec![("--out", out.to_path_buf())];
    if npy {
        v.push(("--out's wavelength list", out.with_file_name(format!("{stem}_wavelengths_nm.npy"))));
    }
    v.push(("--out's preview", out.with_file_name(format!("{stem}_rgb.png"))));
    v
}

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
    let ws = parse_wavelengths_for("--bands", &a.bands)?;
    crate::scene::check_wavelengths(&ws, &format!("--bands `{}`", a.bands))?;
    if a.size == Some(0) {
        return Err(Error::invalid("--size must be ≥ 1"));
    }
    let ext = a.out.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
    if !matches!(ext.as_deref(), Some("npy") | Some("exr")) {
        return Err(Error::File { path: a.out.display().to_string(), message: "--out must end in .npy or .exr".into() });
    }
    // `X_wavelengths_nm.npy` is the wavelength list of the cube `X.npy` beside it: a cube of that name would
    // replace another scene's list (a held-out battery: `X.npy` then read 448 wavelengths for 28 bands).
    if a.out.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.to_ascii_lowercase().ends_with("_wavelengths_nm.npy")) {
        return Err(Error::File { path: a.out.display().to_string(), message: "--out: a name ending in `_wavelengths_nm.npy` is a cube's wavelength list (written beside `NAME.npy`); choose another name".into() });
    }
    // `<stem>_wavelengths_nm.npy` and `<stem>_rgb.png` belong to every cube of that stem: another cube beside
    // --out with the same stem (`x.npy` for `--out x.NPY`) would have its list or preview replaced.
    crate::io::policy::check_companions("--out", &a.out, &["npy", "exr"], &["_wavelengths_nm.npy", "_rgb.png"])?;
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
    // The output policy before any work: every file of the set is a file (replaced if present), never --rgb.
    let outputs = scene_outputs(&a.out, ext.as_deref() == Some("npy"));
    let inputs: Vec<(&str, &std::path::Path)> = a.rgb.iter().map(|p| ("--rgb", p.as_path())).collect();
    for (option, p) in &outputs {
        crate::io::policy::check_out_file(option, p, &inputs)?;
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
    // All or nothing: cube, wavelength list and preview are staged beside their destinations and renamed
    // into place only when all three are written.
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create: {e}") })?;
    }
    let mut set = OutputSet::files();
    match ext.as_deref() {
        Some("exr") => save_exr(&cube, &set.stage(&a.out))?,
        _ => {
            write_npy_f32(set.stage(&a.out), &[cube.height, cube.width, cube.bands()], &cube.data)?;
            write_npy_f64(set.stage(&outputs[1].1), &[cube.bands()], &cube.wavelengths_nm)?;
        }
    }
    let preview = outputs[outputs.len() - 1].1.clone();
    colorimetry::save_srgb_png(&cube, 1.0, &set.stage(&preview))?;
    set.commit()?;
    println!("{what}: {}×{}×{} cube ({:.1}–{:.1} nm) → {}, preview {}", cube.height, cube.width, cube.bands(), ws[0], ws[ws.len() - 1], a.out.display(), preview.display());
    Ok(())
}
