//! The four reference systems of Paillet et al. as Zemax designed them: SP, AP, mSP, mAP; `gsp`, SP with
//! its prism replaced by a plane transmission grating of the same 450–650 nm dispersion span (below); and the
//! dual-disperser `ddsp`, `mddsp` ([`dual_disperser`]).
//!
//! Each preset is built from its Zemax Lens Data Editor transcription (`data/presets/*.prescription.csv`,
//! copied from `shared/reference/zemax`, embedded in the binary) plus the system data the screenshots do
//! not show (object-space NA 0.05, fields F1..F4, wavelengths 450/520/650 nm, primary 520 nm, ray aiming
//! off). Pickup sources are not visible in the screenshots; those recorded here are the ones the shown
//! values identify (tests check the resolved pickups reproduce every shown value). Other `P` cells keep
//! their shown value.
//!
//! ```
//! let spec = diffcassi::presets::spec("msp").unwrap();
//! assert_eq!(spec.surfaces.len(), 20);
//! ```
pub mod dual_disperser;

pub use dual_disperser::{dd_spec, DD_MASK_PITCH_UM};

use crate::error::{Error, Result};
use crate::spec::zemax_csv::{import_prescription, PickupSource, SystemData};
use crate::spec::SystemSpec;

/// The paper's four presets (the ones with Zemax reference data).
pub const NAMES: [&str; 4] = ["sp", "ap", "msp", "map"];

/// Every preset name: the paper's four, the grating CASSI `gsp` and the dual-disperser `ddsp`, `mddsp`.
pub const ALL_NAMES: [&str; 7] = ["sp", "ap", "msp", "map", "gsp", "ddsp", "mddsp"];

/// `gsp`'s grating: lines per µm (see [`gsp_spec`] for how it was chosen).
pub const GSP_LINES_PER_UM: f64 = GSP_T;
/// `gsp`'s diffraction order.
pub const GSP_ORDER: i32 = GSP_M;

struct Preset {
    name: &'static str,
    title: &'static str,
    csv: &'static str,
    file: &'static str,
    pickups: &'static [(usize, &'static str, usize, f64)],
}

const SP_PICKUPS: &[(usize, &str, usize, f64)] = &[(11, "tilt_y_deg", 7, 1.0), (14, "tilt_x_deg", 4, -1.0), (14, "tilt_z_deg", 4, -1.0)];
const AP_PICKUPS: &[(usize, &str, usize, f64)] = &[(10, "tilt_y_deg", 7, 1.0), (12, "tilt_y_deg", 5, 1.0), (14, "tilt_y_deg", 3, 1.0)];
const MAP_PICKUPS: &[(usize, &str, usize, f64)] = &[(12, "tilt_y_deg", 9, 1.0), (14, "tilt_y_deg", 7, 1.0)];

const PRESETS: [Preset; 4] = [
    Preset {
        name: "sp",
        title: "SP: single N-BK7 60° prism, paraxial objective, AC254-050-A doublet",
        csv: include_str!("../../data/presets/SP_single_prism_aligned.prescription.csv"),
        file: "SP_single_prism_aligned.prescription.csv",
        pickups: SP_PICKUPS,
    },
    Preset {
        name: "ap",
        title: "AP: double-Amici prism (N-SK2 / N-SF10 / N-SK2), paraxial 2f–2f relay",
        csv: include_str!("../../data/presets/AP_amici_prism_aligned.prescription.csv"),
        file: "AP_amici_prism_aligned.prescription.csv",
        pickups: AP_PICKUPS,
    },
    Preset {
        name: "msp",
        title: "mSP: SP with the prism tilted 5° about x",
        csv: include_str!("../../data/presets/mSP_single_prism_misaligned.prescription.csv"),
        file: "mSP_single_prism_misaligned.prescription.csv",
        pickups: SP_PICKUPS,
    },
    Preset {
        name: "map",
        title: "mAP: AP with the prism tilted 5° about x",
        csv: include_str!("../../data/presets/mAP_amici_prism_misaligned.prescription.csv"),
        file: "mAP_amici_prism_misaligned.prescription.csv",
        pickups: MAP_PICKUPS,
    },
];

/// The spec of a preset (`sp`, `ap`, `msp`, `map`, `gsp`; case-insensitive).
pub fn spec(name: &str) -> Result<SystemSpec> {
    let key = name.to_ascii_lowercase();
    match key.as_str() {
        "gsp" => return gsp_spec(),
        "ddsp" => return dual_disperser::dd_spec(false),
        "mddsp" => return dual_disperser::dd_spec(true),
        _ => {}
    }
    let p = PRESETS
        .iter()
        .find(|p| p.name == key)
        .ok_or_else(|| Error::invalid(format!("unknown preset `{name}` (presets: {})", ALL_NAMES.join(", "))))?;
    let mut data = SystemData::paper_defaults();
    data.name = p.name.to_string();
    data.pickups = p.pickups.iter().map(|&(surface, column, from_surface, scale)| PickupSource { surface, column, from_surface, scale }).collect();
    data.keep_unsourced_pickups = true;
    let mut spec = import_prescription(p.csv, p.file, &data)?;
    spec.description = p.title.to_string();
    Ok(spec)
}

/// The Zemax prescription text a preset is built from.
pub fn prescription_csv(name: &str) -> Option<&'static str> {
    PRESETS.iter().find(|p| p.name == name.to_ascii_lowercase()).map(|p| p.csv)
}

const GSP_T: f64 = 0.08301317671403566;
const GSP_M: i32 = 1;

/// `gsp`: SP (surfaces 0–2: object, dummy, the f = 50 mm paraxial collimator; 16–19: the AC254-050-A
/// doublet and the detector) with its prism (SP surfaces 3–15) replaced by a plane transmission grating in
/// air, the stop, its lines parallel to the global y axis so that it disperses along x as SP's prism does
/// (a Coordinate Break turns the grating's local x, along which OpticStudio's lines run, by 90° about z, and
/// the next one turns it back), followed by SP's chief-ray-solved break that aligns the doublet with the
/// primary (520 nm) chief ray, 50 mm before it as in SP.
///
/// **The grating.** At normal incidence (the centre field's collimated beam) order m leaves at
/// sin θ(λ) = mλT (the grating equation, `surfaces::grating`); the doublet, aligned with θ(520 nm), maps
/// an angle to the detector at x(λ) = f·tan(θ(λ) − θ(520)) with f = 50.0 mm, the doublet's nominal focal
/// length (its paraxial EFL at 520 nm is 50.07 mm). T is the root of
/// f·[tan(θ(650) − θ(520)) + tan(θ(520) − θ(450))] = S with S = SP's 450–650 nm span of the centre
/// field's chief ray on its detector (`diffcassi dispersion --preset sp`), computed once and recorded in
/// docs/study.md ("gsp"); the grating plate's substrate (a plane-parallel plate) would only shift the beam,
/// so the grating is modelled in air. The order's efficiency is left at its default 1.
pub fn gsp_spec() -> Result<SystemSpec> {
    use crate::spec::{Cell, Driver, SurfaceSpec};
    let sp = spec("sp")?;
    let mut surfaces: Vec<SurfaceSpec> = sp.surfaces[..3].to_vec();
    let mut turn = SurfaceSpec::coordinate_break(0.0, 0.0, 0.0, 0.0, 90.0, GSP_GRATING_GAP_MM);
    turn.comment = "lines along global y".into();
    surfaces.push(turn);
    let mut grating = SurfaceSpec::grating(None, GSP_T, GSP_M, 0.0, None);
    grating.stop = true;
    grating.comment = "transmission grating".into();
    grating.semi_diameter_mm = Some(12.7);
    surfaces.push(grating);
    surfaces.push(SurfaceSpec::coordinate_break(0.0, 0.0, 0.0, 0.0, -90.0, 0.0));
    let mut solve = sp.surfaces[15].clone();
    for col in ["decenter_x_mm", "decenter_y_mm", "tilt_y_deg"] {
        let c = solve.cell_mut(col).expect("SP's surface 15 solves these");
        *c = Cell { value: 0.0, variable: false, driver: Driver::ChiefRay };
    }
    surfaces.push(solve);
    surfaces.extend_from_slice(&sp.surfaces[16..]);
    let mut s = sp;
    s.name = "gsp".into();
    s.description = "gSP: SP with its prism replaced by a plane transmission grating (same 450–650 nm span), paraxial objective, AC254-050-A doublet".into();
    s.surfaces = surfaces;
    Ok(s)
}

/// Distance from the paraxial collimator to the grating: 53 mm, the axial position of SP's stop (between
/// its prism halves) to the nearest millimetre, so that the pupils of the two systems sit alike.
const GSP_GRATING_GAP_MM: f64 = 3.0;
