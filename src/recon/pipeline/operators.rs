//! The forward models a reconstruction rebuilds from a render record ([`OperatorKind`]: exact, mapping,
//! shift), the exact operator's ray seed ([`operator_seed`]) and [`build_operator`].
use super::record::{ferr, RenderRecord};
use crate::error::{Error, Result};
use crate::recon::{ExactOperator, MappingInterpolation, MappingOperator, Operator, ShiftOperator};
use crate::tracer::Tracer;

/// The forward models `--operator` names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OperatorKind {
    Exact,
    Mapping(MappingInterpolation),
    Shift,
}

impl OperatorKind {
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "exact" => Ok(OperatorKind::Exact),
            "mapping" | "mapping-bilinear" => Ok(OperatorKind::Mapping(MappingInterpolation::Bilinear)),
            "mapping-nearest" => Ok(OperatorKind::Mapping(MappingInterpolation::Nearest)),
            "shift" => Ok(OperatorKind::Shift),
            other => Err(Error::invalid(format!("--operator `{other}`: use exact, mapping, mapping-nearest or shift"))),
        }
    }
    pub fn name(&self) -> &'static str {
        match self {
            OperatorKind::Exact => "exact",
            OperatorKind::Mapping(MappingInterpolation::Bilinear) => "mapping",
            OperatorKind::Mapping(MappingInterpolation::Nearest) => "mapping-nearest",
            OperatorKind::Shift => "shift",
        }
    }
}

/// The exact operator's ray seed: `None` → acquisition seed + 1, `same` → the acquisition's, or a number.
pub fn operator_seed(acquisition_seed: u64, given: Option<&str>) -> Result<u64> {
    match given.map(str::trim) {
        None => Ok(acquisition_seed.wrapping_add(1)),
        Some("same") => Ok(acquisition_seed),
        Some(s) => s.parse::<u64>().map_err(|_| Error::invalid(format!("--operator-seed `{s}`: a non-negative integer or `same`"))),
    }
}

/// Build the operator `kind` for the record (exact: traced with `seed`, transport kept up to `budget_bytes`).
pub fn build_operator<'a>(kind: OperatorKind, record: &'a RenderRecord, tracer: &'a dyn Tracer, seed: u64, budget_bytes: u64, progress: &(dyn Fn(u64) + Sync)) -> Result<Box<dyn Operator + 'a>> {
    if kind == OperatorKind::Exact {
        // The exact operator traces what the render traced: the same ray budget (`--max-rays`).
        let c = &record.config;
        let what = format!("scene_height × scene_width × planes × rays per pixel (render.json's rays_per_pixel, or --operator-rays) ({} × {} × {} × {})", c.scene_height, c.scene_width, c.spectral.planes(), c.rays_per_pixel);
        crate::limits::check_rays(&what, c.scene_height as f64 * c.scene_width as f64 * c.spectral.planes() as f64 * c.rays_per_pixel as f64).map_err(|e| ferr(&record.dir.join("render.json"), e.to_string()))?;
    }
    let renderer = record.renderer(tracer, seed)?;
    // The record is resident beside the operator: the exact operator's memory check counts it (held after the
    // renderer is built: its detector check is part of the record's own estimate).
    let _record_held = record.hold();
    let bands = record.bands_nm().to_vec();
    Ok(match kind {
        OperatorKind::Exact => Box::new(ExactOperator::with_progress(renderer, &bands, budget_bytes, progress)?),
        OperatorKind::Mapping(interp) => Box::new(MappingOperator::from_renderer(&renderer, &bands, interp)?),
        OperatorKind::Shift => Box::new(ShiftOperator::from_renderer(&renderer, &bands)?),
    })
}
