//! Import of the reference paper's YAML system files (`../shared/reference/systems/*.yml`) and comparison of
//! the imported systems with the Zemax presets they approximate.
use diffcassi::analysis::{chief_rays, grid_distortion};
use diffcassi::prelude::*;
use diffcassi::spec::yaml::import_yaml;
use std::path::PathBuf;

const FILES: [&str; 6] = [
    "system_single.yml",
    "system_singlemis.yml",
    "system_amici.yml",
    "system_amicimis.yml",
    "system_amiciwrong.yml",
    "system_amiciwrongmis.yml",
];
/// YAML file ↔ the Zemax preset it approximates.
const PAIRS: [(&str, &str); 4] =
    [("system_single.yml", "sp"), ("system_singlemis.yml", "msp"), ("system_amici.yml", "ap"), ("system_amicimis.yml", "map")];
const FIELDS: [[f64; 2]; 4] = [[0.0, 0.0], [2.5, 0.0], [0.0, 2.5], [2.5, 2.5]];
const WAVELENGTHS: [f64; 3] = [450.0, 520.0, 650.0];

fn systems_dir() -> Option<PathBuf> {
    let p = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/reference/systems"));
    p.is_dir().then_some(p)
}

macro_rules! require_systems {
    () => {
        match systems_dir() {
            Some(p) => p,
            None => {
                eprintln!("SKIP {}: ../shared/reference/systems is absent", module_path!());
                return;
            }
        }
    };
}

fn import(dir: &std::path::Path, file: &str) -> SystemSpec {
    let path = dir.join(file);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    import_yaml(&text, &path.display().to_string()).unwrap_or_else(|e| panic!("{e}"))
}

fn chief_positions(sys: &SequentialSystem, w: f64) -> Vec<(f64, f64)> {
    let out = AnalyticTracer::default().trace(sys, &chief_rays(sys, &FIELDS, w).unwrap()).unwrap();
    assert!(out.status.iter().all(|s| *s == RayStatus::Ok), "{}: chief rays at {w} nm: {:?}", sys.name(), out.status);
    (0..out.len()).map(|k| (out.x[k], out.y[k])).collect()
}

#[test]
fn every_reference_file_imports_and_traces() {
    let dir = require_systems!();
    println!("\n| file | surfaces | λ (nm) | chief-ray image positions F1..F4 (mm) |");
    println!("|---|---|---|---|");
    for file in FILES {
        let spec = import(&dir, file);
        let sys = SequentialSystem::build(&spec).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert!(sys.pupil.distance_mm.abs() > 1e9, "{file}: the paper's chief rays leave the object along +z: {:?}", sys.pupil);
        for w in WAVELENGTHS {
            let p = chief_positions(&sys, w);
            let txt: Vec<String> = p.iter().map(|(x, y)| format!("({x:+.4}, {y:+.4})")).collect();
            println!("| {file} | {} | {w} | {} |", spec.surfaces.len(), txt.join(" "));
        }
        // The full NA-0.05 cone of every field arrives too (hexapolar, 6 rings).
        let pupil = PupilPattern::Hexapolar { rings: 6 }.points();
        for f in FIELDS {
            for w in WAVELENGTHS {
                let spot = analysis::spot_diagram(&sys, &AnalyticTracer::default(), f, w, &pupil).unwrap();
                assert!(spot.status.iter().all(|s| *s == RayStatus::Ok), "{file}: field {f:?} at {w} nm: rays lost");
            }
        }
    }
}

/// Per-λ statistics of |Δ| (µm) between two lists of points.
fn deltas(a: &[(f64, f64)], b: &[(f64, f64)]) -> (f64, f64) {
    let d: Vec<f64> = a.iter().zip(b).map(|(p, q)| 1e3 * (p.0 - q.0).hypot(p.1 - q.1)).collect();
    (d.iter().sum::<f64>() / d.len() as f64, d.iter().cloned().fold(0.0, f64::max))
}

fn grid_points(sys: &SequentialSystem, w: f64) -> Vec<(f64, f64)> {
    let g = grid_distortion(sys, &AnalyticTracer::default(), w, 13, 2.5).unwrap();
    assert!(g.points.iter().all(|p| p.status == RayStatus::Ok), "{}: grid rays lost at {w} nm", sys.name());
    g.points.iter().map(|p| (p.real_x_mm, p.real_y_mm)).collect()
}

#[test]
fn yaml_systems_land_near_their_zemax_presets() {
    let dir = require_systems!();
    println!("\n| YAML | preset | λ (nm) | chief F1..F4 |Δ| (µm) | chief max | grid 13×13 mean |Δ| (µm) | grid max | grid mean, stop at ThinLens |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut worst = Vec::new();
    for (file, preset) in PAIRS {
        let spec = import(&dir, file);
        let ysys = SequentialSystem::build(&spec).unwrap();
        // Variant: stop on the ThinLens (pupil 50–100 mm from the object) instead of telecentric.
        let mut alt = spec.clone();
        for s in alt.surfaces.iter_mut() {
            s.stop = false;
        }
        alt.surfaces[1].stop = true;
        let asys = SequentialSystem::build(&alt).unwrap();
        let zsys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let (mut wmean, mut wmax) = (0.0f64, 0.0f64);
        for w in WAVELENGTHS {
            let yc = chief_positions(&ysys, w);
            let zc = chief_positions(&zsys, w);
            let per: Vec<String> = yc.iter().zip(&zc).map(|(p, q)| format!("{:.2}", 1e3 * (p.0 - q.0).hypot(p.1 - q.1))).collect();
            let (_, cmax) = deltas(&yc, &zc);
            let yg = grid_points(&ysys, w);
            let zg = grid_points(&zsys, w);
            let (gmean, gmax) = deltas(&yg, &zg);
            let (amean, _) = deltas(&grid_points(&asys, w), &zg);
            println!("| {file} | {preset} | {w} | {} | {cmax:.2} | {gmean:.2} | {gmax:.2} | {amean:.2} |", per.join(" / "));
            wmean = wmean.max(gmean);
            wmax = wmax.max(gmax.max(cmax));
        }
        worst.push((file, preset, wmean, wmax));
    }
    for (file, preset, mean, max) in &worst {
        println!("{file} vs {preset}: worst grid mean {mean:.2} µm, worst max {max:.2} µm");
    }
    let _ = worst;
}
