//! The scenes of a study: loaded, fitted to the study's size and digested (a resumed study renders and solves
//! again a scene whose file changed).
use super::settings::StudySettings;
use crate::error::{Error, Result};
use crate::render::settings::parse_wavelengths;
use crate::scene::{load_scene, synthetic_scene, synthetic_wavelengths, Fit, SpectralCube};
use serde_json::{json, Value};

/// A scene of the study: its name and the fitted cube (the truth).
pub(super) struct StudyScene {
    pub(super) name: String,
    pub(super) cube: SpectralCube,
    pub(super) source: Value,
    /// SHA-256 of the fitted cube's values and wavelengths (`scene_sha256` in its render.json and cells): a
    /// resumed study renders and solves again a scene whose file changed (it kept the old results).
    pub(super) digest: String,
}

impl StudyScene {
    fn new(name: String, cube: SpectralCube, source: Value) -> Self {
        let mut bytes: Vec<u8> = cube.wavelengths_nm.iter().flat_map(|w| w.to_le_bytes()).collect();
        bytes.extend(cube.data.iter().flat_map(|v| v.to_le_bytes()));
        let digest = crate::io::sha256::sha256_hex(&bytes);
        StudyScene { name, cube, source, digest }
    }
}

/// The study's scenes, fitted to `--scene-size` (the truths): the files of `--scenes` or `--synthetic` ones.
pub(super) fn load_scenes(a: &StudySettings, bands: &[f64]) -> Result<Vec<StudyScene>> {
    let n = a.scene_size;
    match (&a.scenes, a.synthetic) {
        (Some(dir), None) => {
            let fit = Fit::parse(&a.fit)?;
            let given = a.scene_wavelengths.as_deref().map(|t| parse_wavelengths("--scene-wavelengths", t)).transpose()?;
            let found = crate::render::dataset::find_scenes(dir)?;
            if found.is_empty() {
                return Err(Error::File { path: dir.display().to_string(), message: "no scenes (.png photographs, .exr, .npy, or folders of per-band .png)".into() });
            }
            let nb = bands.len().max(given.as_ref().map_or(31, Vec::len));
            crate::limits::check_memory(&format!("--scene-size {n} × {} scenes of {}", found.len(), dir.display()), found.len() as f64 * crate::limits::bytes_cube(n, n, nb))?;
            found
                .into_iter()
                .map(|s| {
                    // RGB photographs are uplifted at --scene-wavelengths as `render` does (it was ignored for them),
                    // else directly at the render bands; cubes keep their own bands unless --scene-wavelengths.
                    let ws = if crate::scene::natural::is_rgb_image(&s.path) { given.as_deref().or(Some(bands)) } else { given.as_deref() };
                    let raw = load_scene(&s.path, ws)?;
                    let cube = raw.fit(n, fit).map_err(|e| Error::File { path: s.path.display().to_string(), message: e.to_string() })?;
                    // The radiance checks `render` applies (finite, ≥ 0, within the limit): a negative scene was
                    // rendered and scored, one beyond the limit failed after the study's first files (a
                    // held-out battery, round 8).
                    crate::render::settings::check_scene_values(&cube).map_err(|m| Error::File { path: s.path.display().to_string(), message: m })?;
                    // The metrics take the scene's maximum as PSNR's peak: a black scene is refused before any
                    // render, naming it (it failed after its renders and solves with "the truth's maximum is 0").
                    crate::recon::metrics::truth_peak(&cube.data).map_err(|e| Error::File { path: s.path.display().to_string(), message: format!("as a truth at --scene-size {n}: {e}; remove it from the study") })?;
                    // Every cell scores its estimate against this truth at the study's bands: a cube whose bands stop
                    // short of them failed after the renders ("cannot resample the truth"; a held-out battery, round 16).
                    if let crate::scene::AtWavelengths::Outside(w) = cube.at_wavelengths(bands)? {
                        let (lo, hi) = (cube.wavelengths_nm[0], cube.wavelengths_nm[cube.bands() - 1]);
                        return Err(Error::File {
                            path: s.path.display().to_string(),
                            message: format!("its bands ({} – {} nm) do not reach the study's band at {} nm (--bands): every cell scores the estimate against the scene at the study's bands; give --bands within the scene's range, or --scene-wavelengths", crate::limits::fmt_num(lo), crate::limits::fmt_num(hi), crate::limits::fmt_num(w)),
                        });
                    }
                    let source = json!({"source": s.path.display().to_string(), "native_height": raw.height, "native_width": raw.width, "fit": fit});
                    Ok(StudyScene::new(s.name, cube, source))
                })
                .collect()
        }
        (None, Some(k)) => {
            if k == 0 {
                return Err(Error::invalid("--synthetic must be ≥ 1"));
            }
            Ok((0..k).map(|s| StudyScene::new(format!("synthetic{s:02}"), synthetic_scene(n, n, &synthetic_wavelengths(), s as u64), json!({"source": "synthetic", "synthetic_seed": s}))).collect())
        }
        _ => Err(Error::invalid("give --scenes DIR or --synthetic N")),
    }
}

