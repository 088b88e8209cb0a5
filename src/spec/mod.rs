//! System specifications: the Lens Data Editor as data.
//!
//! A [`SystemSpec`] lists surfaces exactly like Zemax OpticStudio's Lens Data Editor (surface type, radius,
//! thickness, material, semi-diameter, conic, parameters), plus the system data (aperture, fields,
//! wavelengths). Every numeric cell is a [`Cell`]: a value, optionally marked variable, a pickup from another
//! surface, or a chief-ray solve. Specs are read and written as TOML or JSON ([`load_spec_file`]), imported
//! from Zemax prescription CSV transcriptions ([`zemax_csv`]), Zemax `.zmx` lens files ([`zmx`], also written) or from the reference paper's YAML files
//! ([`yaml`]). A spec is turned into a traceable [`crate::system::SequentialSystem`] by
//! [`crate::system::SequentialSystem::build`].
//!
//! ```
//! let spec = diffcassi::presets::spec("sp").unwrap();
//! let text = diffcassi::spec::to_toml(&spec).unwrap();
//! let back = diffcassi::spec::from_toml(&text, "sp.toml").unwrap();
//! assert_eq!(spec, back);
//! ```
mod cell;
mod coded_mask;
mod compare;
mod format;
mod mechanics;
mod surface;
mod system_spec;
pub mod yaml;
pub mod zemax_csv;
pub mod zmx;

pub use cell::*;
pub use coded_mask::*;
pub use compare::*;
pub use format::*;
pub use mechanics::*;
pub use surface::*;
pub use system_spec::*;
