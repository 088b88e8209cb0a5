//! Monte-Carlo rendering of coded hyperspectral acquisitions (the reference paper's "Rendering").
//!
//! Image formation, per spectral plane λ: the coded scene H_c(:,:,λ) = H(:,:,λ) ⊙ M (mask M on the object
//! plane, one transmission per 10 µm scene pixel) is imaged by forward ray tracing: N rays per open scene
//! pixel, origins uniform over the pixel, directions filling the object-space NA through the paraxial
//! entrance pupil, stratified and seeded ([`sampling`]); each arrived ray splats weight 1/N bilinearly on
//! the detector ([`transport`]). Each plane is convolved with its Airy disk ([`airy`]), weighted by B/K and
//! the planes are summed ([`engine`]). Planes: B bands × F ([`spectral`]). The detector covers the
//! dispersed footprint ([`detector`]). Dataset mode ([`dataset`]) traces the transport once and applies it
//! to many scenes, bit-identically. Optional sensor noise ([`noise`]: shot, read, ADC) is applied to the
//! finished acquisition. [`settings`]: what a render takes, its defaults and checks, for every front end.
//! [`gradient`]: the acquisition differentiable with respect to the optical
//! parameters, the mask and the scene (co-design).
//!
//! ```
//! use diffcassi::prelude::*;
//! use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
//! use diffcassi::scene::SpectralCube;
//! let system = SequentialSystem::build(&presets::spec("ap")?)?;
//! let mut cfg = RenderConfig::paper(8);
//! cfg.spectral = SpectralSampling::new(vec![500.0, 520.0, 540.0], 2)?;
//! cfg.rays_per_pixel = 4;
//! let tracer = AnalyticTracer::default();
//! let r = Renderer::new(&system, &tracer, cfg, Mask::open(8, 8))?;
//! let scene = SpectralCube::uniform(8, 8, vec![500.0, 540.0], 1.0);
//! let acq = r.render(&scene, false, &|_| {})?;
//! // Energy: 64 pixels × 3 bands, everything arrives.
//! assert!((acq.total() - 192.0).abs() < 1e-3);
//! # Ok::<(), diffcassi::Error>(())
//! ```
pub mod airy;
pub mod convolve;
pub mod dataset;
pub mod detector;
pub mod device;
pub mod engine;
pub mod folder;
pub mod ghosts;
pub mod gradient;
pub mod mask;
pub mod noise;
pub mod output;
pub mod sampling;
pub mod settings;
pub mod spectral;
pub mod transport;
pub mod twin;
pub mod trig;
pub(crate) mod vector;
pub mod validate;

pub use airy::AiryKernel;
pub use detector::Detector;
pub use engine::*;
pub use mask::Mask;
pub use noise::{NoiseConfig, NoiseReport};
pub use sampling::{RaySampler, Sampling};
pub use settings::{Device, MaskSource, NoiseSettings, RenderSettings};
pub use spectral::SpectralSampling;
pub use transport::{Footprint, PlaneTransport, RayStats};
