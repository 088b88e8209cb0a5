use diffcassi::prelude::*;
fn main() {
    let spec = presets::spec("sp").unwrap();
    let sys = SequentialSystem::build(&spec).unwrap();
    // (wi, fi, ox, oy) from the pupil fit
    let fits = [(1, 1, 0.00447, 0.0), (1, 2, -0.05160, 0.0), (1, 3, 0.00482, -0.07507), (1, 4, -0.05042, -0.07297),
                (2, 1, 0.0, 0.0), (2, 2, -0.05747, 0.0), (2, 3, 0.00037, -0.07575), (2, 4, -0.05607, -0.07338),
                (3, 1, -0.00454, 0.0), (3, 2, -0.06283, 0.0), (3, 3, -0.00383, -0.07599), (3, 4, -0.06261, -0.07377)];
    for (wi, fi, ox, oy) in fits {
        let w = [450.0, 520.0, 650.0][wi - 1];
        let f = [[0.0, 0.0], [2.5, 0.0], [0.0, 2.5], [2.5, 2.5]][fi - 1];
        let n = sys.indices(w).unwrap();
        let (o, d) = diffcassi::rays::object_ray(&sys, f, ox, oy);
        let mut line = format!("W{wi} F{fi}:");
        for upto in 1..=8 {
            let pts = sys.debug_crossings(&n, o, d, upto);
            line += &format!(" s{}=({:+.4},{:+.4})", pts.0, pts.1, pts.2);
        }
        println!("{line}");
    }
}
