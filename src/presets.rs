//! The four reference systems of Paillet et al. as Zemax designed them: SP, AP, mSP, mAP.
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
use crate::error::{Error, Result};
use crate::spec::zemax_csv::{import_prescription, PickupSource, SystemData};
use crate::spec::SystemSpec;

/// The preset names.
pub const NAMES: [&str; 4] = ["sp", "ap", "msp", "map"];

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
        csv: include_str!("../data/presets/SP_single_prism_aligned.prescription.csv"),
        file: "SP_single_prism_aligned.prescription.csv",
        pickups: SP_PICKUPS,
    },
    Preset {
        name: "ap",
        title: "AP: double-Amici prism (N-SK2 / N-SF10 / N-SK2), paraxial 2f–2f relay",
        csv: include_str!("../data/presets/AP_amici_prism_aligned.prescription.csv"),
        file: "AP_amici_prism_aligned.prescription.csv",
        pickups: AP_PICKUPS,
    },
    Preset {
        name: "msp",
        title: "mSP: SP with the prism tilted 5° about x",
        csv: include_str!("../data/presets/mSP_single_prism_misaligned.prescription.csv"),
        file: "mSP_single_prism_misaligned.prescription.csv",
        pickups: SP_PICKUPS,
    },
    Preset {
        name: "map",
        title: "mAP: AP with the prism tilted 5° about x",
        csv: include_str!("../data/presets/mAP_amici_prism_misaligned.prescription.csv"),
        file: "mAP_amici_prism_misaligned.prescription.csv",
        pickups: MAP_PICKUPS,
    },
];

/// The spec of a preset (`sp`, `ap`, `msp`, `map`; case-insensitive).
pub fn spec(name: &str) -> Result<SystemSpec> {
    let key = name.to_ascii_lowercase();
    let p = PRESETS
        .iter()
        .find(|p| p.name == key)
        .ok_or_else(|| Error::invalid(format!("unknown preset `{name}` (presets: {})", NAMES.join(", "))))?;
    let mut data = SystemData::paper_defaults();
    data.name = p.name.to_string();
    data.pickups = p.pickups.iter().map(|&(surface, column, from_surface, scale)| PickupSource { surface, column, from_surface, scale }).collect();
    let mut spec = import_prescription(p.csv, p.file, &data)?;
    spec.description = p.title.to_string();
    Ok(spec)
}

/// The Zemax prescription text a preset is built from.
pub fn prescription_csv(name: &str) -> Option<&'static str> {
    PRESETS.iter().find(|p| p.name == name.to_ascii_lowercase()).map(|p| p.csv)
}
