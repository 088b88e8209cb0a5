//! Writing a [`SystemSpec`] as a `.zmx` file (ASCII, as older OpticStudio versions and rayoptics read it).
//!
//! Every number is written with Rust's shortest round-trip formatting (`{:?}`), so it reads back
//! bit-identical. Zemax stores curvatures and µm where diffcassi stores radii and nm: the curvature `c`
//! (and the wavelength in µm) written is one for which the importer's `1/c` (`1000·λ`) gives back the
//! spec's radius (nm) exactly — a neighbour of the correctly rounded value when that one does not
//! round-trip. What Zemax has no record for is written as diffcassi records (`DCPK` pickups, `DCCR`
//! chief-ray solves, `DCVR` variables, `DCAI` air index, `DCWP` wavelength policy, `DCGC` catalogue
//! paths), which rayoptics skips.
use super::surfaces::type_name;
use crate::error::{Error, Result};
use crate::spec::{Driver, SurfaceKind, SystemAperture, SystemSpec};
use crate::surfaces::Aperture;
use crate::materials::WavelengthPolicy;
use std::fmt::Write as _;

/// A float as written: shortest round-trip digits, `INFINITY` for +∞.
fn f(v: f64) -> String {
    if v == f64::INFINITY {
        "INFINITY".into()
    } else if v == f64::NEG_INFINITY {
        "-INFINITY".into()
    } else {
        format!("{v:?}")
    }
}

/// The float `x` near `guess` (within 64 ulps) with `back(x) == target`, else `guess`.
pub(crate) fn preimage(target: f64, guess: f64, back: impl Fn(f64) -> f64) -> f64 {
    if back(guess) == target {
        return guess;
    }
    // Neighbours in magnitude, k ulps away (bit patterns ± k; `next_up` needs Rust 1.86, above the MSRV).
    let bits = guess.to_bits();
    for k in 1..=64u64 {
        for x in [f64::from_bits(bits.wrapping_add(k)), f64::from_bits(bits.wrapping_sub(k))] {
            if x.is_finite() && back(x) == target {
                return x;
            }
        }
    }
    guess
}

/// The `.zmx` text of a spec. Errors name what cannot be written (a primary wavelength that is not one of
/// the system wavelengths).
pub fn to_zmx(spec: &SystemSpec) -> Result<String> {
    let fail = |m: String| Error::invalid(format!("cannot write `{}` as .zmx: {m}", spec.name));
    let primary = spec
        .wavelengths_nm
        .iter()
        .position(|w| *w == spec.primary_wavelength_nm)
        .ok_or_else(|| fail(format!("primary wavelength {} nm is not one of the system wavelengths {:?}", spec.primary_wavelength_nm, spec.wavelengths_nm)))?;
    if spec.mechanics.is_some() {
        return Err(fail("the [mechanics] section (mounts and meshes) has no sequential .zmx equivalent: export as .toml or .json".into()));
    }
    // A `.zmx` pickup names its source; written as a plain value it would lose the mark that keeps a fit
    // from freeing its source (and OpticStudio would not follow it either).
    let unknown = spec.unknown_pickups();
    if !unknown.is_empty() {
        return Err(fail(format!("pickups of unknown source ({}) cannot be written as .zmx pickups: give their sources in a .toml/.json spec first, or export as .toml or .json", unknown.join(", "))));
    }
    if let Some((i, _)) = spec.surfaces.iter().enumerate().find(|(_, s)| s.coating.is_some()) {
        return Err(fail(format!("surface {i} has a coating, which the .zmx export cannot write (it would be dropped): export as .toml or .json")));
    }
    if spec.name.contains(['\n', '\r']) || spec.description.contains(['\n', '\r']) {
        return Err(fail("the name or description spans several lines (a .zmx NAME/NOTE is one line)".into()));
    }
    let mut o = String::new();
    let w = &mut o;
    let _ = writeln!(w, "MODE SEQ");
    let _ = writeln!(w, "NAME {}", spec.name);
    if !spec.description.is_empty() {
        let _ = writeln!(w, "NOTE 0 {}", spec.description);
    }
    let _ = writeln!(w, "UNIT MM X W X CM MR CPMM");
    match spec.aperture {
        SystemAperture::EntrancePupilDiameter(d) => writeln!(w, "ENPD {}", f(d)),
        SystemAperture::ObjectSpaceNa(na) => writeln!(w, "OBNA {} 0", f(na)),
        SystemAperture::ImageSpaceFNumber(fno) => writeln!(w, "FNUM {} 0", f(fno)),
        SystemAperture::FloatByStopSize => writeln!(w, "FLOA"),
    }
    .ok();
    let _ = writeln!(w, "ENVD 20 1 0");
    // In OpticStudio's search order (the first catalogue holding a glass wins): the spec's catalogues last
    // first (in a spec a later one wins), then SCHOTT, which the built-in subset stands for (below them all).
    let mut gcat: Vec<String> = Vec::new();
    for p in spec.glass_catalogs.iter().rev().chain(std::iter::once(&"builtin:SCHOTT".to_string())) {
        // `builtin:OHARA` (a built-in catalogue) is OHARA in OpticStudio's list; a file is its stem.
        let stem = match crate::materials::builtin_catalogs::entry_name(p) {
            Some(n) => n.to_ascii_uppercase(),
            None => std::path::Path::new(p).file_stem().and_then(|s| s.to_str()).unwrap_or("").to_ascii_uppercase(),
        };
        if !stem.is_empty() && !gcat.contains(&stem) {
            gcat.push(stem);
        }
    }
    let _ = writeln!(w, "GCAT {}", gcat.join(" "));
    for p in &spec.glass_catalogs {
        let _ = writeln!(w, "DCGC {p}");
    }
    if spec.air_index != 1.0 {
        let _ = writeln!(w, "DCAI {}", f(spec.air_index));
    }
    if spec.wavelength_policy == WavelengthPolicy::AllowExtrapolation {
        let _ = writeln!(w, "DCWP allow_extrapolation");
    }
    let aim = match spec.ray_aiming {
        crate::spec::RayAiming::Off => 0,
        crate::spec::RayAiming::Paraxial => 1,
        crate::spec::RayAiming::Real => 2,
    };
    let _ = writeln!(w, "RAIM 0 {aim} 1 1 0 0 0 0 0");
    // Field values: degrees for angles (FTYP 0), mm for heights (FTYP 1–3).
    let fields = spec.field_values();
    let nf = fields.len();
    let _ = writeln!(w, "FTYP {} 0 {nf} {} 0 0 0", spec.field_type.zmx_code(), spec.wavelengths_nm.len());
    let row = |vals: Vec<String>| vals.join(" ");
    let _ = writeln!(w, "XFLN {}", row(fields.iter().map(|p| f(p[0])).collect()));
    let _ = writeln!(w, "YFLN {}", row(fields.iter().map(|p| f(p[1])).collect()));
    let _ = writeln!(w, "FWGN {}", row(vec!["1".into(); nf]));
    // Vignetting factors (one column of `vignetting_factors` per record; zeros when there are none), VAN 0.
    for (c, k) in ["VDXN", "VDYN", "VCXN", "VCYN"].iter().enumerate() {
        let _ = writeln!(w, "{k} {}", row((0..nf).map(|i| spec.vignetting_factors.get(i).map_or_else(|| "0".into(), |v| f(v[c]))).collect()));
    }
    let _ = writeln!(w, "VANN {}", row(vec!["0".into(); nf]));
    for (i, nm) in spec.wavelengths_nm.iter().enumerate() {
        let um = preimage(*nm, nm / 1000.0, |u| u * 1000.0);
        let _ = writeln!(w, "WAVM {} {} 1", i + 1, f(um));
    }
    let _ = writeln!(w, "PWAV {}", primary + 1);
    for (i, s) in spec.surfaces.iter().enumerate() {
        let _ = writeln!(w, "SURF {i}");
        let _ = writeln!(w, "  TYPE {}", type_name(s.kind));
        if s.stop {
            let _ = writeln!(w, "  STOP");
        }
        // A coded-mask surface has no OpticStudio equivalent: it is written as the plain surface it is (a flat
        // Standard in air), its mask said in the comment's tag (OpticStudio reads a plain surface; diffcassi's
        // importer reads the tag back, src/spec/zmx/surfaces.rs).
        let comment = match &s.coded_mask {
            Some(m) => m.tagged_comment(&s.comment),
            None => s.comment.clone(),
        };
        if !comment.is_empty() {
            if comment.contains(['\n', '\r']) {
                return Err(fail(format!("surface {i} comment spans several lines")));
            }
            let _ = writeln!(w, "  COMM {}", comment);
        }
        let c = match &s.radius_mm {
            Some(r) => preimage(r.value, 1.0 / r.value, |c| 1.0 / c),
            None => 0.0,
        };
        let _ = writeln!(w, "  CURV {} 0 0 0 0 \"\"", f(c));
        let _ = writeln!(w, "  DISZ {}", f(s.thickness_mm.value));
        if let Some(m) = &s.material {
            if m.chars().any(char::is_whitespace) || m.is_empty() {
                return Err(fail(format!("surface {i} material `{m}`: a .zmx glass name has no spaces")));
            }
            let _ = writeln!(w, "  GLAS {m} 0 0 0 0 0 0 0 0 0 0");
        }
        if let Some(k) = &s.conic {
            let _ = writeln!(w, "  CONI {}", f(k.value));
        }
        match s.kind {
            SurfaceKind::EvenAsphere => {
                for (k, a) in s.asphere_coefficients.iter().enumerate() {
                    let _ = writeln!(w, "  PARM {} {}", k + 1, f(a.value));
                }
            }
            SurfaceKind::Paraxial => {
                if let Some(fl) = &s.focal_length_mm {
                    let _ = writeln!(w, "  PARM 1 {}", f(fl.value));
                }
            }
            SurfaceKind::CoordinateBreak => {
                for (k, col) in ["decenter_x_mm", "decenter_y_mm", "tilt_x_deg", "tilt_y_deg", "tilt_z_deg"].iter().enumerate() {
                    if let Some(cell) = s.cell(col) {
                        let _ = writeln!(w, "  PARM {} {}", k + 1, f(cell.value));
                    }
                }
                let _ = writeln!(w, "  PARM 6 {}", s.order);
            }
            SurfaceKind::Toroidal => {
                // PARM 1: radius of rotation (0 = infinite), 2…9: y² … y¹⁶ terms; no Zernike terms.
                let _ = writeln!(w, "  PARM 1 {}", f(s.rotation_radius_mm.as_ref().map(|c| c.value).unwrap_or(0.0)));
                for (k, a) in s.asphere_coefficients.iter().enumerate() {
                    let _ = writeln!(w, "  PARM {} {}", k + 2, f(a.value));
                }
                let _ = writeln!(w, "  XDAT 1 0");
            }
            SurfaceKind::DiffractionGrating => {
                for (k, col) in ["grating_lines_per_um", "grating_order"].iter().enumerate() {
                    if let Some(cell) = s.cell(col) {
                        let _ = writeln!(w, "  PARM {} {}", k + 1, f(cell.value));
                    }
                }
                if let Some(e) = s.grating_efficiency {
                    let _ = writeln!(w, "  DCGE {}", f(e));
                }
            }
            SurfaceKind::Standard => {}
        }
        if let Some(sd) = s.semi_diameter_mm {
            let _ = writeln!(w, "  DIAM {} 1 0 0 1 \"\"", f(sd));
        }
        match &s.aperture {
            None | Some(Aperture::None) => {}
            Some(Aperture::Circular { semi_diameter_mm, min_radius_mm, decenter_x_mm, decenter_y_mm }) => {
                let _ = writeln!(w, "  CLAP {} {} 0", f(*min_radius_mm), f(*semi_diameter_mm));
                let _ = writeln!(w, "  OBDC {} {}", f(*decenter_x_mm), f(*decenter_y_mm));
            }
            Some(Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm }) => {
                let _ = writeln!(w, "  SQAP {} {} 0", f(*half_width_x_mm), f(*half_width_y_mm));
                let _ = writeln!(w, "  OBDC {} {}", f(*decenter_x_mm), f(*decenter_y_mm));
            }
            Some(Aperture::CircularObscuration { min_radius_mm, max_radius_mm, decenter_x_mm, decenter_y_mm }) => {
                let _ = writeln!(w, "  OBSC {} {} 0", f(*min_radius_mm), f(*max_radius_mm));
                let _ = writeln!(w, "  OBDC {} {}", f(*decenter_x_mm), f(*decenter_y_mm));
            }
        }
        for col in s.present_columns() {
            let cell = s.cell(&col).expect("present column");
            if cell.variable {
                let _ = writeln!(w, "  DCVR {col}");
            }
            match &cell.driver {
                // (A pickup of unknown source was refused above.)
                Driver::Fixed | Driver::UnknownPickup => {}
                Driver::ChiefRay => {
                    let _ = writeln!(w, "  DCCR {col}");
                }
                Driver::Pickup(p) => {
                    let src = p.column.as_deref().map(|c| format!(" {c}")).unwrap_or_default();
                    let _ = writeln!(w, "  DCPK {col} {} {} {}{src}", p.surface, f(p.scale), f(p.offset));
                }
            }
        }
    }
    let _ = writeln!(w, "TOL TOFF 0 0 0 0 0 0 0 0");
    let _ = writeln!(w, "MNUM 1 1");
    Ok(o)
}
