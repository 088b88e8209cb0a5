use diffcassi::prelude::*;
use diffcassi::rays::aimed_ray;
fn main() -> diffcassi::Result<()> {
    for aim in [diffcassi::spec::RayAiming::Off, diffcassi::spec::RayAiming::Real] {
    for name in ["sp", "ap"] {
        let mut spec = presets::spec(name)?;
        spec.ray_aiming = aim;
        let sys = SequentialSystem::build(&spec)?;
        println!("{name} {aim:?} CB: {:?}", sys.spec.surfaces.iter().filter(|s| s.kind == diffcassi::spec::SurfaceKind::CoordinateBreak).last().map(|s| (s.decenter_x_mm.as_ref().unwrap().value, s.decenter_y_mm.as_ref().unwrap().value, s.tilt_y_deg.as_ref().unwrap().value)));
        let t = AnalyticTracer::default();
        for w in [450.0, 520.0, 650.0] {
            let n = sys.indices(w)?;
            let mut b = RayBatch::default();
            for f in [[0.0, 0.0], [2.5, 0.0], [0.0, 2.5], [2.5, 2.5]] {
                let (o, d) = aimed_ray(&sys, &n, f, 0.0, 0.0)?;
                b.push(o, d, w);
            }
            let out = t.trace(&sys, &b)?;
            println!("  {w}: {}", (0..4).map(|i| format!("({:.5},{:.5})", out.x[i], out.y[i])).collect::<Vec<_>>().join(" "));
        }
    }}
    Ok(())
}
#[allow(dead_code)]
fn cb() {}
