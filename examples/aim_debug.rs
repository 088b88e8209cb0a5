use diffcassi::prelude::*;
fn main() {
    let sys = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let n = sys.indices(520.0).unwrap();
    // (field, ox, oy) at 520 nm from the pupil fit
    for (f, ox, oy) in [([0.0, 0.0], 0.0, 0.0), ([2.5, 0.0], -0.05747, 0.00006), ([0.0, 2.5], 0.00037, -0.07575), ([2.5, 2.5], -0.05607, -0.07338)] {
        let mut line = format!("field {f:?}:");
        for (px, py) in [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0), (0.7071, 0.7071), (0.7071, -0.7071)] {
            let (o, d) = diffcassi::rays::object_ray(&sys, f, px + ox, py + oy);
            let (x, y) = sys.debug_stop_crossing(&n, o, d).unwrap();
            line += &format!(" ({px:+.1},{py:+.1})→({x:.4},{y:.4}) r={:.4};", x.hypot(y));
        }
        println!("{line}");
        // and every surface semi-diameter touched: max radius over the full pupil edge at each surface
        let mut maxr = vec![0.0f64; sys.path_len()];
        for k in 0..360 {
            let a = (k as f64).to_radians();
            let (o, d) = diffcassi::rays::object_ray(&sys, f, a.cos() + ox, a.sin() + oy);
            for s in 1..=sys.path_len() {
                let (_, x, y) = sys.debug_crossings(&n, o, d, s);
                maxr[s - 1] = maxr[s - 1].max(x.hypot(y));
            }
        }
        println!("   edge max radius per surface: {:?}", maxr.iter().map(|r| format!("{r:.3}")).collect::<Vec<_>>());
    }
}
