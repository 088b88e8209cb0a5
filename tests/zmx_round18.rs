//! A held-out prober's metamorphic checks (round 18): real ray aiming (`RAIM 0 2`) measures the stop radius
//! along +y only (OpticStudio's and optiland's marginal ray), so where the real beam at the stop is not round
//! the traced beam depends on how the lens is turned about its axis. The convention is kept; loading such a
//! system warns, naming the four radii (`SequentialSystem::real_aiming_warnings`). Fixture:
//! tests/fixtures/zmx/round17/front_lens_decentred_stop_raim2.zmx (a stop decentred (0.6, 1.5) mm behind a
//! strong singlet).
use diffcassi::rays::{real_stop_radii, real_stop_radius};
use diffcassi::spec::zmx::{import_zmx, ZmxOptions};
use diffcassi::system::SequentialSystem;

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/zmx/round17");

fn build(text: &str) -> SequentialSystem {
    let opts = ZmxOptions { glass_dirs: vec![DIR.into()], ..Default::default() };
    SequentialSystem::build(&import_zmx(text.as_bytes(), "t.zmx", None, &opts).unwrap().spec).unwrap()
}

#[test]
fn real_aiming_at_a_beam_that_is_not_round_warns_with_its_radii() {
    let text = std::fs::read_to_string(format!("{DIR}/front_lens_decentred_stop_raim2.zmx")).unwrap();
    let sys = build(&text);
    let r = real_stop_radii(&sys).unwrap();
    // +y is OpticStudio's (and optiland's) real stop radius, the one rays are aimed at.
    assert_eq!(r[0], real_stop_radius(&sys).unwrap());
    assert!((r[0] - 2.283728304986656).abs() < 1e-9, "{r:?}");
    let spread = (r.iter().cloned().fold(0.0, f64::max) - r.iter().cloned().fold(f64::INFINITY, f64::min)) / r[0];
    assert!(spread > 0.03, "spread {spread}: {r:?}");
    let w = sys.warnings();
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(w[0].starts_with("real ray aiming: the real axial beam at the stop (surface 4) is not round: its radius is 2.283728 mm along +y"), "{}", w[0]);
    assert!(w[0].contains("as OpticStudio does") && w[0].contains("paraxial aiming does not"), "{}", w[0]);

    // Mirrored in y (the decentre's y negated): the +y and −y radii trade places, to rounding.
    let mirrored = text.replace("PARM 2 1.5", "PARM 2 -1.5").replace("PARM 2 -1.5\r\n  DISZ 5.0", "PARM 2 1.5\r\n  DISZ 5.0");
    assert_eq!(mirrored.matches("PARM 2 -1.5").count(), 1);
    let m = real_stop_radii(&build(&mirrored)).unwrap();
    assert!((m[0] - r[1]).abs() < 1e-9 && (m[1] - r[0]).abs() < 1e-9 && (m[2] - r[2]).abs() < 1e-9, "{m:?} vs {r:?}");
    assert!((m[0] - 2.366111).abs() < 1e-5, "{m:?}");

    // The same lens with its stop centred: the beam is round, no warning; paraxial aiming never warns.
    let centred = text.replace("  PARM 1 0.6\r\n  PARM 2 1.5\r\n", "").replace("  PARM 1 -0.6\r\n  PARM 2 -1.5\r\n", "");
    assert_ne!(centred, text);
    let c = build(&centred);
    let rc = real_stop_radii(&c).unwrap();
    assert!(rc.iter().all(|v| (v - rc[0]).abs() < 1e-9 * rc[0]), "{rc:?}");
    assert!(c.warnings().is_empty(), "{:?}", c.warnings());
    assert!(build(&text.replace("RAIM 0 2", "RAIM 0 1")).warnings().is_empty());
}
