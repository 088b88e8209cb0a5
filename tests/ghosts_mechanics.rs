//! Issue 23's acceptance row: brute force and Embree agree on ghost paths, energies and landing points
//! (≤ 1e-6 mm with f64 refinement) on **a mechanics scene**: SP inside its generated mounts, which absorb
//! or scatter (Lambertian) the rays that hit them, to ghost order 2. The SP and AP cases without mechanics
//! are in tests/nonseq.rs.
#![cfg(feature = "embree")]
use diffcassi::mechanics::{Mechanics, MechanicsScene};
use diffcassi::prelude::*;
use diffcassi::spec::{MechanicsSpec, SurfaceModel};
use diffcassi::tracer::embree::{EmbreeNextHit, SceneOptions};
use diffcassi::tracer::nonseq::{path_label, trace_trees, BruteForce, SolidsOptions, TreeOptions};
use std::path::Path;
use std::sync::Arc;

/// Rays over the nominal pupil and twice it (those the mounts stop), two fields, two wavelengths.
fn rays(sys: &SequentialSystem) -> RayBatch {
    let mut pupil = vec![[0.0, 0.0]];
    for k in 0..10 {
        let a = std::f64::consts::TAU * (k as f64 + 0.25) / 10.0;
        pupil.push([2.0 * a.cos(), 2.0 * a.sin()]);
        pupil.push([1.3 * a.cos(), 1.3 * a.sin()]);
        pupil.push([0.6 * a.cos(), 0.6 * a.sin()]);
    }
    let mut all = RayBatch::for_field(sys, [0.0, 0.0], &pupil, 520.0).unwrap();
    all.extend(&RayBatch::for_field(sys, [2.5, -2.5], &pupil, 450.0).unwrap());
    all
}

#[test]
fn brute_force_and_embree_agree_on_a_mechanics_scene() {
    for surface in [SurfaceModel::Absorbing, SurfaceModel::Lambertian { reflectance: 0.5 }] {
        let mut spec = presets::spec("sp").unwrap();
        spec.mechanics = Some(MechanicsSpec { surface, ..Default::default() });
        let sys = SequentialSystem::build(&spec).unwrap();
        let mech = Mechanics::from_system(&sys, Path::new(".")).unwrap();
        let brute = BruteForce::new(&sys, &SolidsOptions::default()).unwrap().with_extra(Arc::new(mech.clone()));
        let embree = EmbreeNextHit::new(&sys, &SceneOptions::default()).unwrap().with_extra(Arc::new(MechanicsScene::new(&mech).unwrap()));
        let rays = rays(&sys);
        let opts = TreeOptions { order: 2, threshold: 1e-4, seed: 5, ..Default::default() };
        let a = trace_trees(&brute, &sys, &rays, &opts).unwrap();
        let b = trace_trees(&embree, &sys, &rays, &opts).unwrap();
        let (mut ghosts, mut stray, mut blocked) = (0, 0, 0);
        for (i, (ta, tb)) in a.iter().zip(&b).enumerate() {
            assert_eq!(ta.main_status, tb.main_status, "{surface:?} ray {i}");
            blocked += (ta.main_status == Some(RayStatus::Absorbed)) as usize;
            assert_eq!(ta.arrivals.len(), tb.arrivals.len(), "{surface:?} ray {i}");
            for (x, y) in ta.arrivals.iter().zip(&tb.arrivals) {
                assert_eq!((&x.path, x.scatters), (&y.path, y.scatters), "{surface:?} ray {i}");
                assert!((x.power - y.power).abs() <= 1e-12 * x.power.max(1e-300), "{surface:?} ray {i} {}: {} vs {}", path_label(&x.path), x.power, y.power);
                assert!((x.point - y.point).abs().max_element() <= 1e-6, "{surface:?} ray {i} {}: {} vs {}", path_label(&x.path), x.point, y.point);
                ghosts += (!x.path.is_empty()) as usize;
                stray += (x.scatters > 0) as usize;
            }
            for (la, lb) in [(ta.ledger.absorbed, tb.ledger.absorbed), (ta.ledger.escaped, tb.ledger.escaped), (ta.ledger.detector, tb.ledger.detector)] {
                assert!((la - lb).abs() <= 1e-12, "{surface:?} ray {i}: ledger {la} vs {lb}");
            }
        }
        assert!(ghosts > 0, "{surface:?}: no ghost reached the detector");
        assert!(blocked > 0, "{surface:?}: no main path was stopped by a mount");
        if surface != SurfaceModel::Absorbing {
            assert!(stray > 0, "{surface:?}: no scattered light reached the detector");
        }
    }
}
