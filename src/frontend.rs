//! Which front end calls the library, and how each one spells the library's settings.
//!
//! The library's messages name a setting by its command-line option (`--read-noise-e must be ≥ 0`): the CLI is
//! its reference spelling. A Python caller set the same setting as the keyword `read_noise_e`, a C++ caller as
//! the field `RenderOptions::rays_per_pixel`; each should read the name it wrote. [`SETTINGS`] is the one table
//! of those spellings (the library owns the settings, the front ends only spell them), [`spell`] rewrites a
//! message for a front end, and every [`crate::Error`]'s text is spelled for the process's front end
//! ([`current`]), which the Python module and the C++ library set once at start-up ([`set`]) — as they name the
//! budgets ([`crate::limits::name_budgets`]). An option another front end has no name for (`--scene`, which
//! Python takes as an argument) is left as written.
//!
//! ```
//! use diffcassi::frontend::{spell, Frontend};
//! let m = "--read-noise-e -1: must be ≥ 0; raise --rays or lower --planes";
//! assert_eq!(spell(m, Frontend::Cli), m);
//! assert_eq!(spell(m, Frontend::Python), "read_noise_e -1: must be ≥ 0; raise rays or lower planes");
//! assert_eq!(spell(m, Frontend::Cpp), "--read-noise-e -1: must be ≥ 0; raise RenderOptions::rays_per_pixel or lower RenderOptions::planes");
//! // Only an option standing alone: not one inside a path.
//! assert_eq!(spell("runs/--seed/x.npy: unreadable", Frontend::Python), "runs/--seed/x.npy: unreadable");
//! ```
use std::borrow::Cow;
use std::sync::atomic::{AtomicU8, Ordering};

/// A front end of the library.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Frontend {
    /// The `diffcassi` command line: the messages' own spelling (`--rays`).
    Cli = 0,
    /// The Python package: keywords (`rays`, `read_noise_e`).
    Python = 1,
    /// The C++ API: `RenderOptions` fields and function arguments.
    Cpp = 2,
}

static CURRENT: AtomicU8 = AtomicU8::new(Frontend::Cli as u8);

/// Declare the process's front end (the Python module and the C++ library do, once; the CLI is the default).
pub fn set(frontend: Frontend) {
    CURRENT.store(frontend as u8, Ordering::Relaxed);
}

/// The process's front end ([`set`]; [`Frontend::Cli`] unless a binding declared itself).
pub fn current() -> Frontend {
    match CURRENT.load(Ordering::Relaxed) {
        1 => Frontend::Python,
        2 => Frontend::Cpp,
        _ => Frontend::Cli,
    }
}

/// One setting's spellings: the command-line option (without `--`), the Python keyword, the C++ name (`None`:
/// that front end does not take it, and a message naming it keeps the option).
#[derive(Clone, Copy, Debug)]
pub struct Setting {
    pub cli: &'static str,
    pub python: Option<&'static str>,
    pub cpp: Option<&'static str>,
}

const fn s(cli: &'static str, python: &'static str, cpp: Option<&'static str>) -> Setting {
    Setting { cli, python: Some(python), cpp }
}

/// Every setting a front end spells otherwise than `--option`: `render`'s and its noise's (the Python keywords
/// of `diffcassi.render`/`diffcassi.exact`, `render::settings::RENDER_KEYS`; C++'s `RenderOptions`),
/// `reconstruct`'s, and `study`'s (`diffcassi.study`'s keywords). `--bands` is `render`'s `bands_nm` in Python
/// (`diffcassi.study`, whose keyword is `bands`, respells it; "bands_nm (study: bands)" read awkwardly).
pub const SETTINGS: &[Setting] = &[
    // render and its noise
    s("bands", "bands_nm", Some("the scene's wavelengths_nm")),
    s("planes", "planes", Some("RenderOptions::planes")),
    s("rays", "rays", Some("RenderOptions::rays_per_pixel")),
    s("seed", "seed", Some("RenderOptions::seed")),
    s("sampling", "sampling", None),
    s("opening", "opening", Some("RenderOptions::mask_opening")),
    s("mask-seed", "mask_seed", Some("RenderOptions::mask_seed")),
    s("airy-diameter-px", "airy_diameter_px", Some("RenderOptions::airy_diameter_px")),
    s("airy", "airy", Some("RenderOptions::airy")),
    s("backend", "backend", Some("the backend argument")),
    s("device", "device", None),
    s("precision", "precision", Some("RenderOptions::precision")),
    s("tolerance-um", "tolerance_um", Some("RenderOptions::tolerance_um")),
    s("calibration-cache", "calibration_cache", Some("diffcassi::set_calibration_cache")),
    s("scene-fov-deg", "scene_fov_deg", Some("RenderOptions::scene_fov_deg")),
    s("noise", "noise", None),
    s("full-well-e", "full_well_e", None),
    s("electrons-per-unit", "electrons_per_unit", None),
    s("read-noise-e", "read_noise_e", None),
    s("adc-bits", "adc_bits", None),
    s("noise-seed", "noise_seed", None),
    // reconstruct
    s("solver", "solver", None),
    s("iterations", "iterations", None),
    s("step", "step", None),
    s("tv-weight", "tv_weight", None),
    s("tv-iterations", "tv_iterations", None),
    s("tv-coupling", "tv_coupling", None),
    s("accelerated", "accelerated", None),
    s("admm-eta", "admm_eta", None),
    s("sigma-max", "sigma_max", None),
    s("sigma-min", "sigma_min", None),
    s("tolerance", "tolerance", None),
    s("denoiser", "denoiser", Some("the weights argument")),
    s("tv-warmup", "tv_warmup", None),
    s("discrepancy", "discrepancy", None),
    s("noise-norm", "noise_norm", None),
    s("sigma-auto", "sigma_auto", None),
    s("noise-twin", "noise_twin", None),
    s("noise-factor", "noise_factor", None),
    s("equivariant", "equivariant", None),
    s("equivariant-seed", "equivariant_seed", None),
    // study
    s("presets", "presets", None),
    s("systems", "systems", None),
    s("glass-catalogs", "glass_catalogs", None),
    s("operators", "operators", None),
    s("solvers", "solvers", None),
    s("scenes", "scenes", None),
    s("synthetic", "synthetic", None),
    s("scene-wavelengths", "scene_wavelengths", None),
    s("scene-size", "scene_size", None),
    s("fit", "fit", None),
    s("mask", "mask", None),
    s("transport-memory-gb", "transport_memory_gb", None),
    s("force", "force", None),
    s("noise-estimate", "noise_estimate", None),
    s("plain", "plain", None),
    s("weights", "weights", None),
];

/// How `frontend` names the command-line option `cli` (without `--`); `None`: it keeps the option.
pub fn name(cli: &str, frontend: Frontend) -> Option<&'static str> {
    let row = SETTINGS.iter().find(|r| r.cli == cli)?;
    match frontend {
        Frontend::Cli => None,
        Frontend::Python => row.python,
        Frontend::Cpp => row.cpp,
    }
}

/// `message` with each command-line option that `frontend` names otherwise ([`SETTINGS`]) written as that
/// name, where the option stands alone: after a space, a bracket or a quote, and before a space, punctuation
/// or the end (not in a path such as `runs/--seed/x.npy`, nor a file name `--seed.npy`). The CLI's spelling is
/// the message itself.
pub fn spell(message: &str, frontend: Frontend) -> Cow<'_, str> {
    if frontend == Frontend::Cli || !message.contains("--") {
        return Cow::Borrowed(message);
    }
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find("--") {
        let (before, from) = rest.split_at(at);
        out.push_str(before);
        let name_len = from[2..].find(|c: char| !(c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-')).unwrap_or(from.len() - 2);
        let option = from[2..2 + name_len].trim_end_matches('-');
        let alone_before = out.chars().last().map_or(true, |c| c.is_whitespace() || "([`'\"".contains(c));
        let next = &from[2 + option.len()..];
        let alone_after = match next.chars().next() {
            None => true,
            // A full stop, not a file name's extension (`--seed.npy`).
            Some('.') => next[1..].chars().next().map_or(true, char::is_whitespace),
            Some(c) => c.is_whitespace() || ",;:)]`'\"".contains(c),
        };
        match name(option, frontend) {
            Some(spelled) if alone_before && alone_after && option.starts_with(|c: char| c.is_ascii_lowercase()) => {
                out.push_str(spelled);
                rest = next;
            }
            _ => {
                out.push_str("--");
                rest = &from[2..];
            }
        }
    }
    out.push_str(rest);
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_setting_is_spelled_once_and_python_keywords_are_snake_case() {
        let mut seen = std::collections::HashSet::new();
        for r in SETTINGS {
            assert!(seen.insert(r.cli), "--{} twice", r.cli);
            let py = r.python.unwrap();
            if r.cli != "bands" {
                assert_eq!(py, r.cli.replace('-', "_"), "--{}", r.cli);
            }
        }
    }

    #[test]
    fn options_stand_alone_or_are_left() {
        let py = |m| spell(m, Frontend::Python).into_owned();
        assert_eq!(py("give --bands, e.g. (--seed 3)"), "give bands_nm, e.g. (seed 3)");
        assert_eq!(py("`--rays` at the end --rays"), "`rays` at the end rays");
        assert_eq!(py("--scene x.npy: --scene is an argument"), "--scene x.npy: --scene is an argument");
        assert_eq!(py("a --seed.npy file, --seed. Then"), "a --seed.npy file, seed. Then");
        assert_eq!(py("--rays-per-pixel --raysx --Rays"), "--rays-per-pixel --raysx --Rays");
        assert_eq!(py("trailing --"), "trailing --");
        let cpp = |m| spell(m, Frontend::Cpp).into_owned();
        assert_eq!(cpp("--opening 2: must be in [0, 1]"), "RenderOptions::mask_opening 2: must be in [0, 1]");
        assert_eq!(cpp("--read-noise-e 3"), "--read-noise-e 3");
    }

    #[test]
    fn the_process_front_end_is_the_cli_unless_set() {
        // (Other tests of this process never set it: the library's own messages stay the CLI's.)
        assert_eq!(current(), Frontend::Cli);
        assert_eq!(crate::Error::invalid("--rays 0: must be ≥ 1").to_string(), "--rays 0: must be ≥ 1");
    }
}
