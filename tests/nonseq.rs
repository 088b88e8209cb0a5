//! Non-sequential ray trees (issue 23): Fresnel physics, energy ledger, a thick plate's first ghost,
//! bit-identity with the Embree trace when reflections are off, brute force vs Embree next-hit.
use diffcassi::prelude::*;
use diffcassi::spec::{from_toml, Coating};
use diffcassi::tracer::nonseq::coating::interface_coefficients;
use diffcassi::tracer::nonseq::fresnel::amplitudes;
use diffcassi::tracer::nonseq::{path_label, trace_trees, BruteForce, FresnelModel, SolidsOptions, TreeOptions, MAX_GHOST_ORDER};

#[test]
fn normal_incidence_is_exact() {
    for &(n1, n2) in &[(1.0, 1.5168), (1.5168, 1.0), (1.0, 1.7283), (1.33, 1.9)] {
        let a = amplitudes(n1, n2, 1.0);
        let expect = ((n1 - n2) / (n1 + n2)) * ((n1 - n2) / (n1 + n2));
        assert_eq!(a.reflectance_s(), expect);
        assert_eq!(a.reflectance_p(), expect);
    }
}

/// Born & Wolf's closed forms: R_s = sin²(θᵢ−θₜ)/sin²(θᵢ+θₜ), R_p = tan²(θᵢ−θₜ)/tan²(θᵢ+θₜ).
#[test]
fn s_and_p_against_closed_forms_both_sides() {
    for &(n1, n2) in &[(1.0f64, 1.5168f64), (1.5168, 1.0)] {
        let critical = if n1 > n2 { (n2 / n1).asin() } else { std::f64::consts::FRAC_PI_2 };
        for k in 1..=20 {
            let ti = critical * k as f64 / 21.0;
            let tt = (n1 / n2 * ti.sin()).asin();
            let rs = ((ti - tt).sin() / (ti + tt).sin()).powi(2);
            let rp = ((ti - tt).tan() / (ti + tt).tan()).powi(2);
            let a = amplitudes(n1, n2, ti.cos());
            assert!((a.reflectance_s() - rs).abs() < 1e-13, "{n1}→{n2} θ={ti}: {} vs {rs}", a.reflectance_s());
            assert!((a.reflectance_p() - rp).abs() < 1e-13, "{n1}→{n2} θ={ti}: {} vs {rp}", a.reflectance_p());
            assert!((a.transmittance_s() - (1.0 - rs)).abs() < 1e-13);
            assert!((a.transmittance_p() - (1.0 - rp)).abs() < 1e-13);
        }
    }
}

#[test]
fn brewster_and_tir() {
    for &(n1, n2) in &[(1.0f64, 1.5168f64), (1.5168, 1.0)] {
        let tb = (n2 / n1).atan();
        let a = amplitudes(n1, n2, tb.cos());
        assert!(a.reflectance_p() < 1e-28, "R_p at Brewster {}", a.reflectance_p());
        assert!(a.reflectance_s() > 0.01);
    }
    let crit = (1.0f64 / 1.5168).asin();
    for k in 1..=20 {
        let ti = crit + (std::f64::consts::FRAC_PI_2 - crit) * k as f64 / 21.0;
        let a = amplitudes(1.5168, 1.0, ti.cos());
        assert!(a.tir);
        assert!((a.rs.norm() - 1.0).abs() < 1e-15 && (a.rp.norm() - 1.0).abs() < 1e-15);
        assert!(a.rs.arg() != 0.0 && a.rp.arg() != a.rs.arg(), "TIR phases: s {} p {}", a.rs.arg(), a.rp.arg());
        assert_eq!(a.transmittance_s(), 0.0);
    }
}

#[test]
fn ledger_balances_per_tree() {
    for preset in ["sp", "ap"] {
        let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
        let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
        let rays = RayBatch::for_field(&sys, [2.5, 2.5], &PupilPattern::Hexapolar { rings: 2 }.points(), 450.0).unwrap();
        for model in [FresnelModel::Polarized, FresnelModel::Scalar] {
            // A high threshold so roulette plays often.
            let opts = TreeOptions { order: 2, model, threshold: 1e-3, seed: 7, ..Default::default() };
            let trees = trace_trees(&brute, &sys, &rays, &opts).unwrap();
            let mut played = false;
            for t in &trees {
                assert!(t.ledger.imbalance().abs() < 1e-12, "{preset} {model:?}: {:?}", t.ledger);
                played |= t.ledger.rouletted != 0.0;
                assert!(t.ledger.detector > 0.5);
            }
            assert!(played, "roulette never played");
        }
    }
}

fn plate_text(coating: Option<&str>) -> String {
    let c = coating.map(|c| format!("coating = {c}\n")).unwrap_or_default();
    format!(
        r#"name = "plate"
wavelengths_nm = [520.0]
primary_wavelength_nm = 520.0
fields_mm = [[0.0, 0.0], [0.0, 10.0]]
[aperture]
type = "object_space_na"
value = 0.01
[[surfaces]]
type = "standard"
thickness_mm = 50.0
[[surfaces]]
type = "standard"
stop = true
thickness_mm = 10.0
material = "N-BK7"
semi_diameter_mm = 20.0
{c}[[surfaces]]
type = "standard"
thickness_mm = 20.0
semi_diameter_mm = 20.0
[[surfaces]]
type = "standard"
semi_diameter_mm = 20.0
"#
    )
}

fn plate_spec(coating: Option<&str>) -> SystemSpec {
    from_toml(&plate_text(coating), "plate").unwrap()
}

/// A thick plane-parallel plate: the first ghost (back then front surface) leaves parallel to the main
/// ray, displaced by 2·d·tan θₜ in the plate's plane; its power is ½Σ_{s,p} T²R² against the main's ½Σ T².
#[test]
fn thick_plate_first_ghost() {
    let sys = SequentialSystem::build(&plate_spec(None)).unwrap();
    let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
    let rays = RayBatch::chief_rays(&sys, &[[0.0, 10.0]], 520.0).unwrap();
    let opts = TreeOptions { order: 2, threshold: 0.0, ..Default::default() };
    let tree = &trace_trees(&brute, &sys, &rays, &opts).unwrap()[0];
    let main = tree.arrivals.iter().find(|a| a.path.is_empty()).unwrap();
    let ghost = tree.arrivals.iter().find(|a| path_label(&a.path) == "2R 1R").expect("first ghost");
    let n = sys.indices(520.0).unwrap()[1];
    let d = rays.direction(0).normalize();
    let cos_i = d.z;
    let tan_t = (d.y / n) / (1.0 - (d.y / n).powi(2)).sqrt();
    assert!((ghost.point.y - main.point.y - 2.0 * 10.0 * tan_t).abs() < 1e-9, "offset {}", ghost.point.y - main.point.y);
    assert!((ghost.point.x - main.point.x).abs() < 1e-12);
    assert!((ghost.direction - main.direction).length() < 1e-12, "leaves parallel");
    let a = amplitudes(1.0, n, cos_i);
    let (rs, rp, ts, tp) = (a.reflectance_s(), a.reflectance_p(), a.transmittance_s(), a.transmittance_p());
    assert!((main.power - 0.5 * (ts * ts + tp * tp)).abs() < 1e-12, "main {}", main.power);
    assert!((ghost.power - 0.5 * (ts * ts * rs * rs + tp * tp * rp * rp)).abs() < 1e-12, "ghost {}", ghost.power);
    // The scalar model: (1 − R̄)² R̄².
    let scalar = TreeOptions { model: FresnelModel::Scalar, ..opts };
    let t2 = &trace_trees(&brute, &sys, &rays, &scalar).unwrap()[0];
    let g2 = t2.arrivals.iter().find(|a| path_label(&a.path) == "2R 1R").unwrap();
    let r = 0.5 * (rs + rp);
    assert!((g2.power - (1.0 - r).powi(2) * r * r).abs() < 1e-12);
    assert!(tree.ledger.imbalance().abs() < 1e-12);
}

#[test]
fn coatings_from_the_spec_weight_the_ghost() {
    let sys = SequentialSystem::build(&plate_spec(Some("{ reflectance = 0.001 }"))).unwrap();
    let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
    let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).unwrap();
    let tree = &trace_trees(&brute, &sys, &rays, &TreeOptions { order: 2, threshold: 0.0, ..Default::default() }).unwrap()[0];
    let ghost = tree.arrivals.iter().find(|a| path_label(&a.path) == "2R 1R").unwrap();
    // Front coated (R = 0.001), back bare at normal incidence.
    let n = sys.indices(520.0).unwrap()[1];
    let rb = ((n - 1.0) / (n + 1.0)).powi(2);
    let expect = 0.999 * rb * 0.001 * (1.0 - rb);
    assert!((ghost.power - expect).abs() < 1e-15, "{} vs {expect}", ghost.power);
    // Out of range: a clear error naming the surface and field.
    let e = from_toml(&plate_text(Some("{ reflectance = 1.5 }")), "plate").unwrap_err().to_string();
    assert!(e.contains("surface 1") && e.contains("coating") && e.contains("1.5"), "{e}");
    // Round trip through TOML.
    let spec = plate_spec(Some("{ mgf2_quarter_wave_nm = 550.0 }"));
    assert_eq!(spec.surfaces[1].coating, Some(Coating::Mgf2QuarterWaveNm(550.0)));
    let back = from_toml(&diffcassi::spec::to_toml(&spec).unwrap(), "rt").unwrap();
    assert_eq!(back, spec);
    let c = interface_coefficients(spec.surfaces[1].coating.as_ref(), 1.0, n, 1.0, 550.0);
    assert!(c.reflectance() < 0.015);
}

#[test]
fn order_above_maximum_is_refused() {
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
    let rays = RayBatch::chief_rays(&sys, &[[0.0, 0.0]], 520.0).unwrap();
    let e = trace_trees(&brute, &sys, &rays, &TreeOptions { order: MAX_GHOST_ORDER + 1, ..Default::default() }).unwrap_err().to_string();
    assert!(e.contains("ghost order 5") && e.contains("at most 4"), "{e}");
}

#[test]
fn trees_do_not_depend_on_thread_count() {
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
    let rays = RayBatch::for_field(&sys, [0.0, 2.5], &PupilPattern::Hexapolar { rings: 2 }.points(), 520.0).unwrap();
    let opts = TreeOptions { order: 2, threshold: 1e-3, seed: 3, ..Default::default() };
    let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| trace_trees(&brute, &sys, &rays, &opts).unwrap());
    assert_eq!(run(1), run(3));
}

#[cfg(feature = "embree")]
mod embree {
    use super::*;
    use diffcassi::tracer::embree::{EmbreeNextHit, EmbreeOptions, EmbreeTracer, Refinement, SceneOptions};

    fn bundle(sys: &SequentialSystem) -> RayBatch {
        let mut rays = RayBatch::default();
        for &w in &[450.0, 650.0] {
            for f in [[0.0, 0.0], [2.5, 2.5], [-2.5, 0.0]] {
                rays.extend(&RayBatch::for_field(sys, f, &PupilPattern::Hexapolar { rings: 3 }.points(), w).unwrap());
            }
        }
        rays
    }

    /// With reflections off (K = 0, no Fresnel weighting) the brute-force tree is today's Embree trace
    /// with f64 refinement, bit for bit.
    #[test]
    fn reflections_off_is_bit_identical_to_embree() {
        for preset in ["sp", "ap"] {
            let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
            let rays = bundle(&sys);
            let embree = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64)).trace(&sys, &rays).unwrap();
            let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap();
            let trees = trace_trees(&brute, &sys, &rays, &TreeOptions { order: 0, model: FresnelModel::Off, ..Default::default() }).unwrap();
            let mut ok = 0;
            for (i, t) in trees.iter().enumerate() {
                assert_eq!(t.main_status, Some(embree.status[i]), "{preset} ray {i}");
                if embree.status[i] == RayStatus::Ok {
                    let a = &t.arrivals[0];
                    assert_eq!([a.point.x, a.point.y, a.point.z].map(f64::to_bits), [embree.x[i], embree.y[i], embree.z[i]].map(f64::to_bits), "{preset} ray {i}");
                    assert_eq!([a.direction.x, a.direction.y, a.direction.z].map(f64::to_bits), [embree.dir_x[i], embree.dir_y[i], embree.dir_z[i]].map(f64::to_bits));
                    ok += 1;
                }
            }
            assert!(ok > rays.len() / 2, "{preset}: {ok} of {} arrived", rays.len());
        }
    }

    /// Brute force and Embree next-hit agree on ghost paths, energies and landing points.
    #[test]
    fn brute_force_and_embree_agree_on_ghosts() {
        for preset in ["sp", "ap"] {
            let sys = SequentialSystem::build(&presets::spec(preset).unwrap()).unwrap();
            let rays = RayBatch::for_field(&sys, [0.0, 0.0], &PupilPattern::Hexapolar { rings: 2 }.points(), 520.0).unwrap();
            let opts = TreeOptions { order: 2, threshold: 1e-4, seed: 1, ..Default::default() };
            let a = trace_trees(&BruteForce::new(&sys, &SolidsOptions::default()).unwrap(), &sys, &rays, &opts).unwrap();
            let b = trace_trees(&EmbreeNextHit::new(&sys, &SceneOptions::default()).unwrap(), &sys, &rays, &opts).unwrap();
            let mut ghosts = 0;
            for (ta, tb) in a.iter().zip(&b) {
                assert_eq!(ta.arrivals.len(), tb.arrivals.len(), "{preset}");
                for (x, y) in ta.arrivals.iter().zip(&tb.arrivals) {
                    assert_eq!(x.path, y.path);
                    assert!((x.power - y.power).abs() <= 1e-12 * x.power.max(1e-300), "{preset} {}: {} vs {}", path_label(&x.path), x.power, y.power);
                    assert!((x.point - y.point).abs().max_element() <= 1e-6, "{preset} {}", path_label(&x.path));
                    ghosts += (!x.path.is_empty()) as usize;
                }
            }
            assert!(ghosts > 0, "{preset}: no ghost reached the detector");
        }
    }
}
