//! Hyperspectral scenes: the cube type ([`SpectralCube`], `[row][col][band]`), loaders (KAIST-style
//! multichannel EXR, CAVE-style PNG folders, NPY cubes with a wavelength list), spectral resampling to the
//! render wavelengths (linear in λ, constant beyond the scene's range), fitting to the field (centre crop
//! or area resize), a seeded synthetic scene generator, and natural scenes ([`natural`]: RGB photographs
//! uplifted to reflectance spectra by Smits' method, the measured ColorChecker chart) with the colorimetry
//! ([`colorimetry`]) used for sRGB previews.
//!
//! ```
//! use diffcassi::scene::{synthetic_scene, synthetic_wavelengths, Fit};
//! let cube = synthetic_scene(80, 100, &synthetic_wavelengths(), 1);
//! let fitted = cube.fit(64, Fit::Crop).unwrap();
//! assert_eq!((fitted.height, fitted.width), (64, 64));
//! let at_520 = fitted.plane(520.0); // one value per pixel, row-major
//! assert_eq!(at_520.len(), 64 * 64);
//! ```
mod color_tables;
pub mod colorimetry;
mod cube;
mod load;
pub mod natural;
mod synthetic;

pub use cube::*;
pub use load::*;
pub use synthetic::*;
