//! The external referee: diffcassi against Zemax OpticStudio's own exports for SP and AP
//! (`../shared/reference/zemax`). Prints the accuracy table quoted in docs/accuracy.md.
use crate::common;
use diffcassi::analysis::{grid_distortion, spot_diagram, spot_stats};
use diffcassi::prelude::*;

#[test]
fn grid_distortion_matches_zemax() {
    let refdir = require_reference!();
    let tracer = AnalyticTracer::default();
    println!("\n| system | λ (nm) | real: mean |Δ| (µm) | real: max |Δ| (µm) | predicted (ABCD): max |Δ| (µm) | Xref/Yref |Δ| (µm) |");
    println!("|---|---|---|---|---|---|");
    let mut worst: (f64, f64) = (0.0, 0.0);
    for (name, dir) in common::SYSTEMS {
        let sys = SequentialSystem::build(&presets::spec(name).unwrap()).unwrap();
        for (_, w) in common::WAVELENGTHS {
            let path = refdir.join(format!("zemax/{dir}/grid_distorsions_{}nm.csv", w as i32));
            let (zref, rows) = common::zemax_grid(&path);
            let grid = grid_distortion(&sys, &tracer, w, 13, 2.5).unwrap();
            assert_eq!(grid.points.len(), rows.len());
            let (mut sum, mut max, mut pred_max) = (0.0, 0.0f64, 0.0f64);
            for (p, z) in grid.points.iter().zip(&rows) {
                assert!((p.x_field_mm - z[0]).abs() < 1e-5 && (p.y_field_mm - z[1]).abs() < 1e-5, "grid order");
                let d = 1e3 * (p.real_x_mm - z[2]).hypot(p.real_y_mm - z[3]);
                sum += d;
                max = max.max(d);
                let dp = (p.pred_x_mm - grid.reference_mm[0] - z[4]).hypot(p.pred_y_mm - grid.reference_mm[1] - z[5]);
                pred_max = pred_max.max(dp);
            }
            let mean = sum / rows.len() as f64;
            let dref = 1e3 * (grid.reference_mm[0] - zref[0]).hypot(grid.reference_mm[1] - zref[1]);
            println!("| {name} | {w} | {mean:.3} | {max:.3} | {:.3} | {dref:.3} |", pred_max * 1e3);
            worst = (worst.0.max(mean), worst.1.max(max));
        }
    }
    assert!(worst.0 <= 0.5, "grid mean |Δ| {:.3} µm > 0.5 µm", worst.0);
    assert!(worst.1 <= 1.0, "grid max |Δ| {:.3} µm > 1.0 µm", worst.1);
}

/// Our `GridStep { step: 0.025 }` pupil is exactly the grid of Zemax's spot exports.
#[test]
fn grid_step_pupil_is_zemaxs() {
    let refdir = require_reference!();
    let (_, rows) = common::zemax_rays(&refdir.join("zemax/SP_single_prism_aligned/ray_positions_wavelength_W1_field_F1.csv"));
    let mut theirs: Vec<(i64, i64)> = rows.iter().map(|r| ((r[0] * 1e4).round() as i64, (r[1] * 1e4).round() as i64)).collect();
    let mut ours: Vec<(i64, i64)> =
        PupilPattern::GridStep { step: 0.025 }.points().iter().map(|p| ((p[0] * 1e4).round() as i64, (p[1] * 1e4).round() as i64)).collect();
    theirs.sort();
    ours.sort();
    assert_eq!(ours, theirs);
}

/// Per-case comparison of a spot export with our trace of the same pupil coordinates.
struct SpotRow {
    name: &'static str,
    wavelength_nm: f64,
    field_index: usize,
    field_mm: [f64; 2],
    centroid_um: f64,
    rms_ours_um: f64,
    rms_zemax_um: f64,
    per_ray_max_um: f64,
}

fn spot_rows(refdir: &std::path::Path) -> Vec<SpotRow> {
    let tracer = AnalyticTracer::default();
    let mut rows_out = Vec::new();
    for (name, dir) in common::SYSTEMS {
        let sys = SequentialSystem::build(&presets::spec(name).unwrap()).unwrap();
        for (wi, w) in common::WAVELENGTHS {
            for f in 1..=4 {
                let path = refdir.join(format!("zemax/{dir}/ray_positions_wavelength_W{wi}_field_F{f}.csv"));
                let (field, rows) = common::zemax_rays(&path);
                let pupil: Vec<[f64; 2]> = rows.iter().map(|r| [r[0], r[1]]).collect();
                let spot = spot_diagram(&sys, &tracer, field, w, &pupil).unwrap();
                assert!(spot.status.iter().all(|s| *s == RayStatus::Ok), "{name} W{wi} F{f}: all 5013 rays arrive, as in Zemax");
                let zs = spot_stats(rows.iter().map(|r| (r[2], r[3]))).unwrap();
                let ours = spot.stats.unwrap();
                rows_out.push(SpotRow {
                    name,
                    wavelength_nm: w,
                    field_index: f,
                    field_mm: field,
                    centroid_um: 1e3 * (ours.centroid_mm[0] - zs.centroid_mm[0]).hypot(ours.centroid_mm[1] - zs.centroid_mm[1]),
                    rms_ours_um: ours.rms_radius_um,
                    rms_zemax_um: zs.rms_radius_um,
                    per_ray_max_um: rows.iter().enumerate().map(|(k, r)| 1e3 * (spot.x_mm[k] - r[2]).hypot(spot.y_mm[k] - r[3])).fold(0.0, f64::max),
                });
            }
        }
    }
    println!("\n| system | λ (nm) | field | centroid |Δ| (µm) | RMS radius ours / Zemax (µm) | |ΔRMS| (µm) | per-ray max |Δ| (µm) |");
    println!("|---|---|---|---|---|---|---|");
    for r in &rows_out {
        println!(
            "| {} | {} | F{} ({}, {}) | {:.3} | {:.3} / {:.3} | {:.3} | {:.3} |",
            r.name, r.wavelength_nm, r.field_index, r.field_mm[0], r.field_mm[1], r.centroid_um, r.rms_ours_um, r.rms_zemax_um,
            (r.rms_ours_um - r.rms_zemax_um).abs(), r.per_ray_max_um
        );
    }
    rows_out
}

/// SP off-axis fields are the one known discrepancy (see `sp_off_axis_spots_match_zemax`).
fn is_sp_off_axis(r: &SpotRow) -> bool {
    r.name == "sp" && r.field_index != 1
}

/// AP at every field and SP on axis: centroid and RMS radius within 0.5 µm, and — the stretch goal — every
/// single ray within 0.2 µm (the export prints 0.1 µm).
#[test]
fn spots_match_zemax() {
    let refdir = require_reference!();
    let rows = spot_rows(&refdir);
    for r in rows.iter().filter(|r| !is_sp_off_axis(r)) {
        let what = format!("{} {} nm F{}", r.name, r.wavelength_nm, r.field_index);
        assert!(r.centroid_um <= 0.5, "{what}: centroid |Δ| {:.3} µm > 0.5", r.centroid_um);
        assert!((r.rms_ours_um - r.rms_zemax_um).abs() <= 0.5, "{what}: RMS radius |Δ| > 0.5 µm");
        assert!(r.per_ray_max_um <= 0.2, "{what}: per-ray |Δ| {:.3} µm > 0.2", r.per_ray_max_um);
    }
}

/// BLOCKED on missing data: Zemax's SP spot export for off-axis fields does not use the pupil of its own
/// Grid Distortion (whose chief rays we match to 0.01 µm): its chief ray of F4 lands up to 2.3 µm from the
/// grid's. Per-field vignetting factors (a pupil decentre, VDX/VDY, with no compression) fitted at 520 nm
/// reproduce the export at 450 and 650 nm to ≤ 0.13 µm per ray, so the export carries field data that the
/// prescription we were given does not hold (docs/accuracy.md, "What the SP spot export's pupil is (and is not)";
/// `cargo run --release --example zemax_pupil_hypotheses -- vignetting`). Shipping fitted factors would be
/// fitting the referee, so this stays ignored until the SP field data are available.
#[test]
#[ignore = "the SP off-axis spot export needs field data (vignetting factors) not in the prescription; see the doc comment"]
fn sp_off_axis_spots_match_zemax() {
    let refdir = require_reference!();
    let rows = spot_rows(&refdir);
    for r in rows.iter().filter(|r| is_sp_off_axis(r)) {
        assert!(r.centroid_um <= 0.5, "sp {} nm F{}: centroid |Δ| {:.3} µm > 0.5", r.wavelength_nm, r.field_index, r.centroid_um);
        assert!((r.rms_ours_um - r.rms_zemax_um).abs() <= 0.5);
    }
}
